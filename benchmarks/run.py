"""JAX paths against the NumPy/SciPy reference twin (`jaxhop.reference`), in one process.

    python benchmarks/run.py --json PATH [--quick]

Every JAX timing is warm: the first call (compilation included) is timed separately and
`compile_s` is that first call minus the warm time; the warm time is the minimum over
repeats, with `block_until_ready` (or the host copy of the result) inside the timed region.
The reference runs the same inputs; where it would take minutes, it is timed on a documented
subsample and scaled per item (the entry's `note` says so). Output:

    {"device": str, "benchmarks": [{"name", "size", "jax_s", "numpy_s", "speedup",
                                    "compile_s", "note"}], "todo": [...],
     "profile": {"jax_plan_stage_s": {...}, "numpy_plan_stage_s": {...}}}

Benchmarks:
- `plan_build`: the whole BHop plan for the `reference` terrain (situate, instantiate,
  prepares graph with safety sampling, deploy).
- `bhop_sweep`: the nominal sweep on `reference`, every initial condition in the global
  domain (the same initial states and the same plan on both sides; outcomes are checked
  equal).
- `decision`: latency of one reactive decision (first match, deadbeat, clip) for one
  measured apex; JAX: `jit(decide)` on a single state.
- `slip_strides`, `slip_deadbeat`, `slip_sweep`: TODO hooks (SLIP is built separately).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxhop
from jaxhop import Hopper, build_plan, builtin_terrain, paper_templates
from jaxhop import reference as R
from jaxhop._execute import decide, run_batch, sweep_grid

HERE = os.path.dirname(os.path.abspath(__file__))


def device_name() -> str:
    d = jax.devices()[0]
    cpu = platform.processor() or platform.machine()
    return f"{d.platform}:{d.device_kind} ({os.cpu_count()} cores, {cpu})"


def timed(fn, repeats: int):
    """`(first_s, warm_s, result)`: the first call, then the minimum of `repeats` calls."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return first, best, out


def entry(name, size, jax_s, numpy_s, compile_s, note=""):
    return {"name": name, "size": size, "jax_s": jax_s, "numpy_s": numpy_s,
            "speedup": numpy_s / jax_s, "compile_s": max(compile_s, 0.0), "note": note}


def to_reference(terrain, templates):
    return (R.Terrain.from_blocks(terrain.blocks(), terrain.goal),
            R.Templates(templates.as_array(), templates.seg_length))


def reference_plan_with(jp, sit):
    """A twin `Plan` holding the JAX plan's policies (same goals, same order)."""
    return R.Plan(sit, np.asarray(jp.goal), jp.situated, jp.target, jp.goals, jp.safety,
                  jp.margin, jp.is_goal, jp.robustness, jp.prepares, jp.order, jp.stats, {})


# --- plan_build ------------------------------------------------------------------------------


def reference_plan_time(terrain, templates, every: int):
    """Seconds of the twin's plan; with `every > 1`, instantiation and the graph/safety
    sampling stage run on every `every`-th item and are scaled by the item count."""
    rt, rtm = to_reference(terrain, templates)
    goal = np.asarray(terrain.goal, float)
    if every == 1:
        t0 = time.perf_counter()
        plan = R.build_plan(rt, goal, rtm, R.Hopper())
        return time.perf_counter() - t0, plan.timings, plan.stats
    from jaxhop.reference import _plan as P

    timings = {}
    t0 = time.perf_counter()
    sit = P.situate(rt, rtm, R.Hopper())
    gw, dw = R.world_boxes(sit, *R.template_boxes(sit.regions))
    rows, cols = R.candidate_pairs(gw, dw)
    timings["situate"] = time.perf_counter() - t0
    sub = np.arange(0, rows.size, every)
    t0 = time.perf_counter()
    found, goals, _, _ = P.instantiate(sit, rows[sub], cols[sub], gw, dw)
    timings["instantiate"] = (time.perf_counter() - t0) * rows.size / sub.size
    t0 = time.perf_counter()
    P.goal_policies(sit, goal)
    timings["goal_policies"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    P.prepares_and_robustness(sit, goals[found])
    n_inst_est = found.mean() * rows.size
    timings["graph_and_safety_sampling"] = ((time.perf_counter() - t0) * n_inst_est
                                            / max(found.sum(), 1))
    return sum(timings.values()), timings, {"n_candidate_pairs": int(rows.size),
                                            "subsample_every": every}


def bench_plan_build(quick: bool):
    terrain, templates = builtin_terrain("reference"), paper_templates()
    first, warm, jp = timed(lambda: build_plan(terrain, progress=False), 1 if quick else 2)
    every = 20 if quick else 1
    numpy_s, stages, stats = reference_plan_time(terrain, templates, every)
    # Deployment on the JAX plan's inputs (its cost is tiny in both; the twin's own value).
    t0 = time.perf_counter()
    order = R.deploy(jp.prepares, jp.situated, jp.safety, jp.is_goal, jp.robustness)
    stages["deploy"] = time.perf_counter() - t0
    if every > 1:
        numpy_s = sum(stages.values())
    note = (f"{jp.stats['n_candidate_pairs']} candidate pairs, {jp.stats['n_instantiated']} "
            f"instantiated; numpy stages: "
            + ", ".join(f"{k} {v:.1f} s" for k, v in stages.items()))
    if every > 1:
        note += (f"; numpy instantiation and graph/safety sampling timed on every {every}-th "
                 "pair / goal and scaled per item")
    note += f"; twin deploy order equals JAX's: {bool(np.array_equal(order, jp.order))}"
    note += "; JAX stages (warm): " + ", ".join(
        f"{k} {v:.2f} s" for k, v in jp.stats.get("stage_seconds", {}).items())
    e = entry("plan_build", "reference (1200 situated)", warm, numpy_s, first - warm, note)
    e["stages"] = {k: round(v, 3) for k, v in stages.items()}
    return e, jp


# --- bhop_sweep ------------------------------------------------------------------------------


def bench_bhop_sweep(jp, quick: bool):
    terrain = jp.terrain
    grid = sweep_grid(terrain)
    initial = grid[jaxhop.in_global_domain(grid, jp.tables(), Hopper())]
    first, warm, out = timed(lambda: run_batch(jp, initial), 2 if quick else 3)
    rt, rtm = to_reference(terrain, jp.templates)
    ctrl = R.Controller(reference_plan_with(jp, R.situate(rt, rtm, R.Hopper())))
    t0 = time.perf_counter()
    ref = R.run_batch(ctrl, initial)
    numpy_s = time.perf_counter() - t0
    agree = bool(np.array_equal(ref["code"], out["code"])
                 and np.array_equal(ref["steps"], out["steps"]))
    strides = int(ref["steps"].sum())
    note = (f"{initial.shape[0]} initial conditions, {strides} strides in the twin "
            f"(each side stops every run at its end); "
            f"success {float(np.mean(out['code'] == 0)):.3f}; per-run outcomes and step "
            f"counts identical: {agree}")
    return entry("bhop_sweep", f"reference, {initial.shape[0]} ICs", warm, numpy_s,
                 first - warm, note)


# --- decision ------------------------------------------------------------------------------


def bench_decision(jp):
    tables, hopper = jp.tables(), Hopper()
    fn = jax.jit(decide)
    apex = jnp.asarray([4.0, 1.45, 0.5])
    t0 = time.perf_counter()
    jax.block_until_ready(fn(apex, tables, hopper))
    first = time.perf_counter() - t0
    times = []
    for _ in range(2000):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(apex, tables, hopper))
        times.append(time.perf_counter() - t0)
    rt, rtm = to_reference(jp.terrain, jp.templates)
    ctrl = R.Controller(reference_plan_with(jp, R.situate(rt, rtm, R.Hopper())))
    a = np.asarray(apex)
    ref_times = []
    for _ in range(2000):
        t0 = time.perf_counter()
        ctrl.decide(a)
        ref_times.append(time.perf_counter() - t0)
    jax_s, numpy_s = min(times), min(ref_times)
    note = (f"one apex (4.0, 1.45, 0.5); minimum of 2000 calls; median JAX "
            f"{np.median(times) * 1e6:.0f} us, median NumPy {np.median(ref_times) * 1e6:.0f} us")
    return entry("decision", "1 apex", jax_s, numpy_s, first - jax_s, note)


# --- SLIP: TODO hooks ------------------------------------------------------------------------

# TODO(SLIP): `slip_strides` (4 096 SLIP strides), `slip_deadbeat` (deadbeat solves, batch of
# 1 024) and `slip_sweep` (nominal SLIP sweep on `reference`, NumPy/SciPy on a documented
# subsample) are built by the SLIP engineer. Each hook returns an `entry(...)` dict; until
# then they return None and are listed under "todo" in the output.


def bench_slip_strides(quick: bool):
    return None  # TODO(SLIP): diffrax vmap vs solve_ivp with events, 4 096 strides


def bench_slip_deadbeat(quick: bool):
    return None  # TODO(SLIP): optimistix/optax batch of 1 024 vs scipy.optimize


def bench_slip_sweep(quick: bool):
    return None  # TODO(SLIP): JAX sweep vs twin on a documented subsample, per item


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, help="where to write the results")
    parser.add_argument("--quick", action="store_true",
                        help="NumPy plan on a 1/20 subsample, fewer repeats (< 5 min)")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    t_start = time.perf_counter()
    results, todo = [], []

    def report(e):
        results.append(e)
        print(f"{e['name']:12s} {e['size']:28s} jax {e['jax_s']:10.6f} s  numpy "
              f"{e['numpy_s']:10.6f} s  x{e['speedup']:7.1f}  compile {e['compile_s']:.2f} s",
              flush=True)
        print(f"{'':12s} {e['note']}", flush=True)

    plan_entry, jp = bench_plan_build(args.quick)
    report(plan_entry)
    report(bench_bhop_sweep(jp, args.quick))
    report(bench_decision(jp))
    for name, hook in (("slip_strides", bench_slip_strides),
                       ("slip_deadbeat", bench_slip_deadbeat),
                       ("slip_sweep", bench_slip_sweep)):
        e = hook(args.quick)
        if e is None:
            todo.append(name)
            print(f"{name:12s} TODO (SLIP benchmarks not wired in yet)", flush=True)
        else:
            report(e)
    out = {"device": device_name(), "quick": args.quick, "benchmarks": results, "todo": todo}
    out["profile"] = {"jax_plan_stage_s": jp.stats.get("stage_seconds"),
                      "numpy_plan_stage_s": plan_entry.pop("stages")}
    print("plan stages (s): JAX", out["profile"]["jax_plan_stage_s"], flush=True)
    out["total_s"] = round(time.perf_counter() - t_start, 1)
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1)
    print(f"wrote {args.json} ({out['total_s']} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
