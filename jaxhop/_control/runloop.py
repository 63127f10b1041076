"""The reactive run loop (Fig. 8): one step function and the vmapped loop around it.

A step takes one apex of a run: the goal test, the disturbance (sensor noise on the
measured apex, a landing error; section VI-C), the controller's decision on the measured
apex (`Model.decide`), the model's stride on the true terrain with the wind
(`Model.stride`) and the failure checks (a stride that does not finish, a touchdown in a
forbidden interval of a parkour course). The decision is the paper's controller
(`controller="paper"`: first match, wind-blind deadbeat) or the adaptive one
(`"adaptive"`: a disturbance observer, `jaxhop._control.observer`, whose wind estimate the
deadbeat inverts, and recovery of apexes measured outside every domain; its state per run
is a `Control` in the step's input and output; `docs/decisions.md`, "Adaptive
controller"). Its drivers: `run_one` (a while loop, vmapped by `run_chunk` for `run_batch`),
the SLIP lane pool (`jaxhop._execution.pool`), parkour runs across snapshots
(`jaxhop.parkour._run`) and the open-loop replay of the figures (`jaxhop._execution.replay`).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from .._core.batching import run_once
from .._core.errors import InputError
from .._core.params import Disturbance, Hopper, float_array
from .._core.programs import jit
from .._core.result import Result
from .._core.terrain import Terrain
from .._models.flight import flight_position
from .._models.slip.kernels import mirrored_rise_time
from .._planning.plan import PlanTables
from .decisions import BHOP, Model, model_for, sensed_foothold
from .foothold import Footholds, corrected_heights, footholds_init, mapped_height, remember
from .observer import (
    Observer,
    after_stride,
    descent_key,
    descent_noise,
    descent_time,
    descent_update,
    observer_init,
)

CONTROLLERS = ("paper", "adaptive")
#: A run whose apex is measured outside every domain at more than this many consecutive
#: apexes ends with `outside_domain` even where recovery finds a policy.
RECOVERY_STREAK = 3


def check_controller(name: str) -> str:
    if name not in CONTROLLERS:
        raise InputError(f"controller must be one of {', '.join(CONTROLLERS)}, got {name!r}")
    return name


#: The goal tolerance per axis `(y, z, ydot)` of a run (m, m, m/s).
DEFAULT_TOLERANCE = (0.05, 0.05, 0.05)


class RunConfig(eqx.Module):
    """Execution settings.

    `goal` and `tolerance` are float arrays whatever their type as given (`float_array`), so
    that every way of writing them runs on the same compiled program.

    `controller`: `"paper"` (the paper's reactive controller, Fig. 8) or `"adaptive"`
    (disturbance observer, wind-aware deadbeat, recovery outside the domains).

    `landing`: draw a fourth uniform at every apex and shift the true apex by it times
    `Disturbance.landing` before the descent (the parkour runs' draw); without it three
    uniforms are drawn (sensor noise only) and landings are exact.

    `adaptive_on` (traced; with `controller="adaptive"`): `False` runs the paper's
    controller through the adaptive controller's program, every addition switched off
    (`run_config`): both controllers then share one compilation, and without disturbance
    their runs agree to the last bit (`docs/decisions.md`, "Adaptive controller").
    `None`: on.
    """

    goal: jnp.ndarray = eqx.field(converter=float_array)
    tolerance: jnp.ndarray = eqx.field(default=DEFAULT_TOLERANCE, converter=float_array)
    max_steps: int = eqx.field(static=True, default=60)
    model: Model = eqx.field(static=True, default=BHOP, converter=model_for)
    energy_feedback: bool = eqx.field(static=True, default=False)
    landing: bool = eqx.field(static=True, default=False)
    controller: str = eqx.field(static=True, default="paper", converter=check_controller)
    adaptive_on: jnp.ndarray | None = None


def run_config(goal, tolerance=None, max_steps: int = 60, model="bhop",
               controller: str = "paper", energy_feedback: bool = False) -> RunConfig:
    """The `RunConfig` of a batch of runs. A SLIP's two controllers share the adaptive
    controller's program, the paper's with its additions switched off (`adaptive_on`): a
    SLIP decision takes minutes to compile, and the switch keeps the paper's runs the
    adaptive controller's without disturbance, bit for bit. BHop compiles each controller
    as it is."""
    model = model_for(model)
    controller = check_controller(controller)
    shared = not model.instant_stance
    return RunConfig(goal=goal, tolerance=DEFAULT_TOLERANCE if tolerance is None else tolerance,
                     max_steps=max_steps, model=model,
                     energy_feedback=energy_feedback,
                     controller="adaptive" if shared else controller,
                     adaptive_on=jnp.asarray(controller == "adaptive") if shared else None)


class World(eqx.Module):
    """What a step runs against: the plan's tables (for the decision), the true terrain (for
    the stride), the hopper, the disturbance and, on parkour courses, the forbidden
    touchdown intervals `(n, 3)`: `[lo, hi, kind]` rows with `kind` a `Result` code."""

    tables: PlanTables
    terrain: Terrain
    hopper: Hopper
    disturbance: Disturbance
    forbidden: jnp.ndarray | None = None


class Control(NamedTuple):
    """The adaptive controller's state in a run: its observer, the strides taken from a
    recovered apex (`recoveries`), the current run of consecutive recoveries and the
    footholds it has sensed (`jaxhop._control.foothold`)."""

    observer: Observer
    recoveries: jnp.ndarray
    streak: jnp.ndarray
    footholds: Footholds


def control_init() -> Control:
    zero = jnp.asarray(0, jnp.int32)
    return Control(observer_init(), zero, zero, footholds_init())


class Step(NamedTuple):
    """What one step did: the run's new code (`RUNNING` while it goes on), whether a stride
    was taken (`stepping`) and completed (`ok`), its next apex, foothold and policy, and
    the controller's state after it."""

    code: jnp.ndarray
    stepping: jnp.ndarray
    ok: jnp.ndarray
    next_apex: jnp.ndarray
    foothold: jnp.ndarray
    policy: jnp.ndarray
    control: Control


def at_goal(apex, config: RunConfig):
    return jnp.all(jnp.abs(apex - config.goal) <= config.tolerance)


def draw_noise(key, k, config: RunConfig):
    """The uniforms of apex `k` of a run (`fold_in(key, k)`): 3, or 4 with landings."""
    return jax.random.uniform(jax.random.fold_in(key, k), (4 if config.landing else 3,),
                              minval=-1.0, maxval=1.0)


def forbidden_touchdown(foot, forbidden):
    """The `Result` of a touchdown at `foot` inside a forbidden interval (0 where none); a
    restricted area outranks a margin band."""
    inside = ((foot[0] > forbidden[:, 0] + 1e-9) & (foot[0] < forbidden[:, 1] - 1e-9)
              & (forbidden[:, 2] > 0))
    kind = jnp.max(jnp.where(inside, forbidden[:, 2], 0.0)).astype(jnp.int32)
    restricted = jnp.any(inside & (forbidden[:, 2] == Result.RESTRICTED))
    return jnp.where(restricted, Result.RESTRICTED, kind)


def stride_code(nxt, code, foot, world: World):
    """A completed stride with a non-finite apex is a `SOLVER` failure; a touchdown in a
    forbidden interval is that interval's failure."""
    code = jnp.where(jnp.all(jnp.isfinite(nxt)) | (code != Result.SUCCESS), code, Result.SOLVER)
    if world.forbidden is None:
        return code
    kind = forbidden_touchdown(foot, world.forbidden)
    return jnp.where((code == Result.SUCCESS) & (kind > 0), kind, code)


def _descent_measurement(obs: Observer, measured, true_apex, heights, key, world: World):
    """A leg placed in flight (SLIP): the controller sets the touchdown angle after
    `DESCENT_FRACTION` of the fall from the apex to its corrected map under it
    (`descent_time`), and measures its state again then, on the ballistic flight with the
    wind, with the sensor's noise (draws of its own, `descent_noise`).

    Without sensor noise the horizontal velocity gives the wind (`observe_descent`). With
    it, the position and the velocity update the apex estimate and the wind together
    (`fuse_descent`): the stride is decided on both measurements of the flight
    (`docs/decisions.md`, "Apex filter"; `descent_update`)."""
    hop = world.hopper
    t = descent_time(measured, heights, world.tables.terrain, hop)
    noise = descent_noise(key)
    sensor = world.disturbance.sensor
    wind = world.disturbance.wind
    descent = jnp.stack([flight_position(true_apex[0], true_apex[2], wind, t)
                         + noise[0] * sensor[0],
                         flight_position(true_apex[1], 0.0, -hop.g, t) + noise[1] * sensor[1],
                         true_apex[2] + wind * t + noise[2] * sensor[2]])
    return descent_update(obs, measured[2], descent, t, sensor, hop.g)


def _decide_adaptive(measured, true_apex, world: World, config: RunConfig, control: Control,
                     key):
    """The adaptive decision: observer update, deadbeat with the estimated wind on the map
    corrected by the sensed footholds (an instantaneous stance with the foothold sensed at
    its touchdown), recovery, all on the observer's filtered apex. `key`: the draw of a
    measurement in the descent (SLIP). Returns `(found, u, a, recovered, control, heights,
    state)`: `state`, the apex decided on."""
    obs = control.observer
    model = config.model
    on = config.adaptive_on
    dist = world.disturbance
    state = measured
    heights = corrected_heights(control.footholds, world.tables.terrain)

    def observed(zero):
        new = model.observe(obs, measured + zero, dist.sensor, world.hopper,
                            dist.landing if config.landing else 0.0)
        if not model.instant_stance:
            new = _descent_measurement(new, measured, true_apex, heights, key, world)
        return new

    if model.observes:
        # Switched off (the paper's controller), a batch skips the observer's solves.
        obs = observed(0.0) if on is None else run_once(on, observed, obs)
        state = obs.estimate
    if on is not None:  # switched off: the paper's controller (map, no wind, no recovery)
        obs = jax.tree.map(lambda new, old: jnp.where(on, new, old), obs, control.observer)
        heights = jnp.where(on, heights, world.tables.terrain.heights)
        state = jnp.where(on, state, measured)
    h_touch = jnp.asarray(jnp.nan)
    if model.instant_stance:
        landed, foot = sensed_foothold(true_apex, model.foot_offset(None, world.hopper),
                                       world.terrain, world.hopper, world.disturbance.wind)
        h_touch = jnp.where(landed, foot[1], jnp.nan)
    found, u, a, recovered = model.decide_adaptive(state, world.tables, world.hopper,
                                                   obs.wind if model.observes else None,
                                                   heights, h_touch, on,
                                                   (config.goal, config.tolerance))
    if on is not None:
        found = found & (on | ~recovered)
        recovered = recovered & on
    streak = jnp.where(recovered, control.streak + 1, 0).astype(jnp.int32)
    found = found & (streak <= RECOVERY_STREAK)
    return (found, u, a, recovered, control._replace(observer=obs, streak=streak), heights,
            state)


def liftoff_energy(goal, h, th, hopper: Hopper, wind=None):
    """The apex energy `m (g z* + ydot_lo^2 / 2)` that a stance on a foothold at height `h`
    with the touchdown angle `th` aims at to rise to `goal` (`bottom_kd`). With the
    estimated `wind`, the liftoff speed is `ydot_lo = ydot* - wind t_up`, `t_up` the rise
    time of a mirrored stance (`mirrored_rise_time`; `jaxhop._models.slip.kernels.energy_kd`);
    without (`None`), the goal's speed."""
    ydot_lo = goal[2]
    if wind is not None:
        ydot_lo = goal[2] - wind * mirrored_rise_time(goal, h, th, hopper)
    return hopper.m * (hopper.g * goal[1] + 0.5 * ydot_lo**2)


def _stance_energy(true_apex, u, a, heights, world: World, config: RunConfig, adaptive,
                   wind=None):
    """The apex energy the stance aims at (`bottom_kd`), NaN for none: always
    with `energy_feedback`; with the adaptive controller where the foothold sensed at
    touchdown differs from the corrected map under it (a leg-spring stance only), with
    the estimated `wind` (`liftoff_energy`)."""
    goal = world.tables.goals[a]
    hop = world.hopper
    if config.energy_feedback:
        return liftoff_energy(goal, None, None, hop)
    if not adaptive or config.model.instant_stance:
        return None
    landed, foot = sensed_foothold(true_apex, config.model.foot_offset(u, hop),
                                   world.terrain, hop, world.disturbance.wind)
    differs = landed & (foot[1] != mapped_height(foot, heights, world.tables.terrain))
    if config.adaptive_on is not None:
        differs = differs & config.adaptive_on
    return jnp.where(differs, liftoff_energy(goal, foot[1], u[0], hop, wind), jnp.nan)


def step(apex, key, k, world: World, config: RunConfig, controller=None,
         control: Control | None = None) -> Step:
    """Apex `k` of a run: goal test, noise, decision, stride, failure checks.

    `controller(measured, k, world) -> (found, u, policy)` replaces the reactive decision
    (`config.model.decide`): the open-loop replay of a fixed plan (`jaxhop._execution.replay`).
    `control`: the adaptive controller's state before the step (default: a fresh run's).
    """
    done = at_goal(apex, config)
    noise = draw_noise(key, k, config)
    dist = world.disturbance
    measured = apex + noise[:3] * dist.sensor
    control = control_init() if control is None else control
    adaptive = controller is None and config.controller == "adaptive"
    recovered = jnp.asarray(False)
    true_apex = apex.at[0].add(noise[3] * dist.landing) if config.landing else apex
    heights = world.tables.terrain.heights
    if adaptive:
        found, u, a, recovered, control, heights, decided_on = _decide_adaptive(
            measured, true_apex, world, config, control, descent_key(key, k))
    elif controller is None:
        found, u, a = config.model.decide(measured, world.tables, world.hopper)
    else:
        found, u, a = controller(measured, k, world)
    wind = control.observer.wind if adaptive and config.model.observes else None
    energy = _stance_energy(true_apex, u, a, heights, world, config, adaptive, wind)
    nxt, s_code, foot = config.model.stride(true_apex, u, world.terrain, world.hopper,
                                            dist.wind, energy)
    s_code = stride_code(nxt, s_code, foot, world)
    code = jnp.where(done, Result.SUCCESS, jnp.where(
        ~found, Result.OUTSIDE_DOMAIN, jnp.where(s_code == Result.SUCCESS, Result.RUNNING,
                                                 s_code)))
    stepping = ~done & found
    ok = stepping & (s_code == Result.SUCCESS)
    if adaptive:
        # The foothold's height is sensed at touchdown (leg geometry).
        control = control._replace(
            observer=after_stride(control.observer, decided_on, u, foot[1], ok, energy),
            recoveries=control.recoveries + (stepping & recovered).astype(jnp.int32),
            footholds=remember(control.footholds, foot, ok, k))
    return Step(code, stepping, ok, nxt, foot, a, control)


def final_code(code, apex, config: RunConfig):
    """A run still going when the loop stops: `SUCCESS` at the goal, else `MAX_STEPS`."""
    return jnp.where(code == Result.RUNNING,
                     jnp.where(at_goal(apex, config), Result.SUCCESS, Result.MAX_STEPS), code)


# --- the recorded run: a carry with its buffers -------------------------------------------


def run_init(apex0, config: RunConfig):
    """The carry of a run at its first apex: `(apex, code, steps, k, buffers, control)`."""
    n = config.max_steps
    apex0 = jnp.asarray(apex0, float)
    buffers = (jnp.full((n + 1, 3), jnp.nan).at[0].set(apex0), jnp.full((n, 2), jnp.nan),
               jnp.full((n,), -1, jnp.int32))
    return (apex0, jnp.asarray(Result.RUNNING), jnp.asarray(0, jnp.int32), jnp.asarray(0),
            buffers, control_init())


def run_live(carry, config: RunConfig):
    _, code, _, k, _, _ = carry
    return (code == Result.RUNNING) & (k < config.max_steps)


def run_step(carry, key, world: World, config: RunConfig):
    """`step` on a recorded run: the apex, footholds and policies go to its buffers."""
    apex, code, steps, k, (apexes, feet, used), control = carry
    s = step(apex, key, k, world, config, control=control)
    apexes = apexes.at[k + 1].set(jnp.where(s.ok, s.next_apex, jnp.nan))
    feet = feet.at[k].set(jnp.where(s.stepping, s.foothold, jnp.nan))
    used = used.at[k].set(jnp.where(s.stepping, s.policy, -1).astype(jnp.int32))
    apex = jnp.where(s.ok, s.next_apex, apex)
    return (apex, s.code, steps + s.stepping.astype(jnp.int32), k + 1, (apexes, feet, used),
            s.control)


def run_result(carry, config: RunConfig):
    """`(code, steps, apexes, footholds, policies, recoveries)` of a finished (or cut-off)
    run."""
    apex, code, steps, _, (apexes, feet, used), control = carry
    return final_code(code, apex, config), steps, apexes, feet, used, control.recoveries


RUN_FIELDS = ("code", "steps", "apexes", "footholds", "policies", "recoveries")


def run_one(apex0, key, tables: PlanTables, true_terrain: Terrain, hopper: Hopper,
            disturbance: Disturbance, config: RunConfig):
    """Run the reactive controller from one initial apex until success or failure.

    The controller sees the apex plus sensor noise (fresh at every apex, from `key`); the
    stride runs on `true_terrain` with the disturbance's wind.

    Returns:
        `(code, steps, apexes, footholds, policies, recoveries)`: result code, strides taken,
        the `(max_steps + 1, 3)` apex sequence (NaN after the end), `(max_steps, 2)`
        footholds, the instantiated policy used at each stride (-1 after the end) and the
        strides taken from a recovered apex (adaptive controller; 0 with the paper's).
    """
    world = World(tables, true_terrain, hopper, disturbance)
    # A while loop, not a scan: a batch stops when its longest run ends.
    carry = jax.lax.while_loop(lambda c: run_live(c, config),
                               lambda c: run_step(c, key, world, config),
                               run_init(apex0, config))
    return run_result(carry, config)


def run_chunk(apex0, key, index, tables, true_terrain, hopper, disturbance, config):
    # Run i's noise comes from fold_in(key, i): independent of batch size and chunking.
    keys = jax.vmap(jax.random.fold_in, (None, 0))(key, index)
    return jax.vmap(run_one, (0, 0, None, None, None, None, None))(
        apex0, keys, tables, true_terrain, hopper, disturbance, config)


batch_jit = jit(run_chunk)
