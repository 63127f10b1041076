"""MPPC replan benchmark: jaxhop beside the original planner (Drake + SNOPT) on every course.

Each course is run as given (snapshots replayed) and with `--final-snapshot`. Every run
warms up once (one untimed replan, which compiles the padded shapes), then times each
replan of the whole receding-horizon loop with `block_until_ready` semantics (results are
pulled to the host). Runs are deterministic, so each course is run `--repeats` times and
every replan's time is the minimum over the repeats (the single-run numbers are kept in
the JSON). The original's numbers come from `mppc_reference_results.json`, measured on a
2-core machine of the development kind.

    python benchmarks/mppc_replan.py [--json PATH] [--random N] [--grid 0.02] [--repeats 3]
"""

import argparse
import json
import os
import time

import numpy as np

from jaxhop.mppc import (
    MPPC,
    EnvData,
    Settings,
    list_courses,
    load_course,
    random_course,
    reference_results,
    run_course,
)


def _row(name, mode, out, ref):
    ms = out["replan_ms"]
    fin = "yes" if out["finished"] else "NO"
    line = (f"{name:22s} {mode:6s} | {fin:3s} {out['jumps']:3d} {out['flight_time']:8.3f} "
            f"{ms['median']:7.2f} {ms['max']:7.2f} {out['violations']:4d} |")
    if ref is None:
        return line + "  (no reference)"
    rfin = "yes" if ref["finished"] else "NO"
    rms = ref["replan_ms"]
    dt = 100 * (out["flight_time"] / ref["flight_time_s"] - 1) if ref["finished"] else float("nan")
    return line + (f" {rfin:3s} {ref['jumps']:3d} {ref['flight_time_s']:8.3f} "
                   f"{rms['median']:7.2f} {rms['max']:8.2f} | {dt:+6.2f}%")


def _timed(course, planner, repeats):
    # Runs are deterministic (same jumps every time), so each replan is repeated: its
    # time is the minimum over the repeats, which removes other processes' interference.
    results = [run_course(course, planner) for _ in range(repeats)]
    first = results[0].to_json()
    for r in results[1:]:
        assert [j.x1 for j in r.executed] == [j.x1 for j in results[0].executed]
    ms = np.min([r.replan_ms for r in results], axis=0)
    out = dict(first)
    out["replan_ms_single_run"] = first["replan_ms"]
    out["replan_ms"] = {"min": float(ms.min()), "median": float(np.median(ms)),
                        "max": float(ms.max())}
    return out


def run_shipped(planner, repeats):
    refs = {(r["course"], r["mode"]): r for r in reference_results()["results"]}
    head = (f"{'course':22s} {'mode':6s} | {'jaxhop: fin':>3s} {'J':>3s} {'flight':>8s} "
            f"{'med ms':>7s} {'max ms':>7s} {'viol':>4s} | orig: fin   J   flight  med ms"
            f"   max ms | flight vs orig")
    print(head)
    print("-" * len(head))
    rows = []
    for name in list_courses():
        for mode in ("as_given", "final_snapshot_static"):
            course = load_course(name)
            if mode != "as_given":
                course = course.final()
            out = _timed(course, planner, repeats)
            ref = refs.get((name, mode))
            print(_row(name, "given" if mode == "as_given" else "final", out, ref), flush=True)
            rows.append({"course": name, "mode": mode, "jaxhop": {
                k: out[k] for k in ("finished", "jumps", "flight_time", "replan_ms",
                                    "replan_ms_single_run", "violations", "failure")},
                "original": ref})
    return rows


def run_random(planner, n):
    """Random courses: finished rate, and every course the exhaustive search can cross."""
    finished, crossable, missed, violations = 0, 0, [], 0
    t0 = time.perf_counter()
    for seed in range(n):
        course = random_course(seed)
        env = course.environment
        reach = EnvData(MPPC(planner.robot, Settings(grid=planner.settings.grid,
                                                      dead_ends="always")), course, env).reach
        result = run_course(course, planner)
        finished += result.finished
        crossable += bool(reach[0])
        violations += len(result.violations)
        if reach[0] and not result.finished:
            missed.append(seed)
    summary = {"courses": n, "finished": finished, "finished_rate": finished / n,
               "exhaustive_reaches_goal": crossable, "reachable_but_not_finished": missed,
               "violations": violations, "seconds": time.perf_counter() - t0}
    print(f"\nrandom courses: {n}, finished {finished} ({100 * finished / n:.1f} %), "
          f"exhaustive grid search reaches the goal on {crossable}, of which not finished: "
          f"{len(missed)} {missed if missed else ''}; violations {violations}")
    return summary


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", metavar="PATH", help="write all numbers here")
    parser.add_argument("--grid", type=float, default=Settings.grid)
    parser.add_argument("--random", type=int, default=0, metavar="N",
                        help="also run N seeded random courses")
    parser.add_argument("--repeats", type=int, default=3,
                        help="runs per course; each replan's time is the minimum over them")
    args = parser.parse_args()
    planner = MPPC(settings=Settings(grid=args.grid))
    print(f"jaxhop MPPC, grid {args.grid} m, {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.2f}; replan times: per replan the minimum over "
          f"{args.repeats} identical runs, after one warm-up\n")
    rows = run_shipped(planner, args.repeats)
    out = {"grid": args.grid, "cpus": os.cpu_count(), "repeats": args.repeats,
           "load_average": os.getloadavg()[0], "courses": rows}
    ms = np.array([r["jaxhop"]["replan_ms"]["median"] for r in rows])
    mx = np.array([r["jaxhop"]["replan_ms"]["max"] for r in rows])
    print(f"\nreplan median over runs: worst {ms.max():.2f} ms; replan max: worst "
          f"{mx.max():.2f} ms")
    if args.random:
        out["random"] = run_random(planner, args.random)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
