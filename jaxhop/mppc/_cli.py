"""The `parkour` subcommand: run the MPPC planner on a course (SPEC sections 14-15)."""

import json
from pathlib import Path

from tqdm import tqdm

from .._errors import InputError
from ._course import list_courses, load_course
from ._plan import MPPC, Settings, run_course

MIN_GRID = 0.001  # m
MAX_GRID_POINTS = 100_000  # landing grid points over a course


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
    p.add_argument("--planner", default="mppc", choices=["mppc", "reactive"],
                   help="mppc, or reactive: the 2012 reactive planner for the leg (issue 8)")
    p.add_argument("--model", default="bhop", choices=["bhop", "slip"],
                   help="reactive planner: the simulated model (default bhop)")
    p.add_argument("--noise", default="none", choices=["none", "wind", "sensor", "landing"],
                   help="disturbance (Froude-scaled; docs/parkour_reactive.md)")
    p.add_argument("--seed", type=int, default=0, help="seed of initial states and noise")
    p.add_argument("--runs", type=int, default=1,
                   help="reactive planner: seeded runs (run 0 is reported in full)")
    p.add_argument("--segments", default="lattice", choices=["lattice", "centred"],
                   help="reactive planner: floor segments on the lattice grid, so snapshot "
                        "updates redo less (default), or centred in every block")
    p.add_argument("--final-snapshot", action="store_true",
                   help="plan the course's last snapshot as a fixed course")
    p.add_argument("--grid", type=float, default=Settings.grid,
                   help="landing grid spacing in metres (default %(default)s)")
    p.add_argument("--json", metavar="PATH", help="write the result JSON here")
    p.add_argument("--plot", metavar="PATH", help="save a figure of the run here")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """Run the `parkour` subcommand.

    **Arguments:**
    - `args`: the parsed namespace (`course`, `planner`, `final_snapshot`, `json`, `plot`,
      `grid`).

    **Returns:** exit status 0 (the run's outcome is in the summary and the JSON).

    **Raises:** `InputError` for a bad course or option.
    """
    if getattr(args, "planner", "mppc") not in ("mppc", "reactive"):
        raise InputError(f"--planner: unknown planner {args.planner!r} (choices: mppc, "
                         "reactive)")
    grid = getattr(args, "grid", Settings.grid)
    if not (MIN_GRID <= grid <= 0.1):
        raise InputError(f"--grid: must be in [{MIN_GRID:g}, 0.1] m, got {grid!r}")
    course = load_course(args.course)
    if getattr(args, "final_snapshot", False):
        course = course.final()
    if getattr(args, "planner", "mppc") == "reactive" or getattr(args, "noise", "none") != "none":
        from ..parkour._cli import run_parkour

        return run_parkour(args, course, _write)
    span = course.goal - course.start
    if span / grid > MAX_GRID_POINTS:
        raise InputError(f"--grid: {grid:g} m gives {span / grid:.0f} landing points on "
                         f"this course, at most {MAX_GRID_POINTS} allowed")
    with tqdm(total=round(span, 2), unit="m", desc=course.name, disable=None, leave=False,
              bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} m") as bar:
        result = run_course(course, MPPC(settings=Settings(grid=grid)),
                            on_jump=lambda x: bar.update(x - course.start - bar.n))
    out = result.to_json()
    out["final_snapshot"] = bool(getattr(args, "final_snapshot", False))
    ms = out["replan_ms"]
    status = "finished" if out["finished"] else f"NOT finished ({out['failure']})"
    print(f"{course.name}{' (final snapshot)' if out['final_snapshot'] else ''}: {status}, "
          f"{out['jumps']} jumps, flight time {out['flight_time']:.3f} s, "
          f"{out['violations']} violations")
    if ms["median"] is not None:
        print(f"replan ms (warm): min {ms['min']:.2f}, median {ms['median']:.2f}, "
              f"max {ms['max']:.2f}")
    if getattr(args, "json", None):
        _write(args.json, lambda f: json.dump(out, f, indent=1), "--json")
    if getattr(args, "plot", None):
        from ._plot import plot_run

        fig = plot_run(course, result)
        try:
            fig.savefig(args.plot, dpi=120)
        except (OSError, ValueError) as e:
            raise InputError(f"--plot: cannot write {args.plot!r}: {e}") from None
    return 0


def _write(path, writer, flag):
    try:
        with open(Path(path), "w") as f:
            writer(f)
    except OSError as e:
        raise InputError(f"{flag}: cannot write {path!r}: {e.strerror}") from None
