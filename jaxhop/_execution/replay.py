"""A nominal run's plan replayed open loop, without reactive re-selection (Figs. 14-15).

The replay runs the run loop's `step` with the controller's decision replaced by a fixed
schedule: the nominal run's controls (`FixedControls`, the paper's "offline plan") or its
sequence of policy goals, each reached with the BHop deadbeat from the measured apex
(`FixedGoals`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._control.decisions import clip_to_template, decide
from .._control.runloop import RunConfig, World, final_code, step
from .._core.params import Disturbance
from .._core.programs import jit
from .._core.result import Result
from .._core.terrain import Terrain
from .._models.bhop import deadbeat_bhop
from .._planning.plan import Plan
from .._planning.templates import Templates


class FixedControls(eqx.Module):
    """Stride `k` applies `u[k]` (recorded as policy `policy[k]`), whatever the apex."""

    u: jnp.ndarray
    policy: jnp.ndarray

    def __call__(self, measured, k, world: World):
        return jnp.asarray(True), self.u[k], self.policy[k]


class FixedGoals(eqx.Module):
    """Stride `k` heads for policy `policy[k]`'s goal: the BHop deadbeat from the measured
    apex over its foothold height, clipped to its template's limits (as `decide`)."""

    policy: jnp.ndarray
    goals: jnp.ndarray
    heights: jnp.ndarray
    template: jnp.ndarray
    templates: Templates

    def __call__(self, measured, k, world: World):
        u = deadbeat_bhop(measured, self.goals[k], self.heights[k], world.hopper)
        return (jnp.asarray(True), clip_to_template(u, self.templates.row(self.template[k])),
                self.policy[k])


def nominal_controls(plan: Plan, run: dict) -> np.ndarray:
    """BHop controls `(dy, th, k)` the reactive controller applied at each apex of a run.

    Recomputed from the recorded (true) apexes, so exact for an undisturbed run.
    """
    steps = int(run["steps"])
    if steps == 0:
        return np.zeros((0, 3))
    apexes = jnp.asarray(np.asarray(run["apexes"])[:steps], float)
    decide_all = jit(jax.vmap(decide, (0, None, None)))
    found, u, a = decide_all(apexes, plan.tables(), plan.hopper)
    return np.asarray(u)


def _schedule(plan: Plan, run: dict, mode: str):
    steps = int(run["steps"])
    policies = jnp.asarray(np.asarray(run["policies"])[:steps])
    if mode == "controls":
        return FixedControls(jnp.asarray(nominal_controls(plan, run)), policies)
    situated = np.asarray(plan.situated)[np.asarray(policies)]
    nt = plan.templates.n
    heights = np.asarray(plan.table().centre)[situated // nt, 1]
    return FixedGoals(policies, jnp.asarray(np.asarray(plan.goals)[np.asarray(policies)]),
                      jnp.asarray(heights), jnp.asarray(situated % nt), plan.templates)


_step_jit = jit(step)


def open_loop_replay(plan: Plan, run: dict, *, disturbance=None, key=None,
                     true_terrain: Terrain | None = None, mode: str = "controls",
                     tolerance=(0.05, 0.05, 0.05)) -> dict:
    """Replay a nominal run's plan open loop, without reactive re-selection (Figs. 14-15).

    `mode = "controls"`: the nominal run's control sequence (`nominal_controls`) is applied
    stride by stride, whatever happens (the paper's "offline plan"). `mode = "goals"`: the
    nominal run's sequence of policy goals is kept, and the BHop deadbeat toward the k-th
    goal is computed from the k-th *measured* apex (sensor noise drawn as in `run_one` for
    run 0 of a batch with the same `key`), clipped to that policy's limits. The stride uses
    `true_terrain` (default: the plan's map) and the wind. The whole sequence is played: an
    open-loop plan does not stop at the goal on the way.

    Returns:
        a run dict (`code, steps, apexes, footholds, policies`, as from `run_batch` for one
        run): `success` if the last apex is within `tolerance` of the plan's goal, otherwise
        the failure, or `max_steps` when the sequence ran out away from the goal.
    """
    if mode not in ("controls", "goals"):
        raise ValueError(f"mode must be 'controls' or 'goals', got {mode!r}")
    disturbance = Disturbance() if disturbance is None else disturbance
    key = jax.random.fold_in(jax.random.key(0) if key is None else key, 0)
    terrain = plan.terrain if true_terrain is None else true_terrain
    world = World(plan.tables(), terrain, plan.hopper, disturbance)
    goal = jnp.asarray(plan.goal, float)
    # No goal test between strides (an empty tolerance); the real one judges the end.
    playing = RunConfig(goal, jnp.full(3, -jnp.inf))
    schedule = _schedule(plan, run, mode)
    n = len(run["footholds"])
    apexes = np.full((n + 1, 3), np.nan)
    feet = np.full((n, 2), np.nan)
    used = np.full(n, -1, np.int32)
    apex = np.asarray(run["apexes"][0], float)
    apexes[0] = apex
    code, taken = Result.RUNNING, 0
    for k in range(int(run["steps"])):
        s = _step_jit(jnp.asarray(apex), key, k, world, playing, schedule)
        feet[k], used[k] = np.asarray(s.foothold), int(s.policy)
        taken = k + 1
        if int(s.code) != Result.RUNNING:
            code = int(s.code)
            break
        apex = np.asarray(s.next_apex)
        apexes[k + 1] = apex
    code = final_code(code, jnp.asarray(apex), RunConfig(goal, jnp.asarray(tolerance, float)))
    return {"code": np.int32(code), "steps": np.int32(taken), "apexes": apexes,
            "footholds": feet, "policies": used}
