"""`jaxhop parkour --planner mppc`: an exact MPPC run on a course, reported.

The subcommand itself (options, the other planners) is `jaxhop.parkour._cli`; this module
runs the receding-horizon loop (`run_course`), prints its summary and writes the JSON and
the figure. Courses and results: docs/mppc.md.
"""

import json
from pathlib import Path

from .._core.errors import InputError
from .._core.progress import Progress
from ._plan import MPPC, Settings
from ._run import run_course

MIN_GRID = 0.001  # m
MAX_GRID = 0.1  # m
MAX_GRID_POINTS = 100_000  # landing grid points over a course


def check_grid(grid: float) -> float:
    """`--grid`: a landing grid spacing in `[MIN_GRID, MAX_GRID]` metres."""
    if not (MIN_GRID <= grid <= MAX_GRID):
        raise InputError(f"--grid: must be in [{MIN_GRID:g}, {MAX_GRID:g}] m, got {grid!r}")
    return grid


def run_mppc(args, course) -> int:
    """Run MPPC on `course`, executing every planned first jump exactly, and report it.

    **Arguments:**
    - `args`: the parsed namespace (`grid`, `final_snapshot`, `json`, `plot`).
    - `course`: the course (already `final()` under `--final-snapshot`).

    **Returns:** exit status 0 (the run's outcome is in the summary and the JSON).

    **Raises:** `InputError` for a grid too fine for the course or an unwritable output.
    """
    grid = getattr(args, "grid", Settings.grid)
    span = course.goal - course.start
    if span / grid > MAX_GRID_POINTS:
        raise InputError(f"--grid: {grid:g} m gives {span / grid:.0f} landing points on "
                         f"this course, at most {MAX_GRID_POINTS} allowed")
    with Progress(total=round(span * 100), desc=course.name, unit="cm") as bar:
        result = run_course(course, MPPC(settings=Settings(grid=grid)),
                            on_jump=lambda x: bar.update(round((x - course.start) * 100)
                                                         - bar.n))
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
        write_json(args.json, out)
    if getattr(args, "plot", None):
        from ._plot import plot_run

        fig = plot_run(course, result)
        try:
            fig.savefig(args.plot, dpi=120)
        except (OSError, ValueError) as e:
            raise InputError(f"--plot: cannot write {args.plot!r}: {e}") from None
    return 0


def write_json(path, out: dict) -> None:
    """Write `out` as JSON to `path` (`--json`); an `InputError` if it cannot be written."""
    try:
        with open(Path(path), "w") as f:
            json.dump(out, f, indent=1)
    except OSError as e:
        raise InputError(f"--json: cannot write {path!r}: {e.strerror}") from None
