"""Reactive planner (BHop, SLIP) against jaxhop's MPPC on the parkour courses
(docs/parkour_reactive.md).

For every course: the reactive plan for the MPPC leg (`jaxhop.parkour`), its incremental
updates at the snapshots (optionally timed against full rebuilds), then seeded runs of
both planners with no disturbance, wind, sensor noise and landing-position noise.

    python benchmarks/parkour_compare.py --json parkour.json --markdown parkour.md
    python benchmarks/parkour_compare.py --courses mppc-sim-1 --runs 8 --models bhop

Reactive runs start from seeded apexes near the start that the plan covers (rejection
sampling; `coverage` is the covered fraction of the sampling box). MPPC is deterministic
without a disturbance (one run); with one, `--mppc-seeds` seeded runs. Success: the goal
reached with no violation (restricted area, margin, collision). Times are wall-clock on
the machine named in the output; `update` is the incremental plan update after a
snapshot, `full` the full build of the course's first environment (and `rebuild` full
rebuilds of snapshots, where asked).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import sys
import time

import jax
import numpy as np

import jaxhop  # noqa: F401  (float64)
from jaxhop.mppc import list_courses, load_course
from jaxhop.parkour import (
    CourseRuns,
    course_plans,
    leg_hopper,
    leg_templates,
    reactive_parkour,
    run_mppc_noisy,
)

NOISES = ("none", "wind", "sensor", "landing")


def device_name() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    devs = ", ".join(sorted({d.platform for d in jax.devices()}))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{cpu}, {os.cpu_count()} cores visible, JAX {jax.__version__} on {devs}, "
            f"load average {load:.1f} at start")


def _plans(course, hop, tm, rebuild, cache_dir, log, align=True, model="bhop"):
    path = None
    tag = ("-lattice" if align else "-centred") + ("" if model == "bhop" else f"-{model}")
    if cache_dir:
        os.makedirs(cache_dir, exist_ok=True)
        path = os.path.join(cache_dir, f"{course.name}{tag}-r{rebuild}.pkl")
        for r in (rebuild, 1, 0):  # any cached build of this course will do for timing
            alt = os.path.join(cache_dir, f"{course.name}{tag}-r{r}.pkl")
            if os.path.exists(alt) and (r == rebuild or rebuild == 0):
                with open(alt, "rb") as f:
                    return pickle.load(f)
    cps = course_plans(course, hop, tm, rebuild=rebuild, log=log, align=align)
    if path:
        with open(path, "wb") as f:
            pickle.dump(cps, f)
    return cps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--courses", default=",".join(list_courses()))
    ap.add_argument("--noise", default=",".join(NOISES))
    ap.add_argument("--models", default="bhop,slip")
    ap.add_argument("--planners", default="reactive,mppc")
    ap.add_argument("--controllers", default="adaptive,paper",
                    help="reactive controllers (`jaxhop.RunConfig`): adaptive, paper")
    ap.add_argument("--runs", type=int, default=16, help="reactive BHop runs per setting")
    ap.add_argument("--slip-runs", type=int, default=4, help="reactive SLIP runs per setting")
    ap.add_argument("--slip-noise", default="none", help="disturbances for SLIP runs")
    ap.add_argument("--mppc-seeds", type=int, default=8)
    ap.add_argument("--rebuild", default="mppc-hw-dynamic-1,mppc-hw-disturbances",
                    help="courses whose first snapshot is also rebuilt in full (with "
                    "--timing: which snapshots to rebuild: `all`, the first N, `worstK`, "
                    "the K slowest updates, or a list `1:3:4`)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", default=None, help="directory to keep built plans in")
    ap.add_argument("--json")
    ap.add_argument("--markdown")
    ap.add_argument("--merge", nargs="+", metavar="JSON",
                    help="only merge the JSON outputs of earlier runs into one table")
    ap.add_argument("--centred", dest="align", action="store_false",
                    help="every block's segments centred (`course_map(..., align=False)`); "
                         "default: floor segments flush with the lattice")
    ap.add_argument("--repeat", type=int, default=3,
                    help="--timing: timed passes over the update chain (median per snapshot)")
    ap.add_argument("--timing", action="store_true",
                    help="only time incremental updates against full rebuilds (warm), for the "
                         "leg's templates of the first of --models")
    args = ap.parse_args(argv)
    if args.timing:
        return timing(args)
    if args.merge:
        parts = [json.load(open(p)) for p in args.merge]
        out = {"device": parts[0]["device"], "rows": [], "plans": []}
        seen = set()
        for p in parts:
            out["rows"] += p["rows"]
            for q in p["plans"]:
                if q["course"] not in seen:
                    seen.add(q["course"])
                    out["plans"].append(q)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=1)
        text = markdown(out)
        if args.markdown:
            with open(args.markdown, "w") as f:
                f.write(text)
        print(text)
        return 0

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    hop = leg_hopper()
    tm = leg_templates(hop)
    out = {"device": device_name(), "hopper": {"m": hop.m, "g": hop.g, "rho0": hop.rho0},
           "n_templates": tm.n, "rows": [], "plans": []}
    planners = args.planners.split(",")
    for name in args.courses.split(","):
        course = load_course(name)
        if "reactive" in planners:
            for model in args.models.split(","):
                # The SLIP runs on the leg's SLIP templates (`leg_templates(model="slip")`),
                # whose plans are full builds at every snapshot.
                slip = model != "bhop"
                rebuild = 1 if (name in args.rebuild.split(",") and course.snapshots
                                and not slip) else 0
                tm_m = leg_templates(hop, model=model)
                t0 = time.perf_counter()
                cps = _plans(course, hop, tm_m, rebuild, args.cache, log, args.align, model)
                out["plans"].append({
                    "course": name, "model": model, "n_snapshots": len(cps.plans) - 1,
                    "n_policies": [int(cp.stats["n_instantiated"]) for cp in cps.plans],
                    "full_s": cps.build_s, "update_s": cps.update_s,
                    "update_cpu_s": cps.update_cpu_s, "rebuild_s": cps.rebuild_s,
                    "rebuild_cpu_s": cps.rebuild_cpu_s, "rebuild_equal": cps.rebuild_equal,
                    "recomputed_pairs": [int(cp.stats["recomputed_pairs"])
                                         for cp in cps.plans],
                    "stage_seconds": [cp.stats["stage_seconds"] for cp in cps.plans],
                    "seconds": time.perf_counter() - t0})
                noises = args.slip_noise.split(",") if slip else args.noise.split(",")
                runs = args.slip_runs if slip else args.runs
                for controller in args.controllers.split(","):
                    for noise in noises:
                        if not noise:
                            continue
                        t0 = time.perf_counter()
                        settings = CourseRuns(model=model, controller=controller, noise=noise,
                                              seed=args.seed, runs=runs)
                        r = reactive_parkour(course, settings, hopper=hop, templates=tm_m,
                                             plans=cps)
                        r.pop("executed")
                        r["seconds"] = time.perf_counter() - t0
                        out["rows"].append(r)
                        log(f"{name} reactive/{model}/{controller}/{noise}: success "
                            f"{r['success_rate']:.2f}, {r['mean_jumps']} jumps, "
                            f"{r['seconds']:.0f} s")
        if "mppc" in planners:
            for noise in args.noise.split(","):
                seeds = [0] if noise == "none" else range(args.mppc_seeds)
                res = [run_mppc_noisy(course, noise, args.seed + s) for s in seeds]
                ok = [r for r in res if r["success"]]
                ms = np.concatenate([[r["replan_ms"]["median"]] for r in res
                                     if r["replan_ms"]["median"] is not None])
                out["rows"].append({
                    "course": name, "planner": "mppc", "model": "leg", "noise": noise,
                    "runs": len(res), "success_rate": len(ok) / len(res),
                    "mean_jumps": float(np.mean([r["jumps"] for r in ok])) if ok else None,
                    "mean_flight_time": (float(np.mean([r["flight_time"] for r in ok]))
                                         if ok else None),
                    "replan_ms": {"median": float(np.median(ms)) if ms.size else None,
                                  "max": max(r["replan_ms"]["max"] or 0 for r in res)},
                    "violations": int(sum(r["violations"] for r in res)),
                    "failures": sorted({r["failure"] for r in res if r["failure"]}),
                })
                log(f"{name} mppc/{noise}: success {len(ok)}/{len(res)}")
        if args.json:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=1)
    if args.markdown:
        with open(args.markdown, "w") as f:
            f.write(markdown(out))
    print(markdown(out))
    return 0


def timing(args) -> int:
    """Per dynamic course: the update chain, after an untimed warm-up chain so that no
    compilation is timed (`--repeat` timed passes, the median per snapshot), and full
    rebuilds of the snapshots (`--rebuild N`: the first N, `all`: every one, `worstK`: the
    K slowest updates, `1:3:4`: those; each after an untimed build with the same padded
    shapes, so that none includes compilation): wall and CPU time, the ratio per snapshot,
    and whether each rebuild is identical to the update (`identical_plans`)."""
    from jaxhop.parkour import (
        COURSE_GRID,
        build_course_plan,
        build_shape,
        course_map,
        identical_plans,
    )

    hop = leg_hopper()
    model = args.models.split(",")[0]
    tm = leg_templates(hop, model=model)
    out = {"device": device_name(), "align": args.align, "model": model, "courses": []}
    if args.json and os.path.exists(args.json):  # resume: keep the courses measured before
        with open(args.json) as f:
            out["courses"] = json.load(f).get("courses", [])
    done = {c["course"] for c in out["courses"]}
    for name in args.courses.split(","):
        course = load_course(name)
        if not course.snapshots or name in done:
            continue
        cps = _plans(course, hop, tm, 0, args.cache, print, args.align, model)
        maps = [course_map(course, env, hop, align=args.align) for _, env in course.snapshots]
        base = cps.plans[0]
        prev = base
        for m in maps:  # warm-up: compiles every chunk size the updates use
            prev = build_course_plan(m, tm, hop, grid=COURSE_GRID, previous=prev)
        walls, cpus = [], []
        for _ in range(max(int(args.repeat), 1)):  # the chain again: medians per snapshot
            wall, cpu, plans, prev = [], [], [], base
            for m in maps:
                t0, c0 = time.perf_counter(), time.process_time()
                prev = build_course_plan(m, tm, hop, grid=COURSE_GRID, previous=prev)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
                plans.append(prev)
            walls.append(wall)
            cpus.append(cpu)
        wall = np.median(walls, axis=0).tolist()
        cpu = np.median(cpus, axis=0).tolist()
        picked = _rebuilt(args.rebuild, cpu)
        rb_wall, rb_cpu, equal, rb_stages, shapes = [], [], [], [], set()
        for k in picked:
            m, inc = maps[k], plans[k]
            shape = build_shape(m, tm, hop)
            if shape not in shapes:  # compile the full build's chunk sizes for these shapes
                build_course_plan(m, tm, hop, grid=COURSE_GRID)
                shapes.add(shape)
            t0, c0 = time.perf_counter(), time.process_time()
            full = build_course_plan(m, tm, hop, grid=COURSE_GRID)
            rb_wall.append(time.perf_counter() - t0)
            rb_cpu.append(time.process_time() - c0)
            equal.append(identical_plans(full, inc))
            rb_stages.append(full.stats["stage_cpu_seconds"])
            print(f"{name} snapshot {k + 1}: update {wall[k]:.2f} s (cpu {cpu[k]:.2f}), rebuild "
                  f"{rb_wall[-1]:.1f} s (cpu {rb_cpu[-1]:.1f}), ratio {rb_wall[-1] / wall[k]:.1f} "
                  f"(cpu {rb_cpu[-1] / cpu[k]:.1f}), identical {equal[-1]}", flush=True)
        row = {"course": name, "n_snapshots": len(maps), "repeat": len(walls),
               "update_s_all": walls, "update_cpu_s_all": cpus,
               "n_policies": int(base.stats["n_instantiated"]),
               "update_s": wall, "update_cpu_s": cpu,
               "rebuilt": [k + 1 for k in picked], "rebuild_s": rb_wall,
               "rebuild_cpu_s": rb_cpu, "rebuild_equal": equal,
               "ratio": [rb_wall[n] / wall[k] for n, k in enumerate(picked)],
               "ratio_cpu": [rb_cpu[n] / cpu[k] for n, k in enumerate(picked)],
               "rebuild_stage_cpu_s": rb_stages,
               "recomputed_pairs": [int(p.stats["recomputed_pairs"]) for p in plans],
               "new_situated": [int(p.stats["new_situated"]) for p in plans],
               "recomputed_robustness": [int(p.stats["recomputed_robustness"]) for p in plans],
               "recomputed_probes": [int(p.stats["recomputed_probes"]) for p in plans],
               "update_stage_cpu_s": [p.stats["stage_cpu_seconds"] for p in plans]}
        out["courses"].append(row)
        print(f"{name}: update median {np.median(wall):.2f} s (cpu {np.median(cpu):.2f}), "
              f"max {max(wall):.2f} s (cpu {max(cpu):.2f}); rebuild {np.mean(rb_wall):.1f} s "
              f"(cpu {np.mean(rb_cpu):.1f}); min ratio {min(row['ratio'], default=0):.1f} "
              f"(cpu {min(row['ratio_cpu'], default=0):.1f}); identical {equal}", flush=True)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=1)
    return 0


def _rebuilt(spec: str, update_cpu: list) -> list:
    """Snapshots (0-based) to rebuild for `--timing --rebuild spec`: `all`, the first `N`,
    `worstK`, the K whose updates took the most CPU time (the lowest ratios, as a course's
    rebuilds cost about the same), or a list `a:b:c` of snapshots (1-based)."""
    n = len(update_cpu)
    if spec == "all":
        return list(range(n))
    if ":" in spec:
        return sorted({int(k) - 1 for k in spec.split(":") if k and 0 < int(k) <= n})
    if spec.startswith("worst"):
        k = int(spec[5:] or 1)
        return sorted(int(i) for i in np.argsort(update_cpu)[::-1][:k])
    return list(range(min(int(spec) if spec.isdigit() else 1, n)))


def _failures(r) -> str:
    f = r.get("failures")
    if isinstance(f, dict):
        return ", ".join(f"{k} {v}" for k, v in f.items() if v) or "-"
    if f:  # MPPC: failure messages of unfinished runs, and violations
        kinds = sorted({m.split(" at ")[0] for m in f})
        return "; ".join(kinds) + (f"; {r['violations']} violations" if r["violations"] else "")
    return f"{r['violations']} violations" if r.get("violations") else "-"


def _fmt(x, spec=".2f"):
    return "-" if x is None else format(x, spec)


def markdown(out: dict) -> str:
    lines = [f"Device: {out['device']}.", "",
             "| course | planner | noise | runs | success | jumps | time s | "
             "decision / replan ms (median) | failures |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in out["rows"]:
        who = r["planner"] + ("" if r["planner"] == "mppc" else
                              f" {r['model']} {r.get('controller', 'paper')}")
        lines.append(f"| {r['course']} | {who} | {r['noise']} | {r['runs']} | "
                     f"{r['success_rate']:.2f} | {_fmt(r['mean_jumps'], '.1f')} | "
                     f"{_fmt(r['mean_flight_time'])} | {_fmt(r['replan_ms']['median'], '.3f')} | "
                     f"{_failures(r)} |")
    lines += ["", "| course | snapshots | policies | full build s | update s (median / max) | "
              "rebuild s | rebuild / update | update = rebuild |",
              "|---|---|---|---|---|---|---|---|"]
    for p in out["plans"]:
        up = p["update_s"]
        med = float(np.median(up)) if up else None
        reb = p["rebuild_s"][0] if p["rebuild_s"] else None
        ratio = (reb / up[0]) if (reb and up) else None
        lines.append(f"| {p['course']} | {p['n_snapshots']} | {p['n_policies'][0]} | "
                     f"{p['full_s']:.1f} | {_fmt(med)} / {_fmt(max(up) if up else None)} | "
                     f"{_fmt(reb, '.1f')} | {_fmt(ratio, '.1f')} | "
                     f"{'yes' if all(p['rebuild_equal']) and p['rebuild_equal'] else '-'} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
