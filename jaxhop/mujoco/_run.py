"""Closed-loop runs of the MuJoCo hopper under jaxhop's reactive controller.

At every apex of the body (its vertical velocity crossing zero in flight) the runner
measures the body's state (plus sensor noise), asks the controller for the controls
`(th_td, kc, kd)` and simulates the stride (`Simulator.stride`). The decision is the one
jaxhop's run loop makes for the SLIP model (`jaxhop._control.runloop`): `Model.decide` with the
paper's controller, `Model.decide_adaptive` (recovery outside the domains, the map
corrected by the sensed footholds, a re-planned `kd` at the bottom of a stance whose
foothold differs from the map) with the adaptive one. It is jitted once per process and
reused. The sensor noise of apex `k` of run `i` is jaxhop's draw (`fold_in(fold_in(key,
i), k)`), so a MuJoCo run and a jaxhop run of the same index see the same noise.

Runs are independent: `run_many` spreads them over processes, one per core.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .._core.params import Disturbance
from .._core.programs import jit
from .._core.result import Result
from .._core.terrain import Terrain
from ._model import DEFAULT, Mechanics
from ._sim import Simulator

RUN_FIELDS = ("code", "steps", "apexes", "footholds", "policies", "recoveries", "why")
#: A foothold sensed this far (m) from the corrected map's height under it differs from it.
SENSED_DIFFERS = 1e-6


@dataclass(frozen=True)
class Job:
    """Everything a process needs for MuJoCo runs: the true terrain (as a dict), the plan
    (built on the planner's map), the mechanics and the run settings. It is pickled once
    to each worker process."""

    terrain: dict
    plan: object
    mech: Mechanics = DEFAULT
    controller: str = "adaptive"
    sensor: tuple = (0.0, 0.0, 0.0)
    tolerance: tuple = (0.05, 0.05, 0.05)
    max_steps: int = 60
    seed: int = 0


class Controller:
    """jaxhop's reactive SLIP controller for one run after another, in one process.

    The decision, the foothold memory and the noise draw are jitted once and reused; each
    decision then costs one call (tens of ms on a CPU core).
    """

    def __init__(self, plan, controller: str = "adaptive"):

        from .._control.decisions import SLIP
        from .._control.runloop import check_controller

        self.plan, self.tables, self.hopper = plan, plan.tables(), plan.hopper
        self.adaptive = check_controller(controller) == "adaptive"
        self._decide = jit(self._decision)
        self._remember = jit(_remember)
        self._noise = jit(_noise)
        self._model = SLIP

    def _decision(self, measured, footholds, tables, hopper):
        import jax.numpy as jnp

        from .._control.foothold import corrected_heights

        if not self.adaptive:
            found, u, a = self._model.decide(measured, tables, hopper)
            return found, u, a, jnp.asarray(False), tables.terrain.heights
        heights = corrected_heights(footholds, tables.terrain)
        found, u, a, recovered = self._model.decide_adaptive(measured, tables, hopper, None,
                                                             heights, jnp.nan)
        return found, u, a, recovered, heights

    def decide(self, measured, footholds):
        """`(found, u, instantiated, recovered, heights)` as NumPy values."""
        out = self._decide(np.asarray(measured, float), footholds, self.tables, self.hopper)
        found, u, a, recovered, heights = (np.asarray(x) for x in out)
        return bool(found), u, int(a), bool(recovered), heights


def _remember(footholds, foot, k):
    from .._control.foothold import remember

    return remember(footholds, foot, True, k)


def _noise(key, i, k):
    import jax

    return jax.random.uniform(jax.random.fold_in(jax.random.fold_in(key, i), k), (3,),
                              minval=-1.0, maxval=1.0)


def _mapped_height(foot, heights, terrain: Terrain) -> float:
    """The corrected map's height under `foot` (NaN off the map; on a shared edge the
    block nearer in height), as `jaxhop._control.foothold.mapped_height`."""
    starts, ends = np.asarray(terrain.starts), np.asarray(terrain.ends)
    on = (foot[0] >= starts) & (foot[0] <= ends)
    if not on.any():
        return float("nan")
    return float(heights[np.argmin(np.where(on, np.abs(heights - foot[1]), np.inf))])


def run_one(sim: Simulator, ctrl: Controller, apex0, index: int, key, sensor, tolerance,
            max_steps: int = 60, *, record: list | None = None) -> dict:
    """One closed-loop run from the apex `apex0`: the fields of `jaxhop.run_batch`.

    Arguments:
        index: the run's index (its noise is `fold_in(key, index)`).
        sensor: half-widths of the uniform apex measurement noise on `(y, z, ydot)`.
        record: a list that receives the trajectory rows of `Simulator.stride`.
    """
    from .._control.foothold import footholds_init
    from .._control.runloop import RECOVERY_STREAK
    from .._models.slip.stride import bottom_kd

    hopper, tables = ctrl.hopper, ctrl.tables
    goal = np.asarray(ctrl.plan.goal, float)
    tolerance, sensor = np.asarray(tolerance, float), np.asarray(sensor, float)
    apexes = np.full((max_steps + 1, 3), np.nan)
    feet = np.full((max_steps, 2), np.nan)
    used = np.full(max_steps, -1, np.int64)
    apex = np.asarray(apex0, float)
    apexes[0] = apex
    footholds = footholds_init()
    code, steps, streak, recoveries, why = Result.MAX_STEPS, 0, 0, 0, ""
    m, g = float(hopper.m), float(hopper.g)
    for k in range(max_steps):
        if np.all(np.abs(apex - goal) <= tolerance):
            code = Result.SUCCESS
            break
        measured = apex + np.asarray(ctrl._noise(key, index, k)) * sensor
        found, u, a, recovered, heights = ctrl.decide(measured, footholds)
        streak = streak + 1 if recovered else 0
        if not found or streak > RECOVERY_STREAK:
            code = Result.OUTSIDE_DOMAIN
            break
        target = tables.goals[a]
        energy = m * (g * float(target[1]) + 0.5 * float(target[2]) ** 2)

        def kd_at_bottom(bottom, foot, u=u, heights=heights, energy=energy):
            # the adaptive controller re-plans kd where the foothold differs from its map
            h_map = _mapped_height(foot, heights, tables.terrain)
            if not ctrl.adaptive or not abs(foot[1] - h_map) > SENSED_DIFFERS:
                return u[2]
            return float(bottom_kd(bottom, foot[1], u[1], energy, hopper))

        if k == 0:  # the run starts with the leg at its first touchdown angle, as a SLIP's
            sim.reset(apex, float(u[0]))
        s = sim.stride(u, kd_at_bottom, record=record)
        steps += 1
        recoveries += int(recovered)
        feet[k], used[k] = s.foothold, a
        if s.code != Result.SUCCESS:
            code, why = s.code, s.why
            break
        footholds = ctrl._remember(footholds, s.foothold, k)
        apex = s.apex
        apexes[k + 1] = apex
    else:
        if np.all(np.abs(apex - goal) <= tolerance):
            code = Result.SUCCESS
    return {"code": int(code), "steps": steps, "apexes": apexes, "footholds": feet,
            "policies": used, "recoveries": recoveries, "why": why}


# --- many runs over processes ----------------------------------------------------------------

_worker = {}


def _start(job: Job):
    """A process's simulator and controller."""
    import jax

    from .._core.terrain import terrain_from_dict

    _worker.update(job=job, sim=Simulator(job.plan.hopper, terrain_from_dict(job.terrain),
                                          job.mech),
                   ctrl=Controller(job.plan, job.controller), key=jax.random.key(job.seed))


def _one(task):
    i, apex0 = task
    w = _worker
    job = w["job"]
    return i, run_one(w["sim"], w["ctrl"], apex0, i, w["key"], job.sensor, job.tolerance,
                      job.max_steps)


def run_recorded(job: Job, apex0, index: int = 0):
    """One run in this process with its trajectory: `(result, trajectory)`, `result` as one
    run of `run_many` and `trajectory` an `(n, 6)` array of `(t, y, z, foot_y, foot_z,
    in_stance)` rows, one per 10 ms."""
    _start(job)
    w = _worker
    rows: list = []
    out = run_one(w["sim"], w["ctrl"], apex0, index, w["key"], job.sensor, job.tolerance,
                  job.max_steps, record=rows)
    return out, np.asarray(rows, float).reshape(-1, 6)


def run_many(job: Job, initial, processes: int | None = None, progress: bool = False) -> dict:
    """Run every initial apex of `initial` (`(n, 3)`), run `i` with noise index `i`.

    `processes`: worker processes (default: one per core, at most one per run); 1 runs in
    this process. Each worker compiles the controller once (importing jaxhop turns on the
    compilation cache under the plan cache, which keeps the compiled code for later sweeps).

    Returns:
        dict of NumPy arrays, the fields of `jaxhop.run_batch` and `why`, what ended a failed
        stride (`RUN_FIELDS`).
    """
    from .._core.progress import Progress

    initial = np.atleast_2d(np.asarray(initial, float))
    n = initial.shape[0]
    processes = min(processes or os.cpu_count() or 1, max(n, 1))
    results: list = [None] * n
    tasks = list(enumerate(initial))
    with Progress(n, "mujoco runs", "run", enabled=progress) as bar:
        if processes == 1:
            _start(job)
            for task in tasks:
                i, out = _one(task)
                results[i] = out
                bar.update(1)
        else:
            import multiprocessing as mp

            ctx = mp.get_context("spawn")
            with _one_thread_each(), ctx.Pool(processes, _start, (job,)) as pool:
                for i, out in pool.imap_unordered(_one, tasks):
                    results[i] = out
                    bar.update(1)
    return {k: np.asarray([r[k] for r in results]) for k in RUN_FIELDS}


class _one_thread_each:
    """XLA in worker processes on one thread each: the processes are the parallelism."""

    FLAG = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"

    def __enter__(self):
        self.old = os.environ.get("XLA_FLAGS")
        os.environ["XLA_FLAGS"] = f"{self.old or ''} {self.FLAG}".strip()

    def __exit__(self, *exc):
        if self.old is None:
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = self.old


def job_for(terrain: Terrain, plan, mech: Mechanics = DEFAULT, controller: str = "adaptive",
            disturbance: Disturbance | None = None, tolerance=(0.05, 0.05, 0.05),
            max_steps: int = 60, seed: int = 0) -> Job:
    """A `Job` from jaxhop objects: runs on the true `terrain` under `plan` (built on the
    planner's map), the sensor noise from `disturbance` (MuJoCo runs have no wind or
    landing error)."""
    sensor = (0.0, 0.0, 0.0) if disturbance is None else tuple(
        float(x) for x in np.asarray(disturbance.sensor))
    return Job(terrain.to_dict(), plan, mech, controller, sensor,
               tuple(float(x) for x in np.asarray(tolerance)), int(max_steps), int(seed))


def summarize_runs(result: dict, seconds: float) -> dict:
    """The summary of a MuJoCo sweep: `jaxhop.sweep`'s keys, the failures with `slip`,
    and what ended the failed strides (`why`, counted)."""
    from collections import Counter

    from .._core.result import SIM_FAILURE_NAMES, failure_counts
    from .._execution.batches import summarize

    out = summarize(result, seconds)
    out["failures"] = failure_counts(result["code"], SIM_FAILURE_NAMES)
    out["stride_failures"] = dict(Counter(str(w) for w in result["why"] if w))
    return out
