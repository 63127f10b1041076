"""Closed-loop runs of the MuJoCo hopper under jaxhop's reactive controller.

At every apex of the body (its vertical velocity crossing zero in flight) the runner
measures the body's state (plus sensor noise), asks the controller for the controls
`(th_td, kc, kd)` and simulates the stride (`Simulator.stride`, with the disturbance's
wind in flight). The decision is the one jaxhop's run loop makes for the SLIP model
(`jaxhop._control.runloop.step`): `Model.decide` with the paper's controller; with the
adaptive one, the disturbance observer (`jaxhop._control.observer`) updated with the
measured apex and with a second measurement in the descent, read from a copy of the
MuJoCo state flown ahead (`Simulator.descent_state`), then `Model.decide_adaptive` on the
observer's apex estimate with its wind estimate (recovery outside the domains, the map
corrected by the sensed footholds), a re-planned `kd` at the bottom of a stance whose
foothold differs from the map, and the observer told the stride taken. The observer's
update and the decision are jitted once per process and reused. The sensor noise of apex
`k` of run `i` is jaxhop's draw (`fold_in(fold_in(key, i), k)`, the descent's from
`fold_in` of that key with 1), so a MuJoCo run and a jaxhop run of the same index see the
same noise.

Runs are independent: `run_many` spreads them over processes, one per core.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .._core.errors import InputError
from .._core.params import Disturbance
from .._core.programs import jit
from .._core.result import Result
from .._core.terrain import Terrain
from ._model import DEFAULT, Mechanics
from ._sim import Simulator

RUN_FIELDS = ("code", "steps", "apexes", "footholds", "policies", "recoveries", "why")
#: Half-widths `(y, z, ydot)` of the error of a MuJoCo stride that the SLIP's apex map does
#: not describe (m, m, m/s), for the adaptive controller's observer: about the largest
#: differences between a stride of the `DEFAULT` hopper and the SLIP's over the
#: cross-check's 50 strides (`docs/mujoco.md`, "The controller").
STRIDE_ERROR = (0.03, 0.05, 0.05)
#: A foothold sensed this far (m) from the corrected map's height under it differs from it.
SENSED_DIFFERS = 1e-6


@dataclass(frozen=True)
class Job:
    """Everything a process needs for MuJoCo runs: the true terrain (as a dict), the plan
    (built on the planner's map), the mechanics and the run settings: the sensor noise's
    half-widths, the wind (m/s^2 in flight) and the observer's `stride_error`
    (`Controller`). It is pickled once to each worker process."""

    terrain: dict
    plan: object
    mech: Mechanics = DEFAULT
    controller: str = "adaptive"
    sensor: tuple = (0.0, 0.0, 0.0)
    tolerance: tuple = (0.05, 0.05, 0.05)
    max_steps: int = 60
    seed: int = 0
    wind: float = 0.0
    stride_error: tuple | None = STRIDE_ERROR


class Controller:
    """jaxhop's reactive SLIP controller for one run after another, in one process.

    The decision, the observer's update at an apex (adaptive controller), the foothold
    memory and the noise draws are jitted once and reused; each apex then costs a call or
    two (tens of ms on a CPU core).

    `stride_error`: the observer's `stride_error` (`jaxhop._control.observer.observe`),
    half-widths of the MuJoCo stride's error against the SLIP's apex map; `None`: jaxhop's
    observer as it is, whose model is exact (an attribute: changing it compiles nothing).
    """

    def __init__(self, plan, controller: str = "adaptive", stride_error=STRIDE_ERROR):

        from .._control.decisions import SLIP
        from .._control.runloop import check_controller

        self.plan, self.tables, self.hopper = plan, plan.tables(), plan.hopper
        self.adaptive = check_controller(controller) == "adaptive"
        self.stride_error = stride_error
        self._model = SLIP
        self._decide = jit(self._decision)
        self._observe = jit(self._observation)
        self._remember = jit(_remember)
        self._noise = jit(_noise)

    def _observation(self, obs, measured, footholds, sensor, key, i, k, tables, hopper,
                     stride_error=None):
        import jax

        from .._control.foothold import corrected_heights
        from .._control.observer import descent_key, descent_noise, descent_time

        heights = corrected_heights(footholds, tables.terrain)
        obs = self._model.observe(obs, measured, sensor, hopper, stride_error=stride_error)
        t = descent_time(measured, heights, tables.terrain, hopper)
        return obs, t, descent_noise(descent_key(jax.random.fold_in(key, i), k))

    def _decision(self, measured, footholds, obs, descent, t, sensor, tolerance, tables,
                  hopper):
        import jax.numpy as jnp

        from .._control.foothold import corrected_heights
        from .._control.observer import descent_update

        if not self.adaptive:
            found, u, a = self._model.decide(measured, tables, hopper)
            return found, u, a, jnp.asarray(False), tables.terrain.heights, obs
        heights = corrected_heights(footholds, tables.terrain)
        obs = descent_update(obs, measured[2], descent, t, sensor, hopper.g)
        found, u, a, recovered = self._model.decide_adaptive(
            obs.estimate, tables, hopper, obs.wind, heights, jnp.nan, None,
            (jnp.asarray(self.plan.goal, float), tolerance))
        return found, u, a, recovered, heights, obs

    def observe(self, obs, measured, footholds, sensor, key, index: int, k: int):
        """The adaptive controller at apex `k` of run `index`: the observer updated with
        the `measured` apex (`Model.observe`, with `stride_error`), the time `t` of the
        descent measurement
        (`descent_time`, on the map corrected by `footholds`) and its noise draws
        (`descent_noise`): `(obs, t, noise)`, as NumPy values."""
        obs, t, noise = self._observe(_numpy(obs), np.asarray(measured, float), footholds,
                                      np.asarray(sensor, float), key, index, k, self.tables,
                                      self.hopper, np.zeros(3) if self.stride_error is None
                                      else np.asarray(self.stride_error, float))
        return _numpy(obs), float(t), np.asarray(noise)

    def decide(self, measured, footholds, obs=None, descent=None, t: float = 0.0,
               sensor=None, tolerance=(0.05, 0.05, 0.05)):
        """`(found, u, instantiated, recovered, heights, obs)` as NumPy values. The adaptive
        controller takes the observer `obs` after `observe` and the state `descent`
        measured `t` seconds into the descent (with the sensor's half-widths `sensor`),
        updates the observer with it (`descent_update`) and decides on its apex estimate
        with its wind, with capture strides near the plan's goal within the run's goal
        `tolerance` (`jaxhop._control.decisions.decide_slip`); `obs` is returned updated
        (the paper's controller: `None`)."""
        from .._control.observer import observer_init

        if obs is None:
            obs = observer_init()
        zero = np.zeros(3)
        out = self._decide(np.asarray(measured, float), footholds, _numpy(obs),
                           zero if descent is None else np.asarray(descent, float),
                           float(t), zero if sensor is None else np.asarray(sensor, float),
                           np.asarray(tolerance, float), self.tables, self.hopper)
        found, u, a, recovered, heights = (np.asarray(x) for x in out[:5])
        return (bool(found), u, int(a), bool(recovered), heights,
                _numpy(out[5]) if self.adaptive else None)


def _numpy(obs):
    """The observer with NumPy leaves: the jitted calls then see one signature."""
    return type(obs)(*(np.asarray(x) for x in obs))


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
            max_steps: int = 60, *, wind: float = 0.0, record: list | None = None,
            observed: list | None = None) -> dict:
    """One closed-loop run from the apex `apex0`: the fields of `jaxhop.run_batch`.

    Arguments:
        index: the run's index (its noise is `fold_in(key, index)`).
        sensor: half-widths of the uniform apex measurement noise on `(y, z, ydot)`.
        wind: horizontal acceleration of the hopper in flight (m/s^2).
        record: a list that receives the trajectory rows of `Simulator.stride`.
        observed: a list that receives the adaptive controller's observer after each
            decision (`jaxhop._control.observer.Observer`).
    """
    from .._control.foothold import footholds_init
    from .._control.observer import after_stride, observer_init
    from .._control.runloop import RECOVERY_STREAK, liftoff_energy
    from .._models.slip.stride import bottom_kd

    hopper, tables = ctrl.hopper, ctrl.tables
    goal = np.asarray(ctrl.plan.goal, float)
    tolerance, sensor = np.asarray(tolerance, float), np.asarray(sensor, float)
    wind = float(wind)
    apexes = np.full((max_steps + 1, 3), np.nan)
    feet = np.full((max_steps, 2), np.nan)
    used = np.full(max_steps, -1, np.int64)
    apex = np.asarray(apex0, float)
    apexes[0] = apex
    footholds = footholds_init()
    obs = observer_init() if ctrl.adaptive else None
    code, steps, streak, recoveries, why = Result.MAX_STEPS, 0, 0, 0, ""
    for k in range(max_steps):
        if np.all(np.abs(apex - goal) <= tolerance):
            code = Result.SUCCESS
            break
        measured = apex + np.asarray(ctrl._noise(key, index, k)) * sensor
        if ctrl.adaptive:
            if k == 0:  # at the first apex the leg hangs at rest length, held
                sim.reset(apex)
            obs, t, noise = ctrl.observe(obs, measured, footholds, sensor, key, index, k)
            descent = sim.descent_state(t, wind) + noise * sensor
            found, u, a, recovered, heights, obs = ctrl.decide(measured, footholds, obs,
                                                               descent, t, sensor, tolerance)
            if observed is not None:
                observed.append(obs)
        else:
            found, u, a, recovered, heights, _ = ctrl.decide(measured, footholds)
        streak = streak + 1 if recovered else 0
        if not found or streak > RECOVERY_STREAK:
            code = Result.OUTSIDE_DOMAIN
            break
        target = np.asarray(tables.goals[a], float)
        aimed = [np.nan]  # the apex energy the stance aimed at (NaN: kd as decided)

        def kd_at_bottom(bottom, foot, u=u, heights=heights, target=target, aimed=aimed,
                         obs=obs):
            # the adaptive controller re-plans kd where the foothold differs from its map,
            # for the liftoff speed that reaches the goal against the estimated wind
            h_map = _mapped_height(foot, heights, tables.terrain)
            if not ctrl.adaptive or not abs(foot[1] - h_map) > SENSED_DIFFERS:
                return u[2]
            aimed[0] = float(liftoff_energy(target, foot[1], u[0], hopper, obs.wind))
            return float(bottom_kd(bottom, foot[1], u[1], aimed[0], hopper))

        if k == 0:  # the run starts with the leg at its first touchdown angle, as a SLIP's
            sim.reset(apex, float(u[0]))
        s = sim.stride(u, kd_at_bottom, record=record, wind=wind)
        steps += 1
        recoveries += int(recovered)
        feet[k], used[k] = s.foothold, a
        if s.code != Result.SUCCESS:
            code, why = s.code, s.why
            break
        footholds = ctrl._remember(footholds, s.foothold, k)
        if ctrl.adaptive:  # the foothold's height sensed at touchdown (leg geometry)
            obs = after_stride(obs, obs.estimate, u, s.foothold[1], True, aimed[0])
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
                   ctrl=Controller(job.plan, job.controller, job.stride_error),
                   key=jax.random.key(job.seed))


def _one(task):
    i, apex0 = task
    w = _worker
    job = w["job"]
    return i, run_one(w["sim"], w["ctrl"], apex0, i, w["key"], job.sensor, job.tolerance,
                      job.max_steps, wind=job.wind)


def run_recorded(job: Job, apex0, index: int = 0):
    """One run in this process with its trajectory: `(result, trajectory)`, `result` as one
    run of `run_many` and `trajectory` an `(n, 6)` array of `(t, y, z, foot_y, foot_z,
    in_stance)` rows, one per 10 ms."""
    _start(job)
    w = _worker
    rows: list = []
    out = run_one(w["sim"], w["ctrl"], apex0, index, w["key"], job.sensor, job.tolerance,
                  job.max_steps, wind=job.wind, record=rows)
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
    planner's map), the sensor noise and the wind from `disturbance` (MuJoCo runs have no
    landing error: a `disturbance` with one is refused). The adaptive controller's
    observer allows for `STRIDE_ERROR` (`Controller`; `dataclasses.replace(job,
    stride_error=None)` runs jaxhop's observer as it is)."""
    sensor, wind = (0.0, 0.0, 0.0), 0.0
    if disturbance is not None:
        if float(disturbance.landing) != 0.0:
            raise InputError("MuJoCo runs have no landing error (Disturbance.landing)")
        sensor = tuple(float(x) for x in np.asarray(disturbance.sensor))
        wind = float(disturbance.wind)
    return Job(terrain.to_dict(), plan, mech, controller, sensor,
               tuple(float(x) for x in np.asarray(tolerance)), int(max_steps), int(seed),
               wind)


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
