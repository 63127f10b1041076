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
- `slip_strides`: 4 096 random SLIP strides over flat ground; JAX `_slip.slip_strides`
  (diffrax, vmapped, chunks of 512 over the CPU devices), twin `solve_ivp` with events in
  a loop over all of them (`--quick`: every 4-th, scaled per item; codes and apexes are
  checked).
- `slip_table`: the SLIP deadbeat's start table built anew (`jaxhop.slip.build_table`), time
  only (the twin reads the same table).
- `slip_deadbeat`: 1 024 deadbeat solves to reachable targets; JAX `deadbeat_slips` (the
  table start and Gauss-Newton polish through diffrax, in passes over the targets that
  missed, the multi-start solver last), beside the multi-start solver alone (split over the
  devices the same way) in the same run; twin the same stages with a finite-difference
  Jacobian on every 32-th target (`--quick`: every 128-th), scaled per item.
- `slip_decision`: latency of one SLIP decision (`decide_slip` with the table) for one
  measured apex, median over 64 sweep states; twin on 8 of them.
- `slip_sweep`: SLIP runs (`run_batch(plan, initial, model="slip")`) on the BHop plan of
  `reference` from 256 of its 4 470 initial conditions, evenly spaced (`--quick`: 64); the
  twin on 8 of those, scaled per initial condition; per-run outcome and step count
  compared.

`"todo"` lists benchmarks not wired in (empty).
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
from jaxhop import (
    Hopper,
    build_plan,
    builtin_terrain,
    chunked_map,
    decide,
    paper_templates,
    run_batch,
    sweep_grid,
)
from jaxhop import reference as R

HERE = os.path.dirname(os.path.abspath(__file__))


def device_name() -> str:
    d = jax.devices()[0]
    cpu = platform.processor() or platform.machine()
    return (f"{d.platform}:{d.device_kind} x{len(jax.devices())} ({os.cpu_count()} cores, "
            f"{cpu})")


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
    timings = {}
    t0 = time.perf_counter()
    sit = R.situate(rt, rtm, R.Hopper())
    gw, dw = R.world_boxes(sit, *R.template_boxes(sit.regions))
    rows, cols = R.candidate_pairs(gw, dw)
    timings["situate"] = time.perf_counter() - t0
    sub = np.arange(0, rows.size, every)
    t0 = time.perf_counter()
    found, goals, _, _ = R.instantiate(sit, rows[sub], cols[sub], gw, dw)
    timings["instantiate"] = (time.perf_counter() - t0) * rows.size / sub.size
    t0 = time.perf_counter()
    R.goal_policies(sit, goal)
    timings["goal_policies"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    R.prepares_and_robustness(sit, goals[found])
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
    paper = jaxhop.RunSettings(controller="paper")
    first, warm, out = timed(lambda: run_batch(jp, initial, paper), 2 if quick else 3)
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
    fn = jaxhop.jit(decide)
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


# --- SLIP ----------------------------------------------------------------------------------


def random_slip_strides(seed, n):
    """Random admissible SLIP strides over flat ground at 0 (as docs/slip.md)."""
    from jaxhop.slip import KAPPA_HI, KAPPA_LO, RATIO_HI, RATIO_LO

    hopper = Hopper()
    mg = hopper.m * hopper.g / hopper.rho0
    rng = np.random.default_rng(seed)
    apex = np.stack([rng.uniform(-1, 1, n), rng.uniform(1.1, 1.6, n),
                     rng.uniform(-2.5, 2.5, n)], axis=1)
    kc = rng.uniform(KAPPA_LO, KAPPA_HI, n) * mg
    u = np.stack([rng.uniform(-0.45, 0.45, n), kc, kc * rng.uniform(RATIO_LO, RATIO_HI, n)],
                 axis=1)
    return apex, u


def bench_slip_strides(quick: bool):
    from jaxhop import make_terrain
    from jaxhop.slip import slip_strides

    n = 4096
    blocks = [(-20.0, 20.0, 0.0)]
    terrain, r_terrain = make_terrain(blocks), R.Terrain.from_blocks(blocks)
    apex, u = random_slip_strides(0, n)
    first, warm, (nxt, code, _) = timed(lambda: slip_strides(apex, u, terrain, Hopper()),
                                        2 if quick else 3)
    nxt, code = np.asarray(nxt), np.asarray(code)
    every = 4 if quick else 1
    sub = np.arange(0, n, every)
    t0 = time.perf_counter()
    ref = [R.slip_stride(apex[i], u[i], r_terrain, R.Hopper()) for i in sub]
    numpy_s = (time.perf_counter() - t0) * n / sub.size
    r_code = np.array([r[1] for r in ref])
    ok = (code[sub] == 0) & (r_code == 0)
    err = float(np.max(np.abs(np.array([r[0] for r in ref])[ok] - nxt[sub][ok])))
    which = (f"all {n} strides" if every == 1
             else f"every {every}-th stride ({sub.size}), scaled per item")
    note = (f"random strides over flat ground (apex y in [-1, 1], z in [1.1, 1.6], ydot in "
            f"[-2.5, 2.5]; admissible controls); JAX slip_strides (vmap(slip_stride), diffrax "
            f"Tsit5, chunks of 512 over {len(jax.local_devices())} devices), twin "
            f"solve_ivp DOP853 with events, a Python loop over "
            f"{which}, both rtol = atol = 1e-10; {int((code == 0).sum())} complete; codes "
            f"identical on the twin's strides: {bool(np.array_equal(code[sub], r_code))}; max apex "
            f"difference {err:.1e}")
    return entry("slip_strides", f"{n} strides", warm, numpy_s, first - warm, note)


def bench_slip_table():
    from jaxhop.slip import DEFAULT_GRID, build_table

    t0 = time.perf_counter()
    values = build_table(DEFAULT_GRID, progress=False)
    jax_s = time.perf_counter() - t0
    done = float(np.isfinite(values[..., 0]).mean())
    note = (f"the SLIP deadbeat's start table built anew (no cache): "
            f"{values[..., 0].size} strides of a unit hopper on the grid "
            f"{DEFAULT_GRID.to_list()} (zeta, nu, eps, th, s), {done:.3f} of them complete; "
            f"first call, compilation included; no twin (the twin reads the same table)")
    return entry("slip_table", f"{values[..., 0].size} strides", jax_s, float("nan"), 0.0, note)


def slip_targets(n):
    """`n` reachable SLIP targets: apexes of random admissible strides over flat ground."""
    from jaxhop.slip import slip_apex_map

    apex, u = random_slip_strides(1, 2 * n)
    goal, code = jaxhop.jit(jax.vmap(slip_apex_map, (0, 0, None, None)))(
        jnp.asarray(apex), jnp.asarray(u), 0.0, Hopper())
    keep = np.nonzero(np.asarray(code) == 0)[0][:n]
    return apex[keep], np.asarray(goal)[keep]


def within_1mm(apex, goal, u):
    """Which controls `u` take `apex` to within 1 mm and 1 mm/s of `goal` (strides at the
    simulation's tolerance)."""
    from jaxhop.slip import slip_apex_map

    nxt, code = jaxhop.jit(jax.vmap(slip_apex_map, (0, 0, None, None)))(
        jnp.asarray(apex), jnp.asarray(u), 0.0, Hopper())
    err = np.max(np.abs(np.asarray(nxt) - goal), axis=1)
    return (np.asarray(code) == 0) & (err <= 1e-3)


def bench_slip_deadbeat(quick: bool):
    from jaxhop.slip import deadbeat_slip, deadbeat_slips, slip_table

    n = 1024
    hopper = Hopper()
    apex, goal = slip_targets(n)
    table = slip_table(progress=False)
    first, warm, (ju, jok, stage) = timed(
        lambda: deadbeat_slips(apex, goal, 0.0, hopper, table), 1 if quick else 2)
    hit = within_1mm(apex, goal, ju)
    # The multi-start solver alone (no table), split over the devices as deadbeat_slips is.
    multi = jaxhop.jit(jax.vmap(lambda a, g: deadbeat_slip(a, g, 0.0, hopper)))
    share = -(-n // len(jax.local_devices()))
    m_first, m_warm, (mu, _) = timed(lambda: chunked_map(multi, n, share, (apex, goal)), 1)
    m_hit = within_1mm(apex, goal, np.asarray(mu))
    every = 128 if quick else 32
    sub = np.arange(0, n, every)
    rtab = table.data()
    t0 = time.perf_counter()
    search = R.DeadbeatSearch(table=rtab)
    ref = [R.deadbeat_slip(apex[i], goal[i], 0.0, R.Hopper(), search, full=True) for i in sub]
    numpy_s = (time.perf_counter() - t0) * n / sub.size
    du = np.array([np.max(np.abs(r[0] - ju[i]) / np.maximum(1.0, np.abs(ju[i])))
                   for r, i in zip(ref, sub)])
    same_ok = int(sum(r[1] == jok[i] for r, i in zip(ref, sub)))
    counts = np.bincount(stage, minlength=4)[1:]
    note = (f"{n} reachable targets (apexes of random strides over flat ground); JAX "
            f"deadbeat_slips: the table start, Gauss-Newton polish through diffrax in "
            f"stages as passes over the targets that missed (stage 1 {counts[0]}, stage 2 "
            f"{counts[1]}, stage 3 = multi-start fallback {counts[2]}: rate "
            f"{counts[2] / n:.4f}); within 1 mm and 1 mm/s: {hit.mean():.4f}; ok "
            f"{float(jok.mean()):.4f}. The multi-start solver alone (vmap(deadbeat_slip), no "
            f"table) in the same run: {m_warm:.3f} s warm, compile {m_first - m_warm:.1f} s, "
            f"within 1 mm {m_hit.mean():.4f}: the table start is "
            f"{m_warm / warm:.1f}x faster. Twin: the same stages (the same table's values, "
            f"finite-difference Jacobian, scipy solve_ivp strides), timed on every {every}-th "
            f"target ({sub.size}) and scaled per item; ok flags equal {same_ok}/{sub.size}, "
            f"stages equal {int(sum(r[2] == stage[i] for r, i in zip(ref, sub)))}/{sub.size},"
            f" controls' largest relative difference {float(du.max()):.1e} "
            f"(median {float(np.median(du)):.1e})")
    return entry("slip_deadbeat", f"{n} targets", warm, numpy_s, first - warm, note)


def bench_slip_decision(jp):
    """One SLIP decision (first matches, staged table-start deadbeat, prediction) for one
    measured apex, as the run loop makes it; latency of a single call."""
    from jaxhop.slip import decide_slip

    tables = jp.tables(slip=True)
    hopper = Hopper()
    fn = jaxhop.jit(lambda a: decide_slip(a, tables, hopper))
    grid = sweep_grid(jp.terrain)
    initial = grid[jaxhop.in_global_domain(grid, jp.tables(), hopper)]
    states = initial[np.linspace(0, initial.shape[0] - 1, 64).round().astype(int)]
    t0 = time.perf_counter()
    jax.block_until_ready(fn(jnp.asarray(states[0])))
    first = time.perf_counter() - t0
    times = []
    for _ in range(3):
        for z in states:
            z = jnp.asarray(z)
            t0 = time.perf_counter()
            jax.block_until_ready(fn(z))
            times.append(time.perf_counter() - t0)
    rt, rtm = to_reference(jp.terrain, jp.templates)
    ctrl = R.Controller(reference_plan_with(jp, R.situate(rt, rtm, R.Hopper())),
                        slip_table=tables.slip.data())
    ref_times = []
    for z in states[::8]:
        t0 = time.perf_counter()
        ctrl.decide_slip(z)
        ref_times.append(time.perf_counter() - t0)
    med, ref_med = float(np.median(times)), float(np.median(ref_times))
    note = (f"one SLIP decision (decide_slip with the table: first matches, staged deadbeat, "
            f"predicted stride) on each of 64 evenly spaced initial states of the reference "
            f"sweep, 3 rounds, one state per call (no batch); median {med * 1e3:.2f} ms, "
            f"90th percentile {np.percentile(times, 90) * 1e3:.2f} ms, minimum "
            f"{min(times) * 1e3:.2f} ms; twin (same decision, table start) median "
            f"{ref_med * 1e3:.0f} ms on 8 of the states")
    return entry("slip_decision", "1 apex", med, ref_med, first - med, note)


def bench_slip_sweep(jp, quick: bool):
    terrain = jp.terrain
    grid = sweep_grid(terrain)
    initial = grid[jaxhop.in_global_domain(grid, jp.tables(), Hopper())]
    n_all = initial.shape[0]
    # The BHop plan without the SLIP adjustments (the twin has none): about half of the
    # SLIP runs on it leave the global domain (`outside_domain`), so the load differs from
    # the nominal `--model slip` sweep. JAX: an evenly spaced subsample of the sweep's initial
    # conditions (256 of 4 470; --quick: 64). The twin (two deadbeat solves per stride,
    # about 1 s): an evenly spaced subsample of what JAX ran; both compared per run.
    n_jax = 64 if quick else min(256, n_all)
    runs = initial[np.linspace(0, n_all - 1, n_jax).round().astype(int)]
    slip_paper = jaxhop.RunSettings(model="slip", controller="paper")
    first, warm, out = timed(lambda: run_batch(jp, runs, slip_paper), 1)
    n_ref = 8
    pick = np.linspace(0, n_jax - 1, n_ref).round().astype(int)
    rt, rtm = to_reference(terrain, jp.templates)
    tab = jp.tables(slip=True).slip
    ctrl = R.Controller(reference_plan_with(jp, R.situate(rt, rtm, R.Hopper())),
                        slip_table=tab.data())
    t0 = time.perf_counter()
    ref = R.run_batch(ctrl, runs[pick], model="slip")
    numpy_s = (time.perf_counter() - t0) * n_jax / n_ref
    same = int(np.sum((ref["code"] == out["code"][pick]) & (ref["steps"] == out["steps"][pick])))
    names = ("success",) + R.FAILURE_NAMES
    outcomes = ", ".join(f"{names[c]} {int((out['code'] == c).sum())}"
                         for c in range(len(names)) if (out["code"] == c).any())
    note = (f"SLIP runs on the BHop plan (model='slip': decide_slip, the SLIP deadbeat on the "
            f"best-reaching of the first matches) from {n_jax} of the {n_all} nominal initial "
            f"conditions "
            f"{'(every ~' + str(n_all // n_jax) + '-th) ' if n_jax < n_all else ''}"
            f"in JAX (run_batch, {int(out['steps'].sum())} strides, longest run "
            f"{int(out['steps'].max())}; {outcomes}); the twin on "
            f"{n_ref} of them, evenly spaced, {int(ref['steps'].sum())} strides, time scaled "
            f"per initial condition; per-run outcome and step count equal on "
            f"{same}/{n_ref}")
    return entry("slip_sweep", f"reference, {n_jax} ICs", warm, numpy_s, first - warm, note)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, help="where to write the results")
    parser.add_argument("--quick", action="store_true",
                        help="NumPy plan on a 1/20 subsample, fewer repeats (< 5 min)")
    parser.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1,
                        help="CPU devices to expose (default: one per core, as the jaxhop "
                        "command does; the JAX plan and sweeps spread chunks over them)")
    parser.add_argument("--only", default=None,
                        help="comma-separated names of the benchmarks to run (default: all)")
    args = parser.parse_args(argv)
    names = ("plan_build", "bhop_sweep", "decision", "slip_strides", "slip_table",
             "slip_deadbeat", "slip_decision", "slip_sweep")
    only = names if args.only is None else tuple(args.only.split(","))
    if unknown := set(only) - set(names):
        parser.error(f"--only: unknown {sorted(unknown)}; choose from {', '.join(names)}")
    jax.config.update("jax_enable_x64", True)
    try:  # must come before the backend starts; a no-op on GPU hosts
        jax.config.update("jax_num_cpu_devices", max(args.cpu_devices, 1))
    except (RuntimeError, AttributeError):
        pass
    t_start = time.perf_counter()
    results, todo = [], []

    def report(e):
        results.append(e)
        print(f"{e['name']:12s} {e['size']:28s} jax {e['jax_s']:10.6f} s  numpy "
              f"{e['numpy_s']:10.6f} s  x{e['speedup']:7.1f}  compile {e['compile_s']:.2f} s",
              flush=True)
        print(f"{'':12s} {e['note']}", flush=True)

    plan_entry, jp = None, None
    if "plan_build" in only:
        plan_entry, jp = bench_plan_build(args.quick)
        report(plan_entry)
    elif {"bhop_sweep", "decision", "slip_decision", "slip_sweep"} & set(only):
        jp = build_plan(builtin_terrain("reference"), progress=False)
    if "bhop_sweep" in only:
        report(bench_bhop_sweep(jp, args.quick))
    if "decision" in only:
        report(bench_decision(jp))
    if "slip_strides" in only:
        report(bench_slip_strides(args.quick))
    if "slip_table" in only:
        report(bench_slip_table())
    if "slip_deadbeat" in only:
        report(bench_slip_deadbeat(args.quick))
    if "slip_decision" in only:
        report(bench_slip_decision(jp))
    if "slip_sweep" in only:
        report(bench_slip_sweep(jp, args.quick))
    out = {"device": device_name(), "quick": args.quick, "benchmarks": results, "todo": todo}
    if plan_entry is not None:
        out["profile"] = {"jax_plan_stage_s": jp.stats.get("stage_seconds"),
                          "numpy_plan_stage_s": plan_entry.pop("stages")}
        print("plan stages (s): JAX", out["profile"]["jax_plan_stage_s"], flush=True)
    out["total_s"] = round(time.perf_counter() - t_start, 1)
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1)
    print(f"wrote {args.json} ({out['total_s']} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
