"""Robustness of the reactive controllers: sweep success under each disturbance and seed.

Runs `jaxhop sweep` (in this process, so compilation is shared) for every model, seed,
disturbance and controller asked for, and writes one JSON with the sweep summaries and a
table. The SLIP sweeps may run on a coarser grid (`--slip-step`, default 0.2 m: about 280
initial apexes on `reference`) because each SLIP stride is a nested deadbeat solve.

    python benchmarks/robustness.py --model bhop --seeds 0 1 2 \
        --out benchmarks/results/cpu2-robustness-bhop-2026-11.json
    python benchmarks/robustness.py --model slip --noise ground --seeds 0 1 2 3 4 5 6 7 8 9
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

NOISES = ("none", "wind", "sensor", "ground", "wind+sensor")


def sweep_one(model, noise, seed, controller, terrain, step, workdir, fresh=False):
    """One `jaxhop sweep`, in this process or (`fresh`) in a process of its own."""
    path = os.path.join(workdir, f"{model}-{noise}-{seed}-{controller}.json")
    argv = ["sweep", "--terrain", terrain, "--model", model, "--noise", noise,
            "--seed", str(seed), "--controller", controller, "--json", path]
    if step is not None:
        argv += ["--dy", str(step), "--dz", str(step)]
    t0 = time.perf_counter()
    if fresh:
        code = subprocess.call([sys.executable, "-m", "jaxhop", *argv])
    else:
        import jaxhop

        code = jaxhop.main(argv)
    if code != 0:
        raise SystemExit(f"jaxhop {' '.join(argv)} exited with {code}")
    with open(path) as f:
        out = json.load(f)
    out["wall_seconds"] = round(time.perf_counter() - t0, 1)
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="bhop", choices=("bhop", "slip"))
    p.add_argument("--terrain", default="reference")
    p.add_argument("--noise", nargs="+", default=list(NOISES))
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--controllers", nargs="+", default=["adaptive", "paper"])
    p.add_argument("--slip-step", type=float, default=0.2,
                   help="grid step (m) of the SLIP sweeps; 0.05 is the full grid")
    p.add_argument("--out", default=None, help="write the results as JSON here")
    p.add_argument("--fresh", action=argparse.BooleanOptionalAction, default=None,
                   help="run every sweep in a process of its own (default: for SLIP). Each "
                   "seed's plan has its own shapes, so the SLIP run loop compiles again "
                   "for each; in one process the fifth seed exhausted the memory maps that "
                   "XLA's CPU compiler asks for (vm.max_map_count 65 530). The compiled "
                   "programs cached on disk keep what a fresh process repeats to tracing.")
    args = p.parse_args(argv)

    import jax

    step = args.slip_step if args.model == "slip" else None
    fresh = args.model == "slip" if args.fresh is None else args.fresh
    meta = {"device": f"{os.cpu_count()}-core {platform.machine()} CPU",
            "jax": jax.__version__, "python": platform.python_version(),
            "grid_step": step or 0.05, "command": " ".join(sys.argv)}
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        for noise in args.noise:
            for seed in args.seeds:
                for controller in args.controllers:
                    r = sweep_one(args.model, noise, seed, controller, args.terrain, step,
                                  workdir, fresh)
                    rows.append(r)
                    fails = {k: v for k, v in r["failures"].items() if v}
                    print(f"{args.model:4s} {noise:12s} seed {seed} {controller:8s} "
                          f"n={r['n_initial_conditions']:5d} success={r['success_rate']:.4f} "
                          f"first-stride failures={r['first_stride_failures']} "
                          f"recoveries={r['recoveries']['total']} {fails} "
                          f"{r['wall_seconds']} s", flush=True)
                    # Written after every sweep: a crash later loses nothing finished.
                    if args.out:
                        with open(args.out, "w") as f:
                            json.dump({"meta": meta, "runs": rows}, f, indent=1)


if __name__ == "__main__":
    main()
