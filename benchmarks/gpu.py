"""The reference sweeps and the plan build on a GPU against two CPU cores of the same
machine, in one run (`benchmarks/gpu.sh` starts it).

Two processes run side by side on disjoint cores: one on the GPU (every core but the
first two), one with `JAX_PLATFORMS=cpu` pinned to the first two cores, so that the CPU
baseline is the 2-core CPU that the other benchmarks use. Each process loads the cached
`reference` plans (BHop, and SLIP on the SLIP-adjusted templates) and the SLIP table,
times the BHop plan build twice, then for each model runs the sweep once cold (compiling;
only `--cold-runs` states) and `--repeats` times warm on the whole grid, the way
`jaxhop sweep --terrain reference --model M` runs it. The outcomes (codes and strides) of
the two processes are compared run by run.

    python benchmarks/gpu.py --json benchmarks/results/h200-gpu-2026-11.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

_CHILD = r"""
import json, sys, time
import jax, numpy as np, jaxhop
models, repeats, cold_runs = sys.argv[1].split(","), int(sys.argv[2]), int(sys.argv[3])
out = {"backend": jax.default_backend(), "device": str(jax.devices()[0].device_kind),
       "n_devices": len(jax.devices()), "jax": jax.__version__, "plan_build_s": [],
       "sweeps": {}}
terrain = jaxhop.builtin_terrain("reference")
for _ in range(2):
    t0 = time.perf_counter()
    jaxhop.build_plan(terrain, progress=False)
    out["plan_build_s"].append(round(time.perf_counter() - t0, 3))
    print("plan_build_s", out["plan_build_s"][-1], file=sys.stderr, flush=True)
for model in models:
    plan = jaxhop.get_plan(terrain, templates=jaxhop.templates_for(model), progress=False)
    settings = jaxhop.RunSettings(model=model)
    def sweep(runs):
        t0 = time.perf_counter()
        summary, init, r = jaxhop.sweep(plan, settings, key=jax.random.key(0),
                                        initial=jaxhop.SweepGrid(runs=runs))
        t = time.perf_counter() - t0
        print(model, runs, round(t, 3), summary["success_rate"], file=sys.stderr, flush=True)
        return t, summary, r
    cold, _, _ = sweep(cold_runs)
    warm = []
    for _ in range(repeats):
        t, summary, r = sweep(None)
        warm.append(round(t, 3))
    out["sweeps"][model] = {"cold_s": round(cold, 3), "cold_runs": cold_runs,
                            "warm_s": min(warm), "all_warm_s": warm, "summary": summary,
                            "code": r["code"].tolist(), "steps": r["steps"].tolist()}
print(json.dumps(out))
"""


def _start(platform_: str, cores: str, models: list[str], repeats: int, cold_runs: int,
           log: str):
    env = dict(os.environ)
    env["JAX_COMPILATION_CACHE_DIR"] = f"/tmp/jaxhop-gpu-bench-xla-{platform_}"
    if platform_ == "cpu":
        env["JAX_PLATFORMS"] = "cpu"
    cmd = ["taskset", "-c", cores, sys.executable, "-c", _CHILD, ",".join(models),
           str(repeats), str(cold_runs)]
    stderr_log = open(log, "w")
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=stderr_log, text=True)
    proc.stderr_log = stderr_log
    return proc


def _cores() -> int:
    return len(os.sched_getaffinity(0))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True)
    parser.add_argument("--models", nargs="+", default=["bhop", "slip"])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--cold-runs", type=int, default=256)
    args = parser.parse_args(argv)
    n = _cores()
    if n < 4:
        parser.error(f"needs at least 4 cores (2 for the CPU baseline), found {n}")
    logdir = os.path.dirname(os.path.abspath(args.json))
    t0 = time.perf_counter()
    procs = {p: _start(p, c, args.models, args.repeats, args.cold_runs,
                       os.path.join(logdir, f"gpu-bench-{p}.log"))
             for p, c in (("gpu", f"2-{n - 1}"), ("cpu", "0,1"))}
    results = {}
    for name, proc in procs.items():
        stdout, _ = proc.communicate()
        proc.stderr_log.close()
        if proc.returncode:
            print(f"{name} process failed ({proc.returncode}); see its log", file=sys.stderr)
            return 1
        results[name] = json.loads(stdout.strip().splitlines()[-1])
    gpu, cpu = results["gpu"], results["cpu"]
    if gpu["backend"] == "cpu":
        print("no GPU: JAX's default backend is the CPU", file=sys.stderr)
    report = {
        "device": gpu["device"],
        "cpu_baseline": "the same machine's CPU, JAX_PLATFORMS=cpu, pinned to 2 cores",
        "host": {"cores": n, "python": platform.python_version(), "jax": gpu["jax"]},
        "wall_s": round(time.perf_counter() - t0, 1),
        "plan_build_s": {"gpu": gpu["plan_build_s"], "cpu2": cpu["plan_build_s"]},
        "sweeps": {},
    }
    for model in args.models:
        g, c = gpu["sweeps"][model], cpu["sweeps"][model]
        report["sweeps"][model] = {
            "gpu": {k: g[k] for k in ("cold_s", "warm_s", "all_warm_s")},
            "cpu2": {k: c[k] for k in ("cold_s", "warm_s", "all_warm_s")},
            "speedup_warm": round(c["warm_s"] / g["warm_s"], 2),
            "same_outcomes": g["code"] == c["code"] and g["steps"] == c["steps"],
            "summary_gpu": g["summary"], "summary_cpu2": c["summary"],
        }
    with open(args.json, "w") as f:
        json.dump(report, f, indent=1)
    for model, s in report["sweeps"].items():
        print(f"{model}: warm {s['gpu']['warm_s']} s on the GPU, {s['cpu2']['warm_s']} s on "
              f"2 CPU cores ({s['speedup_warm']}x); same outcomes: {s['same_outcomes']}")
    print(f"plan build: {report['plan_build_s']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
