"""`parkour --planner reactive` (and `--planner mppc --noise ...`): issue 8."""

from __future__ import annotations

import json
import sys

from .._errors import InputError


def run_parkour(args, course, write) -> int:
    """Run the reactive planner (or MPPC under a disturbance) and report like `parkour`."""
    noise = getattr(args, "noise", "none")
    if getattr(args, "plot", None):
        raise InputError("--plot: only with --planner mppc and --noise none")
    seed = int(getattr(args, "seed", 0))
    runs = int(getattr(args, "runs", 1))
    if runs < 1 or runs > 4096:
        raise InputError(f"--runs: must be in [1, 4096], got {runs}")
    if getattr(args, "planner", "mppc") == "reactive":
        from ._api import reactive_parkour

        out = reactive_parkour(course, model=getattr(args, "model", "bhop"), noise=noise,
                               seed=seed, runs=runs,
                               align=getattr(args, "segments", "lattice") == "lattice",
                               log=lambda m: print(m, file=sys.stderr))
    else:
        from ._mppc_noise import run_mppc_noisy

        out = run_mppc_noisy(course, noise, seed)
    out["final_snapshot"] = bool(getattr(args, "final_snapshot", False))
    status = "finished" if out["finished"] else f"NOT finished ({out['failure']})"
    print(f"{course.name} [{out['planner']}, noise {noise}]: {status}, {out['jumps']} jumps, "
          f"flight time {out['flight_time']:.3f} s, {out['violations']} violations")
    ms = out["replan_ms"]
    if ms["median"] is not None:
        what = "decision" if out["planner"] == "reactive" else "replan"
        print(f"{what} ms (warm): min {ms['min']:.3f}, median {ms['median']:.3f}, "
              f"max {ms['max']:.3f}")
    if out["planner"] == "reactive":
        print(f"success rate {out['success_rate']:.3f} over {out['runs']} runs; plan built in "
              f"{out['build_s']:.1f} s; {out['n_snapshots']} snapshot updates")
    if getattr(args, "json", None):
        write(args.json, lambda f: json.dump(out, f, indent=1), "--json")
    return 0
