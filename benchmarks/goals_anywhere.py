"""Goals anywhere: a goal apex on a random point of a random landable block of a random terrain.

For each of `--n` seeded terrains (`random_terrain(key(seed + i), --length)`) a block with at
least one segment is drawn, and on it the goal `y`: for every fourth terrain exactly on a
segment boundary (`start + k * 0.15`, as a user would type it) or, alternately, on the
block's midpoint; otherwise uniform over the block. The goal is 1.3 m above the block, at
rest. Each goal is planned (`build_plan`): either the plan has goal policies, or it is
refused with a reason (`InputError`, `goal_refusal`). Each planned one is swept without
disturbance on a coarse grid (`--dy`, `--dz`; default 0.1 m) at the default tolerance.

    python benchmarks/goals_anywhere.py [--n 40] [--length 5] [--dy 0.1] [--dz 0.1] [--json PATH]
"""

import argparse
import json
import math
import time

import jax
import numpy as np

import jaxhop
from jaxhop import SEGMENT_LENGTH, InputError, build_plan, random_terrain, sweep

jax.config.update("jax_enable_x64", True)


def pick_goal(terrain, rng, i):
    """`(goal, where)`: the goal apex on a random landable block and how `y` was drawn."""
    blocks = [b for b in terrain.blocks() if b[1] - b[0] >= SEGMENT_LENGTH - 1e-9]
    s, e, h = blocks[int(rng.integers(len(blocks)))]
    if i % 4 == 0:
        n = int(math.floor((e - s) / SEGMENT_LENGTH + 1e-9))
        if (i // 4) % 2 == 0 and n > 1:
            y, where = s + int(rng.integers(1, n)) * SEGMENT_LENGTH, "boundary"
        else:
            y, where = 0.5 * (s + e), "midpoint"
    else:
        y, where = float(rng.uniform(s, e)), "random"
    return (float(y), h + 1.3, 0.0), where


def one(i, seed, length, dy, dz):
    terrain = random_terrain(jax.random.key(seed + i), length)
    goal, where = pick_goal(terrain, np.random.default_rng(seed + i), i)
    row = {"terrain": seed + i, "goal": list(goal), "where": where}
    t0 = time.perf_counter()
    try:
        plan = build_plan(terrain, goal, progress=False)
    except InputError as err:
        return row | {"outcome": "refused", "reason": str(err),
                      "seconds": round(time.perf_counter() - t0, 1)}
    row |= {"outcome": "planned", "n_goal_policies": plan.stats["n_goal_policies"],
            "n_deployed": plan.stats["n_deployed"]}
    try:
        s, _, _ = sweep(plan, jaxhop.RunSettings(controller="paper"),
                        initial=jaxhop.SweepGrid(dy=dy, dz=dz))
        row |= {"n_initial": s["n_initial_conditions"], "success_rate": s["success_rate"],
                "failures": {k: v for k, v in s["failures"].items() if v}}
    except InputError as err:
        row |= {"n_initial": 0, "success_rate": None, "sweep_error": str(err)}
    return row | {"seconds": round(time.perf_counter() - t0, 1)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="terrains")
    ap.add_argument("--seed", type=int, default=0, help="first terrain seed")
    ap.add_argument("--length", type=float, default=5.0, help="terrain length (m)")
    ap.add_argument("--dy", type=float, default=0.1)
    ap.add_argument("--dz", type=float, default=0.1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows = []
    print(f"{'terrain':>7} {'where':9} {'goal':>22} {'outcome':8} {'goal pol':>8} "
          f"{'states':>6} {'success':>7} {'s':>6}  reason / failures")
    for i in range(args.n):
        r = one(i, args.seed, args.length, args.dy, args.dz)
        rows.append(r)
        g = ", ".join(f"{x:.4g}" for x in r["goal"])
        rate = "-" if r.get("success_rate") is None else f"{r['success_rate']:.4f}"
        note = r.get("reason") or r.get("sweep_error") or r.get("failures") or ""
        print(f"{r['terrain']:7d} {r['where']:9} {g:>22} {r['outcome']:8} "
              f"{r.get('n_goal_policies', 0):8d} {r.get('n_initial', 0):6d} {rate:>7} "
              f"{r['seconds']:6.1f}  {note}", flush=True)
    planned = [r for r in rows if r["outcome"] == "planned"]
    rates = [r["success_rate"] for r in planned if r.get("success_rate") is not None]
    summary = {"n_terrains": len(rows), "planned": len(planned),
               "refused": len(rows) - len(planned),
               "planned_on_boundary_or_midpoint": sum(r["where"] != "random" for r in planned),
               "min_success": min(rates) if rates else None,
               "all_at_least_0.999": all(x >= 0.999 for x in rates),
               "length": args.length, "dy": args.dy, "dz": args.dz, "jax": jax.__version__}
    print(json.dumps(summary))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"summary": summary, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
