"""Drawing blocks of the figures: terrain, a run's path rebuilt from its apexes and
footholds, the cross-sections of the policies' regions."""

from __future__ import annotations

import dataclasses

import numpy as np

from .._control.decisions import model_for
from .._core.params import Hopper
from .._core.programs import jit
from .._core.terrain import Terrain
from .._planning.plan import Plan


@dataclasses.dataclass(frozen=True)
class RunStyle:
    """How a run's path is rebuilt from its apexes and footholds.

    Attributes:
        model: `"bhop"` (a point foot under the body) or `"slip"` (touchdown and liftoff
            where the uncompressed leg meets the foothold, the leg drawn at both).
        hopper: its leg length `rho0` and gravity `g` give the flight arcs.
        wind: the horizontal flight acceleration that bent them.
    """

    model: str = "bhop"
    hopper: Hopper = dataclasses.field(default_factory=Hopper)
    wind: float = 0.0

    @property
    def rho0(self) -> float:
        return float(self.hopper.rho0)

    @property
    def g(self) -> float:
        return float(self.hopper.g)


def draw_terrain(ax, terrain: Terrain, perceived: Terrain | None = None, depth: float = 0.6):
    """Blocks as filled rectangles; holes stay empty. A perceived map is drawn dashed."""
    bottom = float(np.min(terrain.heights)) - depth
    for s, e, h in terrain.blocks():
        ax.fill_between([s, e], [bottom, bottom], [h, h], color="0.55", lw=0, zorder=1)
        ax.plot([s, s, e, e], [bottom, h, h, bottom], color="0.25", lw=1.0, zorder=2)
    if perceived is not None:
        for s, e, h in perceived.blocks():
            ax.plot([s, e], [h, h], "k--", lw=0.8, zorder=2)
    ax.set_xlabel("y (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal")


# --- run geometry shared by the run figures and the animation ----------------------------


def ballistic(y0, z0, vy, vz, t, g, wind=0.0):
    return y0 + vy * t + 0.5 * wind * t**2, z0 + vz * t - 0.5 * g * t**2


def _first_within(ys, zs, foot, rho0):
    """Index of the first sample within `rho0` of the foot (len(ys) if none)."""
    d = np.hypot(ys - foot[0], zs - foot[1])
    hit = np.nonzero(d <= rho0)[0]
    return int(hit[0]) if hit.size else len(ys)


def stride_paths(apexes: np.ndarray, footholds: np.ndarray, rho0: float = 1.0,
                 g: float = 9.81, model: str = "bhop", wind: float = 0.0, n: int = 24):
    """Reconstruct the COM path of a run, stride by stride, from its apexes and footholds.

    Flight is ballistic (with the wind's horizontal acceleration). `bhop`: the foot is
    directly below the COM at touchdown (`z = h + rho0`) and the instantaneous stance slides
    the COM by `dy` at that height. `slip`: touchdown and liftoff are where the COM is
    `rho0` from the foot (the leg is uncompressed at both); the stance in between is drawn
    as a straight chord (the compression is not recorded by a run).

    Returns:
        list with one dict per stride taken: `descent` and `ascent` `(ys, zs)` arrays
        (`ascent` is None after the last apex or on a failed stride), `td` and `lo` the COM
        at touchdown and liftoff, `foot` the foothold `(y, h)`, `apex` and `t_down` the
        descent's start and duration, `liftoff` = `(y, z, ydot, zdot, t_up)` (or None).
    """
    leg_touchdown = not model_for(model).instant_stance
    apexes = np.asarray(apexes, float)
    feet = np.asarray(footholds, float)
    apexes = apexes[np.all(np.isfinite(apexes), axis=1)]
    feet = feet[np.all(np.isfinite(feet), axis=1)]
    out = []
    for k, (yf, h) in enumerate(feet):
        if k >= len(apexes):
            break
        a = apexes[k]
        b = apexes[k + 1] if k + 1 < len(apexes) else None
        if leg_touchdown:
            t_max = np.sqrt(max(2.0 * (a[1] - h) / g, 0.0))
            t = np.linspace(0.0, t_max, 4000)
            ys, zs = ballistic(a[0], a[1], a[2], 0.0, t, g, wind)
            i = min(_first_within(ys, zs, (yf, h), rho0), len(t) - 1)
            t_d = t[i]
        else:
            t_d = np.sqrt(max(2.0 * (a[1] - h - rho0) / g, 0.0))
        descent = ballistic(a[0], a[1], a[2], 0.0, np.linspace(0.0, t_d, n), g, wind)
        td = (descent[0][-1], descent[1][-1])
        lo, ascent = td, None
        if b is not None:
            if leg_touchdown:
                tau_max = np.sqrt(max(2.0 * (b[1] - h) / g, 0.0))
                tau = np.linspace(0.0, tau_max, 4000)
                ys, zs = ballistic(b[0], b[1], -b[2], 0.0, tau, g, wind)
                t_up = tau[min(_first_within(ys, zs, (yf, h), rho0), len(tau) - 1)]
            else:
                t_up = np.sqrt(max(2.0 * (b[1] - h - rho0) / g, 0.0))
            y_lo = b[0] - b[2] * t_up + 0.5 * wind * t_up**2
            z_lo = b[1] - 0.5 * g * t_up**2
            ascent = ballistic(y_lo, z_lo, b[2] - wind * t_up, g * t_up,
                                np.linspace(0.0, t_up, n), g, wind)
            lo = (y_lo, z_lo)
            lift = (y_lo, z_lo, b[2] - wind * t_up, g * t_up, t_up)
        out.append({"descent": descent, "ascent": ascent, "td": td, "lo": lo,
                    "foot": (yf, h), "apex": tuple(a), "t_down": t_d,
                    "liftoff": lift if b is not None else None})
    return out


def draw_run(ax, apexes: np.ndarray, footholds: np.ndarray, rho0: float = 1.0,
             g: float = 9.81, color="tab:blue", label=None, model: str = "bhop",
             wind: float = 0.0, legs: bool = False, ls="-"):
    """COM path of a run from its apexes and footholds (see `stride_paths`).

    Dots mark apexes, triangles footholds, `x` the initial apex. With `legs`, the leg is
    drawn at touchdown and liftoff.
    """
    apexes = np.asarray(apexes)[np.all(np.isfinite(apexes), axis=1)]
    feet = np.asarray(footholds)[np.all(np.isfinite(footholds), axis=1)]
    paths = stride_paths(apexes, feet, rho0, g, model, wind)
    for k, p in enumerate(paths):
        kw = {"color": color, "lw": 1.2, "zorder": 5, "ls": ls}
        ax.plot(*p["descent"], label=label if k == 0 else None, **kw)
        (yf, h), td, lo = p["foot"], p["td"], p["lo"]
        if p["ascent"] is not None:
            ax.plot([td[0], lo[0]], [td[1], lo[1]], **kw)
            ax.plot(*p["ascent"], **kw)
        if legs:
            for q in (td, lo) if p["ascent"] is not None else (td,):
                ax.plot([q[0], yf], [q[1], h], color="0.2", lw=0.7, zorder=4)
        elif model_for(model).instant_stance:
            ax.plot([yf, yf], [h, h + rho0], color="0.3", lw=0.6, zorder=4)
    if feet.size:
        ax.plot(feet[:, 0], feet[:, 1], "v", color=color, ms=5, zorder=6)
    ax.plot(apexes[:, 0], apexes[:, 1], ".", color=color, ms=5, zorder=6)
    ax.plot(apexes[0, 0], apexes[0, 1], "x", color=color, ms=8, mew=2, zorder=6)
    if not paths and label is not None:
        ax.plot([], [], color=color, label=label)


# --- cross-sections of the policies' regions (Figs. 13, 19) ------------------------------


@jit
def _section_bounds(t, v_d, v_g, tmpls, hop):
    """The domain's height bounds at `v_d` and the feasible goal's at `v_g` of templates `t`
    (jitted once here: an explorer redraws one policy's sections without tracing)."""
    import jax
    import jax.numpy as jnp

    from .._planning.regions import domain_height_bounds, goal_height_bounds

    def one(t, v_d, v_g):
        tmpl = tmpls.row(t)
        d = domain_height_bounds(v_d, tmpl, hop)
        gb = goal_height_bounds(v_g, tmpl, hop)
        return jnp.stack(d), jnp.stack(gb)

    return jax.vmap(one)(t, v_d, v_g)


def policy_cross_sections(plan: Plan, policies, apexes, n: int = 40):
    """Cross-sections in `(y, z)` of the domain and feasible goal of the policies used.

    For stride `k` (instantiated policy `policies[k]`, situated on a segment at `(py, h)`):
    the domain `D` at the apex's velocity `apexes[k][2]` (eqs 38-41: heights from
    the energy range, `y` such that the nominal touchdown lies on the segment) and the
    feasible goal `Gf` at the policy goal's velocity (corrected eqs 45-50). The planner's
    collision-free trims (`docs/decisions.md`, "Regions") are not drawn.

    Returns:
        list of `(domain_polygon, goal_polygon)`, each an `(m, 2)` array or None if empty.
    """
    import jax.numpy as jnp

    policies = np.asarray(policies)
    policies = policies[policies >= 0]
    if policies.size == 0:
        return []
    apexes = np.asarray(apexes, float)[: policies.size]
    nt = plan.templates.n
    sit = plan.situated[policies]
    t_idx, seg = sit % nt, sit // nt
    centre = np.asarray(plan.table().centre)[seg]
    goals = np.asarray(plan.goals)[policies]
    hop, tmpls = plan.hopper, plan.templates
    l = tmpls.half_length

    d_b, g_b = (np.asarray(x) for x in _section_bounds(
        jnp.asarray(t_idx), jnp.asarray(apexes[:, 2]), jnp.asarray(goals[:, 2]), tmpls, hop))
    dy_lo, dy_hi = np.asarray(tmpls.dy_lo)[t_idx], np.asarray(tmpls.dy_hi)[t_idx]
    rho0, g = float(hop.rho0), float(hop.g)
    out = []
    for k in range(policies.size):
        py, h = centre[k]
        polys = []
        lo, hi = d_b[k]
        if np.isfinite(lo) and np.isfinite(hi) and hi > lo:
            zr = np.linspace(lo, hi, n)
            shift = apexes[k, 2] * np.sqrt(2.0 * zr / g)
            left, right = py - l - shift, py + l - shift
            polys.append(np.concatenate([np.stack([left, zr + h + rho0], 1),
                                         np.stack([right, zr + h + rho0], 1)[::-1]]))
        else:
            polys.append(None)
        lo, hi = g_b[k]
        if np.isfinite(lo) and np.isfinite(hi) and hi > lo:
            zr = np.linspace(lo, hi, n)
            shift = goals[k, 2] * np.sqrt(2.0 * zr / g)  # eqs 49-50
            y_lo, y_hi = shift + l + dy_lo[k], shift - l + dy_hi[k]
            polys.append(np.concatenate([np.stack([py + y_lo, zr + h + rho0], 1),
                                         np.stack([py + y_hi, zr + h + rho0], 1)[::-1]]))
        else:
            polys.append(None)
        out.append(tuple(polys))
    return out


def draw_cross_sections(ax, sections, label=True):
    """Domain cross-sections dark red, feasible-goal cross-sections light green."""
    from matplotlib.patches import Polygon

    first_d = first_g = label
    for dom, goal in sections:
        if dom is not None:
            ax.add_patch(Polygon(dom, closed=True, fc="darkred", ec="none", alpha=0.28,
                                 zorder=3, label="domain at the apex's ydot" if first_d
                                 else None))
            first_d = False
        if goal is not None:
            ax.add_patch(Polygon(goal, closed=True, fc="limegreen", ec="none", alpha=0.3,
                                 zorder=3, label="feasible goal at the goal's ydot" if first_g
                                 else None))
            first_g = False
