"""Refit eq 35's horizontal-shift limits `h(v)` to SLIP strides (docs/decisions.md).

    python docs/slip_shift_fit.py [--n 40000] [--seed 0] [--plot docs/gallery/fig18.png]

Samples apex states over the templates' velocity and energy ranges above flat ground and
admissible SLIP controls (`th_td` in [-pi/3, pi/3], `kc rho0 / (m g)` in [10, 60],
`kd / kc` in [0.5, 2], log-uniform), simulates one stride each, and keeps those that end
inside the template ranges. For each, the BHop-equivalent horizontal shift is

    dy = y_lo - y_foot,   y_lo = y' - ydot' sqrt(2 (z' - h - rho0) / g)

(the liftoff point of the BHop ascent through the next apex, minus the SLIP foot), binned
by `ydot_avg = (ydot + ydot') / 2`. The 10th and 90th percentiles per 0.25 m/s bin, with
the symmetry `hi(v) = -lo(-v)`, are fitted by `h(v) = cm (atan(c (v + co)) / pi - cs)`.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from jaxhop import Hopper, jit  # noqa: E402
from jaxhop.slip import flat_touchdown, slip_apex_map  # noqa: E402


def sample(n: int, seed: int, hopper: Hopper):
    rng = np.random.default_rng(seed)
    ydot = rng.uniform(-2.5, 2.5, n)
    energy = rng.uniform(120.0, 1120.0, n)
    zr = (energy - 0.5 * hopper.m * ydot**2) / (hopper.m * hopper.g)
    ydot, zr = ydot[zr > 0.01], zr[zr > 0.01]
    k = ydot.size
    th = rng.uniform(-np.pi / 3, np.pi / 3, k)
    kc = rng.uniform(10.0, 60.0, k) * hopper.m * hopper.g / hopper.rho0
    kd = kc * np.exp(rng.uniform(np.log(0.5), np.log(2.0), k))
    apex = jnp.stack([jnp.zeros(k), jnp.asarray(zr + hopper.rho0), jnp.asarray(ydot)], 1)
    u = jnp.stack([jnp.asarray(th), jnp.asarray(kc), jnp.asarray(kd)], 1)
    nxt, code = jit(jax.vmap(lambda a, c: slip_apex_map(a, c, 0.0, hopper)))(apex, u)
    y_foot = jax.vmap(lambda a, t: flat_touchdown(a, t, 0.0, hopper)[0])(apex, u[:, 0])
    nxt, code, y_foot = np.asarray(nxt), np.asarray(code), np.asarray(y_foot)
    zr1 = nxt[:, 1] - hopper.rho0
    e1 = 0.5 * hopper.m * nxt[:, 2] ** 2 + hopper.m * hopper.g * zr1
    ok = (code == 0) & (zr1 > 0) & (np.abs(nxt[:, 2]) <= 2.5) & (e1 >= 120) & (e1 <= 1120)
    y_lo = nxt[:, 0] - nxt[:, 2] * np.sqrt(2.0 * np.maximum(zr1, 0.0) / hopper.g)
    return 0.5 * (ydot + nxt[:, 2])[ok], (y_lo - y_foot)[ok]


def h_form(p, v):
    cm, c, co, cs = p
    return cm * (np.arctan(c * (v + co)) / np.pi - cs)


def fit(v_avg, dy, q=10.0, width=0.25):
    edges = np.arange(-2.5, 2.5 + 1e-9, width)
    centres, lo, hi = [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (v_avg >= a) & (v_avg < b)
        if sel.sum() >= 20:
            centres.append(0.5 * (a + b))
            lo.append(np.percentile(dy[sel], q))
            hi.append(np.percentile(dy[sel], 100.0 - q))
    c, lo, hi = np.array(centres), np.array(lo), np.array(hi)
    v, target = np.r_[c, -c], np.r_[lo, -hi]
    res = least_squares(lambda p: h_form(p, v) - target, [0.6, 2.0, -1.0, 0.2])
    return res.x, float(np.sqrt(np.mean(res.fun**2))), (c, lo, hi)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plot", default=None)
    args = ap.parse_args()
    v_avg, dy = sample(args.n, args.seed, Hopper())
    p, rms, (c, lo, hi) = fit(v_avg, dy)
    print(f"{v_avg.size} strides kept; cm={p[0]:.4f} ca=cb={p[1]:.4f} co={p[2]:.4f} "
          f"cs={p[3]:.4f} (rms {rms:.3f} m)")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4))
        ax.scatter(v_avg, dy, s=2, alpha=0.2, color="0.5", label="SLIP strides")
        ax.plot(c, lo, "v", color="C0", label="10th / 90th percentile")
        ax.plot(c, hi, "^", color="C0")
        v = np.linspace(-2.5, 2.5, 200)
        ax.plot(v, h_form(p, v), color="C3", label="fitted h(v)")
        ax.plot(v, -h_form(p, -v), color="C3", ls="--", label="-h(-v)")
        ax.set_xlabel("average apex velocity ydot_avg (m/s)")
        ax.set_ylabel("horizontal shift dy (m)")
        ax.set_title("Horizontal-shift limits for SLIP (eq 35, refitted; Fig. 18)")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)


if __name__ == "__main__":
    main()
