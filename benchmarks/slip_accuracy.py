"""Accuracy of a SLIP decision's trial strides and deadbeat, adaptive and fixed-shape.

Two measurements for each of a decision's stride settings (`DECISION_TOL`, adaptive at
1e-5, a CPU's; `FIXED_DECISION_TOL`, fixed-shape, an accelerator's; `docs/slip.md`,
"Fixed-shape trial strides"):

- strides: `--strides` random strides of the reference hopper over flat ground, half of
  them under a wind of -0.2 m/s^2, against the 1e-10 stride: result codes that differ and
  the largest apex error;
- deadbeat: `--targets` random reachable targets (the 1e-10 stride of random admissible
  controls from a random apex), solved from the apex table without and with the
  multi-start fallback, the controls executed at 1e-10: the share that lands within 1 mm
  and 1 mm/s of its target.

    python benchmarks/slip_accuracy.py --json benchmarks/results/cpu2-slip-accuracy-2026-11.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax
import numpy as np

import jaxhop
import jaxhop.slip as slip

HOP = jaxhop.Hopper()
FLAT = jaxhop.make_terrain([(-20.0, 20.0, 0.0)])


def random_strides(rng, n):
    """Random apexes over flat ground and random admissible controls."""
    mg = HOP.m * HOP.g / HOP.rho0
    apex = np.stack([rng.uniform(-1, 1, n), rng.uniform(1.1, 1.6, n),
                     rng.uniform(-2.5, 2.5, n)], axis=1)
    kc = rng.uniform(slip.KAPPA_LO + 1, slip.KAPPA_HI - 1, n) * mg
    u = np.stack([rng.uniform(-0.4, 0.4, n), kc,
                  kc * rng.uniform(slip.RATIO_LO + 0.05, slip.RATIO_HI - 0.05, n)], axis=1)
    return apex, u


def strides(tol):
    return jaxhop.jit(jax.vmap(lambda a, v, w: slip.slip_stride(a, v, FLAT, HOP, w, tol)[:2]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True)
    parser.add_argument("--strides", type=int, default=2000)
    parser.add_argument("--targets", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    exact = strides(slip.STRIDE_TOL)
    settings = {"adaptive 1e-5": slip.DECISION_TOL, "fixed-shape": slip.FIXED_DECISION_TOL}

    apex, u = random_strides(rng, args.strides)
    wind = np.where(np.arange(args.strides) % 2 == 0, 0.0, -0.2)
    ref, ref_code = (np.asarray(x) for x in exact(apex, u, wind))
    out = {"device": f"{platform.machine()}, {os.cpu_count()} cores", "jax": jax.__version__,
           "load_average": os.getloadavg()[0], "strides": {}, "deadbeat": {}}
    for name, tol in settings.items():
        nxt, code = (np.asarray(x) for x in strides(tol)(apex, u, wind))
        ok = (code == 0) & (ref_code == 0)
        err = np.abs(nxt - ref)[ok].max(axis=1)
        out["strides"][name] = {"n": args.strides, "codes_differ": int(np.sum(code != ref_code)),
                                "max_error": float(err.max()),
                                "p99_error": float(np.quantile(err, 0.99))}
        print(name, out["strides"][name], flush=True)

    apex, u = random_strides(rng, 2 * args.targets)
    goal, code = (np.asarray(x) for x in exact(apex, u, np.zeros(len(apex))))
    keep = np.flatnonzero(code == 0)[:args.targets]
    apex, goal = apex[keep], goal[keep]
    table = slip.slip_table(progress=False)
    for name, tol in settings.items():
        for fallback in (False, True):
            search = slip.DeadbeatSearch(tol=tol, table=table, fallback=fallback)
            solve = jaxhop.jit(jax.vmap(lambda a, g, s=search: slip.deadbeat_slip(
                a, g, 0.0, HOP, s)[0]))
            jax.block_until_ready(solve(apex, goal))
            t0 = time.perf_counter()
            us = np.asarray(solve(apex, goal))
            seconds = time.perf_counter() - t0
            nxt, c = (np.asarray(x) for x in exact(apex, us, np.zeros(len(apex))))
            err = np.abs(nxt - goal)
            within = (c == 0) & (err[:, :2].max(axis=1) <= 1e-3) & (err[:, 2] <= 1e-3)
            key = f"{name}, {'with' if fallback else 'without'} fallback"
            out["deadbeat"][key] = {"n": int(len(keep)), "within_1mm": float(within.mean()),
                                    "warm_ms_per_target": 1e3 * seconds / len(keep)}
            print(key, out["deadbeat"][key], flush=True)
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
