"""Redraw times of the notebook explorers (`jaxhop.explore`, `jaxhop.explore_stride`).

    python benchmarks/explore.py --json benchmarks/results/cpu2-explore-2026-11.json

A redraw is what one widget change costs, timed from setting the value to the new PNG in
the image widget: the computation (a `run_batch` run on the `reference` plan, one
`stride_path`, one `deadbeat_slip` plus the stride it gives), the artists' update and the
Agg rendering. Each kind is timed over `--repeats` changes to distinct values after the
explorer is built (building compiles everything, `build_s`); the minimum, median and
maximum are recorded, with the device, the jax version and the load average (`uptime`)
before and after. No change may trace or compile: the script counts JAX's trace and
compile events and fails if one happens.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time

import jax
import numpy as np

import jaxhop

EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/backend_compile_duration")


def timed(change, values, after=None) -> list[float]:
    """Seconds of `change(v)` for each value; `after()` (untimed) after each."""
    out = []
    for v in values:
        t0 = time.perf_counter()
        change(v)
        out.append(time.perf_counter() - t0)
        if after is not None:
            after()
    return out


def stats(times: list[float], bound: float) -> dict:
    return {"min_s": min(times), "median_s": float(np.median(times)), "max_s": max(times),
            "n": len(times), "bound_s": bound, "within": max(times) <= bound}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)
    uptime = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    load_before = os.getloadavg()
    events = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: events.append(event) if event in EVENTS else None)
    rng = np.random.default_rng(0)
    n = args.repeats

    plan = jaxhop.get_plan(jaxhop.builtin_terrain("reference"), progress=False)
    t0 = time.perf_counter()
    ex = jaxhop.explore(plan, [0.6, 1.6, 0.5])
    build_plan_explorer = time.perf_counter() - t0
    t0 = time.perf_counter()
    st = jaxhop.explore_stride()
    build_stride_explorer = time.perf_counter() - t0
    compiled_at_build = len(events)

    def set_apex(v):
        ex.set(y=v[0], z=v[1], ydot=v[2])

    def set_options(v):
        ex.set(noise=v[0], seed=v[1], controller=v[2])

    def set_target(v):
        st.set(target_y=v[0], target_z=v[1], target_ydot=v[2])
        st.controls["deadbeat"].click()

    apexes = np.stack([rng.uniform(0.4, 1.2, n), rng.uniform(1.5, 1.9, n),
                       rng.uniform(0.3, 0.7, n)], 1)
    options = [(("none", "wind", "sensor", "wind+sensor")[i % 4], i % 10,
                ("adaptive", "paper")[i // 4 % 2]) for i in range(n)]
    targets = np.stack([rng.uniform(0.55, 0.9, n), rng.uniform(1.25, 1.35, n),
                        rng.uniform(0.7, 1.3, n)], 1)
    events.clear()
    steps, errors = [], []
    runs = timed(set_apex, apexes, lambda: steps.append(int(ex.result["steps"])))
    runs += timed(set_options, options, lambda: steps.append(int(ex.result["steps"])))
    policy = timed(lambda k: setattr(ex.controls["policy"], "value", int(k)),
                   rng.integers(0, len(plan.order), n))
    stride = timed(lambda th: st.set(th=float(th)), rng.uniform(0.0, 0.25, n))
    deadbeat = timed(set_target, targets, lambda: errors.append(
        (st.result["deadbeat"]["ok"], st.result["deadbeat"]["error"])))
    if events:
        raise SystemExit(f"a value change traced or compiled: {len(events)} events")
    result = {
        "device": f"{jax.devices()[0].platform} x{len(jax.devices())} ({os.cpu_count()} cores, "
                  f"{platform.machine()})",
        "jax": jax.__version__,
        "uptime_before": uptime,
        "uptime_after": subprocess.run(["uptime"], capture_output=True, text=True)
        .stdout.strip(),
        "load_before": list(load_before),
        "load_after": list(os.getloadavg()),
        "plan": "reference",
        "build_s": {"explore": build_plan_explorer, "explore_stride": build_stride_explorer},
        "traces_and_compiles": {"at_build": compiled_at_build, "on_changes": len(events)},
        "redraw": {
            "bhop_run": stats(runs, 0.3),
            "policy": stats(policy, 0.3),
            "slip_stride": stats(stride, 0.3),
            "slip_deadbeat": stats(deadbeat, 0.5),
        },
        "bhop_run_strides": {"min": min(steps), "max": max(steps)},
        "deadbeat_within_limits": sum(ok for ok, _ in errors),
        "deadbeat_errors": [e for _, e in errors],
    }
    print(json.dumps(result, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
            f.write("\n")
    return result


if __name__ == "__main__":
    main()
