"""`jaxhop parkour`: MPPC or the 2012 reactive planner on a parkour course.

`--planner mppc` runs the receding-horizon planner of Albracht et al. (docs/mppc.md),
executing each planned first jump exactly, or under a disturbance with `--noise`;
`--planner reactive` runs the reactive planner of Arslan & Saranli (2012) on the course
turned into a terrain (docs/parkour_reactive.md).
"""

from __future__ import annotations

import sys

from .._core import validate as v
from .._core.errors import InputError
from .._core.params import check_noise
from ..mppc._cli import check_grid, run_mppc, write_json
from ..mppc._course import list_courses, load_course
from ..mppc._plan import Settings

MAX_RUNS = 4096
PLANNERS = ("mppc", "reactive")
#: `--noise` kinds on a course (`ground` has no meaning there), joined by `+` if several.
NOISE_KINDS = ("none", "wind", "sensor", "landing")


def _noise(text: str, field: str) -> str:
    return check_noise(text, NOISE_KINDS, field)


def add_parser(subparsers):
    """Add `parkour` to an argparse subparsers object; it sets `func=run`.

    **Arguments:**
    - `subparsers`: the object returned by `ArgumentParser.add_subparsers()`.

    **Returns:** the new subparser.
    """
    p = subparsers.add_parser(
        "parkour",
        help="receding-horizon parkour planning for the hopping leg (MPPC)",
        description="Run the MPPC receding-horizon planner on a parkour course, executing "
        "each planned first jump and checking it. Shipped courses: "
        + ", ".join(list_courses()),
    )
    p.add_argument("--course", required=True, metavar="NAME|FILE",
                   help="a shipped course name or a course JSON file")
    p.add_argument("--planner", default="mppc", choices=PLANNERS,
                   help="mppc, or reactive: the 2012 reactive planner for the leg "
                        "(docs/parkour_reactive.md)")
    p.add_argument("--model", default="bhop", choices=["bhop", "slip"],
                   help="reactive planner: the simulated model (default bhop)")
    p.add_argument("--noise", default="none", type=v.arg_type(_noise, "--noise"),
                   help="disturbance: none, wind, sensor or landing, or several joined by "
                   "'+' (wind+sensor); Froude-scaled, docs/parkour_reactive.md")
    p.add_argument("--seed", type=v.arg_type(v.seed, "--seed"), default=0,
                   help="seed of initial states and noise")
    p.add_argument("--runs", type=v.arg_type(v.count, "--runs", MAX_RUNS), default=1,
                   help="reactive planner: seeded runs (run 0 is reported in full)")
    p.add_argument("--controller", default="adaptive", choices=["paper", "adaptive"],
                   help="reactive planner: the paper's controller, or adaptive (wind "
                        "observer, wind-aware deadbeat, recovery; docs/decisions.md)")
    p.add_argument("--segments", default="lattice", choices=["lattice", "centred"],
                   help="reactive planner: floor segments on the lattice grid, so snapshot "
                        "updates redo less (default), or centred in every block")
    p.add_argument("--final-snapshot", action="store_true",
                   help="plan the course's last snapshot as a fixed course")
    p.add_argument("--grid", type=v.arg_type(v.real, "--grid"), default=Settings.grid,
                   help="landing grid spacing in metres (default %(default)s)")
    p.add_argument("--json", metavar="PATH", help="write the result JSON here")
    p.add_argument("--plot", metavar="PATH", help="save a figure of the run here")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """Run the `parkour` subcommand.

    **Arguments:**
    - `args`: the parsed namespace (`course`, `planner`, `noise`, `seed`, `runs`, `model`,
      `segments`, `final_snapshot`, `grid`, `json`, `plot`).

    **Returns:** exit status 0 (the run's outcome is in the summary and the JSON).

    **Raises:** `InputError` for a bad course or option.
    """
    planner = getattr(args, "planner", "mppc")
    if planner not in PLANNERS:
        raise InputError(f"--planner: unknown planner {planner!r} (choices: mppc, reactive)")
    check_grid(getattr(args, "grid", Settings.grid))
    course = load_course(args.course)
    if getattr(args, "final_snapshot", False):
        course = course.final()
    if planner == "reactive" or getattr(args, "noise", "none") != "none":
        return run_parkour(args, course)
    return run_mppc(args, course)


def run_parkour(args, course) -> int:
    """Run the reactive planner (or MPPC under a disturbance) and report like `parkour`."""
    noise = getattr(args, "noise", "none")
    if getattr(args, "plot", None):
        raise InputError("--plot: only with --planner mppc and --noise none")
    seed = int(getattr(args, "seed", 0))
    runs = int(getattr(args, "runs", 1))
    if runs < 1 or runs > MAX_RUNS:
        raise InputError(f"--runs: must be in [1, {MAX_RUNS}], got {runs}")
    if getattr(args, "planner", "mppc") == "reactive":
        from ._api import CourseRuns, reactive_parkour

        settings = CourseRuns(model=getattr(args, "model", "bhop"),
                              controller=getattr(args, "controller", "adaptive"), noise=noise,
                              seed=seed, runs=runs)
        out = reactive_parkour(course, settings,
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
        timed = [s for s in out["snapshots"] if s["flight_s"] is not None]
        if timed:
            print(f"updates within the flight they started in: "
                  f"{sum(s['within_flight'] for s in timed)} of {len(timed)}, before the next "
                  f"decision: {sum(s['before_decision'] for s in timed)} (updates "
                  f"{min(s['update_s'] for s in timed):.2f}-"
                  f"{max(s['update_s'] for s in timed):.2f} s, flights "
                  f"{min(s['flight_s'] for s in timed):.2f}-"
                  f"{max(s['flight_s'] for s in timed):.2f} s)")
    if getattr(args, "json", None):
        write_json(args.json, out)
    return 0
