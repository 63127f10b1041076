"""Domain-of-attraction sweeps (`docs/decisions.md`, "Sweeps"): every grid state inside the
global domain through the reactive controller, and their summary."""

from __future__ import annotations

import time

from ._errors import InputError
from ._execute import in_global_domain, run_batch, sweep_grid
from ._params import Disturbance
from ._plan import Plan
from ._result import Result, failure_counts
from ._terrain import Terrain


def summarize(result: dict, seconds: float) -> dict:
    """The summary of a sweep (the keys of `jaxhop sweep --json`)."""
    code, steps = result["code"], result["steps"]
    n = int(code.size)
    ok = code == Result.SUCCESS
    return {
        "n_initial_conditions": n,
        "success_rate": float(ok.mean()) if n else 0.0,
        "mean_steps": float(steps[ok].mean()) if ok.any() else 0.0,
        "max_steps": int(steps[ok].max()) if ok.any() else 0,
        "failures": failure_counts(code),
        "seconds": round(seconds, 3),
    }


MAX_GRID = 2_000_000


def sweep(plan: Plan, *, initial=None, key=None, true_terrain: Terrain | None = None,
          disturbance: Disturbance | None = None, ydot0: float = 0.5, dy: float = 0.05,
          dz: float = 0.05, max_steps: int = 60, tolerance=None, chunk: int | None = None,
          checkpoint: str | None = None, model: str = "bhop", progress: bool = False):
    """Domain-of-attraction sweep: run every grid state inside the global domain.

    The grid (`sweep_grid`) covers `true_terrain` (default: the plan's map); `initial`
    replaces it. The other arguments are `run_batch`'s.

    Returns:
        `(summary, initial_states, result)`.

    Raises:
        InputError: the grid would exceed `MAX_GRID` states, or no state to run.
    """
    t0 = time.perf_counter()
    if initial is None:
        grid = sweep_grid(plan.terrain if true_terrain is None else true_terrain, ydot0, dy, dz)
        if grid.shape[0] > MAX_GRID:
            raise InputError(f"dy/dz: the grid would exceed {MAX_GRID} initial states")
        initial = grid[in_global_domain(grid, plan.tables(), plan.hopper)]
        if initial.shape[0] == 0:
            raise InputError("no grid state lies in the global domain (is the goal reachable?)")
    result = run_batch(plan, initial, key=key, true_terrain=true_terrain,
                       disturbance=disturbance, max_steps=max_steps, tolerance=tolerance,
                       chunk=chunk, progress=progress, checkpoint=checkpoint, model=model)
    return summarize(result, time.perf_counter() - t0), initial, result
