"""BHop sweeps on one CPU device against several forced CPU devices
(`docs/scaling.md`, "CPUs").

Each device count runs in its own process (XLA reads `--xla_force_host_platform_device_count`
once, at start-up). Every process loads the same cached plan for `reference`, runs each sweep
once cold, then `--repeats` times warm, and reports the minimum warm time. The outcomes of all
device counts are compared run by run.

    python benchmarks/devices.py --json devices.json [--devices 1 2 4] [--noise none wind]
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
noises, repeats = sys.argv[1].split(","), int(sys.argv[2])
plan = jaxhop.get_plan(jaxhop.builtin_terrain("reference"), progress=False)
grid = jaxhop.sweep_grid(plan.terrain)
init = grid[jaxhop.in_global_domain(grid, plan.tables(), plan.hopper)]
out = {"devices": len(jax.devices()), "n": int(init.shape[0]), "sweeps": {}}
for noise in noises:
    dist = jaxhop.disturbance_for(noise)
    def sweep():
        return jaxhop.run_batch(plan, init, jaxhop.RunSettings(controller="paper"),
                                key=jax.random.key(0), disturbance=dist)
    t0 = time.perf_counter(); r = sweep(); cold = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter(); r = sweep(); warm.append(time.perf_counter() - t0)
    out["sweeps"][noise] = {"cold_s": cold, "warm_s": min(warm), "all_warm_s": warm,
                            "success": float(np.mean(r["code"] == 0)),
                            "code": r["code"].tolist(), "steps": r["steps"].tolist()}
print(json.dumps(out))
"""


def _child(n_devices: int, noises: list[str], repeats: int) -> dict:
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n_devices}",
               JAXHOP_CPU_DEVICES=str(n_devices))
    out = subprocess.run([sys.executable, "-c", _CHILD, ",".join(noises), str(repeats)],
                         env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True)
    parser.add_argument("--devices", type=int, nargs="+", default=[1, 4])
    parser.add_argument("--noise", nargs="+", default=["none", "sensor", "wind"])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    runs = {n: _child(n, args.noise, args.repeats) for n in args.devices}
    base = runs[args.devices[0]]
    rows = []
    for noise in args.noise:
        for n in args.devices:
            s = runs[n]["sweeps"][noise]
            same = (s["code"] == base["sweeps"][noise]["code"]
                    and s["steps"] == base["sweeps"][noise]["steps"])
            rows.append({"noise": noise, "devices": n, "size": runs[n]["n"],
                         "warm_s": s["warm_s"], "cold_s": s["cold_s"],
                         "success": s["success"],
                         "speedup_vs_first": base["sweeps"][noise]["warm_s"] / s["warm_s"],
                         "same_outcomes_as_first": same})
            print(f"{noise:7s} {n} device(s): warm {s['warm_s']:.3f} s  "
                  f"(x{rows[-1]['speedup_vs_first']:.2f})  success {s['success']:.3f}  "
                  f"identical={same}")
    result = {"device": f"cpu ({os.cpu_count()} cores, {platform.machine()})",
              "load_average_before": load0, "load_average_after": os.getloadavg()[0],
              "total_s": time.perf_counter() - t0, "rows": rows}
    with open(args.json, "w") as fh:
        json.dump(result, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
