"""The reactive planner on a parkour course: snapshots, incremental updates, batched runs.

`course_plans` builds the plan of the course's first environment in full and, for every
snapshot, updates it incrementally (`build_course_plan(..., previous=...)`), timing each
update (optionally against a full rebuild). `run_reactive` runs a batch of initial apexes
through the paper's reactive controller (Fig. 8: first match, deadbeat, clip; the run loop's
`step`) on the true terrain of the environment in force: environment `e` is in force from stride
`from_jump` on, so stride `k` is decided with the plan of the snapshot of replan `k`.

A stride fails with `restricted` (`margin`) when its touchdown lies strictly inside a
restricted area (a margin band). Disturbances (section VI-C's, Froude-scaled by the hopper's
size: `jaxhop._core.params.disturbance_for`): `wind` (horizontal acceleration `-0.2 g / 9.81` in
flight), `sensor` (uniform apex measurement noise `+-0.05` leg lengths on `y`, `z` and
`+-0.05 sqrt(g rho0 / 9.81)` on `ydot`), `landing` (the true apex is shifted by uniform
`+-0.05` leg lengths in `y` before each descent, i.e. each touchdown lands that much off).

All plans of a course are padded to common shapes, so one compilation of the stride
serves every snapshot (and every course with the same padded sizes).
"""

from __future__ import annotations

import dataclasses
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._control.decisions import decide, in_global_domain, model_for
from .._control.runloop import Control, RunConfig, World, control_init, final_code, step
from .._core.batching import bucket, pad_terrain, pad_to
from .._core.params import NOISE_KINDS, Hopper, check_noise, disturbance_for
from .._core.programs import jit
from .._core.result import Result
from .._planning.plan import PlanTables
from .._planning.policies import PairGrid
from .._planning.templates import template_scales
from ..mppc._course import Course
from ._build import CoursePlan, build_course_plan
from ._map import CourseMap, course_map

#: Disturbances of course runs: `ground` does not apply (the planner's map of a course is
#: exact; its uncertainty is the snapshots').
COURSE_NOISE = tuple(k for k in NOISE_KINDS if k != "ground")
#: Strides a course run may take before it ends with `max_steps`.
MAX_STRIDES = 80
#: Course plans: coarser intersection grid than `jaxhop.build_plan`'s 16 x 16 (docs).
COURSE_GRID = PairGrid(8, 8)


@dataclasses.dataclass
class CoursePlans:
    """The plans of a course's environments and how long they took."""

    course: Course
    starts: list  # from_jump of each environment (0 first)
    maps: list
    plans: list
    build_s: float
    update_s: list
    update_cpu_s: list
    rebuild_s: list
    rebuild_cpu_s: list
    rebuild_equal: list = dataclasses.field(default_factory=list)
    rebuilt: list = dataclasses.field(default_factory=list)

    def index_at(self, k: int) -> int:
        return max(i for i, s in enumerate(self.starts) if s <= k)


def course_plans(course: Course, hopper: Hopper, templates, *, grid: PairGrid = COURSE_GRID,
                 rebuild: int = 0, log=None, align: bool = True) -> CoursePlans:
    """Full plan for the first environment, incremental updates for the snapshots.

    The first `rebuild` snapshots' plans are also built in full (timed, kept in
    `CoursePlans.rebuilt`), for the update-vs-rebuild comparison;
    `CoursePlans.rebuild_equal` records whether the full rebuild gave the same deployment
    (same policies, goals and order) as the update.
    `align` is `course_map`'s option (default: segments flush with the floor lattice).
    """
    envs = [(0, course.environment)] + list(course.snapshots)
    maps = [course_map(course, env, hopper, align=align) for _, env in envs]
    t0, c0 = time.perf_counter(), time.process_time()
    plans = [build_course_plan(maps[0], templates, hopper, grid=grid)]
    build_s = time.perf_counter() - t0
    if log:
        log(f"{course.name}: full plan {build_s:.1f} s "
            f"({plans[0].stats['n_instantiated']} policies)")
    del c0
    update_s, update_cpu, rebuild_s, rebuild_cpu, equal, rebuilt = [], [], [], [], [], []
    for m in maps[1:]:
        t0, c0 = time.perf_counter(), time.process_time()
        plans.append(build_course_plan(m, templates, hopper, grid=grid, previous=plans[-1]))
        update_s.append(time.perf_counter() - t0)
        update_cpu.append(time.process_time() - c0)
        if len(rebuild_s) < int(rebuild):
            t0, c0 = time.perf_counter(), time.process_time()
            full = build_course_plan(m, templates, hopper, grid=grid)
            rebuild_s.append(time.perf_counter() - t0)
            rebuild_cpu.append(time.process_time() - c0)
            equal.append(same_deployment(full, plans[-1]))
            rebuilt.append(full)
        if log:
            log(f"{course.name}: update {update_s[-1]:.2f} s"
                + (f", rebuild {rebuild_s[-1]:.2f} s" if len(rebuild_s) == len(update_s)
                   else ""))
    return CoursePlans(course, [k for k, _ in envs], maps, plans, build_s, update_s,
                       update_cpu, rebuild_s, rebuild_cpu, equal, rebuilt)


def same_deployment(a: CoursePlan, b: CoursePlan) -> bool:
    """Same instantiated policies (situated, target), goals (to 1e-12) and order."""
    pa, pb = a.plan, b.plan
    return bool(pa.goals.shape == pb.goals.shape and np.array_equal(pa.situated, pb.situated)
                and np.array_equal(pa.target, pb.target)
                and np.allclose(pa.goals, pb.goals, rtol=0, atol=1e-12)
                and np.array_equal(pa.order, pb.order))


def identical_plans(a: CoursePlan, b: CoursePlan) -> bool:
    """`same_deployment`, and bit for bit the same goals, margins, safety, robustness, goal
    policies and prepares matrix (an incremental update against a full rebuild)."""
    pa, pb = a.plan, b.plan
    return bool(same_deployment(a, b) and np.array_equal(pa.goals, pb.goals)
                and np.array_equal(pa.margin, pb.margin) and np.array_equal(pa.safety, pb.safety)
                and np.array_equal(pa.robustness, pb.robustness)
                and np.array_equal(pa.is_goal, pb.is_goal)
                and (pa.prepares != pb.prepares).nnz == 0)


# --- padding: one compiled stride for every environment ------------------------------


def hold_tables(plan) -> tuple[np.ndarray, np.ndarray]:
    """Holding strides (`docs/parkour_reactive.md`, "Holding"): `(hold_pos, best_inst)`.

    A situated policy none of whose instantiated policies is deployed (a snapshot left its
    part of the course without a route to the goal) still has safe strides: each of its
    instantiated policies has a collision-free goal in another situated domain on the
    current map. Per such situated policy, the best of them by robustness, then safety
    (eq 34), then id; `hold_pos` is its rank among all of them (`iinfo(int32).max` for
    deployed situated policies and those without instantiated policies), `best_inst` the
    plan's, with that policy where none is deployed.
    """
    big = np.iinfo(np.int32).max
    best_pos, best_inst = plan.best_per_situated()
    cand = np.nonzero(best_pos[plan.situated] == big)[0]
    rank = np.lexsort((cand, -plan.safety[cand], -plan.robustness[cand]))
    cand = cand[rank]
    sit = plan.situated[cand]
    _, first = np.unique(sit, return_index=True)  # the best per situated policy
    hold_pos = np.full(best_pos.shape, big, np.int64)
    hold_pos[sit[first]] = first
    best_inst = best_inst.copy()
    best_inst[sit[first]] = cand[first]
    return hold_pos, best_inst


def _pad_tables(cp: CoursePlan, n_blocks: int, n_seg: int, n_inst: int,
                slip: bool) -> PlanTables:
    tb = cp.plan.tables(slip=slip)
    hold_pos, best_inst = hold_tables(cp.plan)
    held = PlanTables(tb.table, tb.templates, tb.terrain, tb.best_pos, jnp.asarray(best_inst),
                      tb.goals, tb.slip, hold_pos=jnp.asarray(hold_pos))
    return held.padded(n_blocks, n_seg, n_inst)


def _forbidden(m: CourseMap, n: int) -> jnp.ndarray:
    return pad_to(np.asarray(m.forbidden_intervals(), float), n, 0.0)


def course_disturbance(noise: str, hopper: Hopper):
    """The disturbance of a course run, Froude-scaled to the hopper (`COURSE_NOISE`)."""
    return disturbance_for(check_noise(noise, COURSE_NOISE), hopper)


def _course_step(apex, code, key, k, world: World, config: RunConfig, control: Control):
    """`step` for the runs still going (ended runs keep their code): `(apex, code, foothold,
    policy, stepping, control)`."""
    s = step(apex, key, k, world, config, control=control)
    running = code == Result.RUNNING
    stepping = running & s.stepping
    control = jax.tree.map(lambda new, old: jnp.where(running, new, old), s.control, control)
    return (jnp.where(running & s.ok, s.next_apex, apex), jnp.where(running, s.code, code),
            jnp.where(stepping, s.foothold, jnp.nan), jnp.where(stepping, s.policy, -1),
            stepping, control)


def _course_config(goal, tol, model, max_steps: int = MAX_STRIDES,
                   controller: str = "paper") -> RunConfig:
    # Course runs draw four uniforms per apex: sensor noise and the landing error.
    return RunConfig(goal, tol, max_steps=max_steps, model=model, landing=True,
                     controller=controller)


def _step_one(apex, code, key, k, tables, true_terrain, forb, goal, tol, dist, hopper, model,
              control, controller):
    return _course_step(apex, code, key, k, World(tables, true_terrain, hopper, dist, forb),
                        _course_config(goal, tol, model, controller=controller), control)


_step_vmap = jit(jax.vmap(_step_one, (0, 0, 0, None, None, None, None, None, None, None,
                                          None, None, 0, None)),
                     static_argnames=("model", "controller"))


def _step_batch(apex, code, keys, k, tables, true_terrain, forb, goal, tol, dist, hopper,
                model, control=None, controller="paper"):
    """One stride of a batch of course runs: `(apex, code, foothold, policy, stepping,
    control)`; `control` defaults to fresh runs' controller states."""
    if control is None:
        control = jax.vmap(lambda _: control_init())(jnp.arange(apex.shape[0]))
    # Codes as int32 whatever the caller passes (the step returns int64): a code of another
    # type would select another compiled step for the next stride.
    return _step_vmap(apex, jnp.asarray(code, jnp.int32), keys, k, tables, true_terrain, forb,
                      goal, tol, dist, hopper, model, control, controller)


_decide_jit = jit(decide, static_argnames=("model",))


@dataclasses.dataclass
class Padded:
    tables: list
    terrains: list
    forbidden: list


def pad_plans(cps: CoursePlans, model: str = "bhop") -> Padded:
    """Every plan's controller tables padded to one shape (one compiled run loop); for
    `model="slip"` with the SLIP deadbeat's start table (`jaxhop._models.slip.table`)."""
    slip = not model_for(model).instant_stance
    nb = bucket(max(m.true.n_blocks for m in cps.maps) + 1, 64)
    ns = bucket(max(cp.plan.stats["n_segments"] for cp in cps.plans), 256)
    ni = bucket(max(cp.plan.goals.shape[0] for cp in cps.plans), 65536)
    nf = bucket(max(m.forbidden_intervals().shape[0] for m in cps.maps), 32)
    return Padded([_pad_tables(cp, nb, ns, ni, slip) for cp in cps.plans],
                  [pad_terrain(m.true, nb) for m in cps.maps],
                  [_forbidden(m, nf) for m in cps.maps])


def goal_tolerance(hopper: Hopper) -> np.ndarray:
    """The goal tolerance (0.05 m, 0.05 m, 0.05 m/s for the paper's hopper), Froude-scaled."""
    f = template_scales(hopper)
    return np.array([0.05 * f["length"], 0.05 * f["length"], 0.05 * f["velocity"]])


def initial_states(cps: CoursePlans, padded: Padded, n: int, seed: int,
                   hopper: Hopper) -> tuple[np.ndarray, float]:
    """`n` seeded initial apexes near the start, inside the first plan's global domain.

    Drawn uniformly from the box `y in start + [0, 1] rho0`, `zr in [0.3, 0.8] rho0` over
    the floor, `ydot in [0, 0.3] sqrt(g rho0)`, and kept if the plan covers them (rejection
    sampling). Returns the states and the covered fraction of the box.
    """
    leg, v = float(hopper.rho0), math.sqrt(float(hopper.g) * float(hopper.rho0))
    rng = np.random.default_rng(seed)
    out, tried, kept = [], 0, 0
    while len(out) < n and tried < 200 * max(n, 1):
        m = max(4 * n, 64)
        box = np.column_stack([cps.course.start + rng.uniform(0, 1, m) * leg,
                               leg * (1.0 + rng.uniform(0.3, 0.8, m)),
                               rng.uniform(0, 0.3, m) * v])
        inside = in_global_domain(box, padded.tables[0], hopper)
        tried += m
        kept += int(inside.sum())
        out.extend(box[inside].tolist())
    return np.asarray(out[:n]).reshape(-1, 3), kept / max(tried, 1)


def run_reactive(cps: CoursePlans, padded: Padded, apex0, *, hopper: Hopper, noise="none",
                 seed: int = 0, model: str = "bhop", controller: str = "adaptive") -> dict:
    """Run a batch of initial apexes over the course (snapshots in force by stride).

    Stride `k` of every run is one jitted `step` (vmapped) against the plan and true map of
    the environment in force (`CoursePlans.index_at(k)`); run `i` draws its noise from
    `fold_in(key(seed), i)`; each run takes at most `MAX_STRIDES` strides. `controller`:
    `"adaptive"` (the default) or `"paper"` (`RunConfig`).

    Returns:
        dict of NumPy arrays: `code (n,)`, `steps (n,)`, `apexes (n, MAX_STRIDES + 1, 3)`,
        `footholds (n, MAX_STRIDES, 2)`, `policies (n, MAX_STRIDES)`, `recoveries (n,)`.
    """
    apex0 = np.atleast_2d(np.asarray(apex0, float))
    n = apex0.shape[0]
    nb = bucket(n, 8)
    apex = jnp.asarray(np.concatenate([apex0, np.repeat(apex0[-1:], nb - n, 0)]))
    keys = jax.vmap(jax.random.fold_in, (None, 0))(jax.random.key(seed), jnp.arange(nb))
    code = jnp.full(nb, Result.RUNNING, jnp.int32)
    goal = jnp.asarray(cps.maps[0].goal)
    tol = jnp.asarray(goal_tolerance(hopper))
    dist = course_disturbance(noise, hopper)
    apexes = np.full((nb, MAX_STRIDES + 1, 3), np.nan)
    apexes[:, 0] = np.asarray(apex)
    feet = np.full((nb, MAX_STRIDES, 2), np.nan)
    used = np.full((nb, MAX_STRIDES), -1, np.int64)
    steps = np.zeros(nb, np.int64)
    control = jax.vmap(lambda _: control_init())(jnp.arange(nb))
    for k in range(MAX_STRIDES):
        e = cps.index_at(k)
        apex, code, foot, a, stepping, control = _step_batch(
            apex, code, keys, k, padded.tables[e], padded.terrains[e], padded.forbidden[e],
            goal, tol, dist, hopper, model, control, controller)
        stepping = np.asarray(stepping)
        steps += stepping
        feet[:, k] = np.asarray(foot)
        used[:, k] = np.asarray(a)
        apexes[stepping, k + 1] = np.asarray(apex)[stepping]
        if not np.any(np.asarray(code) == Result.RUNNING):
            break
    config = _course_config(goal, tol, model, MAX_STRIDES)
    code = np.asarray(jax.vmap(final_code, (0, 0, None))(code, apex, config))
    return {"code": code[:n], "steps": steps[:n], "apexes": apexes[:n], "footholds": feet[:n],
            "policies": used[:n], "recoveries": np.asarray(control.recoveries)[:n]}


def decision_ms(cps: CoursePlans, padded: Padded, apexes, hopper: Hopper,
                model: str = "bhop") -> list:
    """Wall time (ms) of single-apex decisions, warm (one call per apex)."""
    out = []
    tables = padded.tables[0]
    _decide_jit(jnp.asarray(apexes[0]), tables, hopper, model)[1].block_until_ready()
    for z in apexes:
        z = jnp.asarray(z)
        t0 = time.perf_counter()
        _decide_jit(z, tables, hopper, model)[1].block_until_ready()
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def executed_strides(result: dict, i: int, hopper: Hopper, wind: float = 0.0) -> list:
    """Run `i` as a list of `{xs, zs, v, theta, t, x1, z1}` (the MPPC result's `executed`).

    Stride `k`: `xs, zs` its foothold; `v, theta` the COM's liftoff speed and angle from
    the horizontal; `t` the flight from liftoff to the next touchdown (to the final apex
    for the last stride); `x1, z1` the next foothold (for the last stride the point under
    the final apex).
    """
    g, rho0 = float(hopper.g), float(hopper.rho0)
    n = int(result["steps"][i])
    ap, ft = result["apexes"][i], result["footholds"][i]
    out = []
    for k in range(n):
        y_f, h = ft[k]
        nxt = ap[k + 1]
        if not np.all(np.isfinite(nxt)):
            break
        t_up = math.sqrt(max(2.0 * (nxt[1] - h - rho0) / g, 0.0))
        ydot_lo = nxt[2] - wind * t_up
        zdot_lo = g * t_up
        if k + 1 < n and np.all(np.isfinite(ft[k + 1])):
            x1, z1 = ft[k + 1]
            t_d = math.sqrt(max(2.0 * (nxt[1] - z1 - rho0) / g, 0.0))
        else:
            x1, z1, t_d = nxt[0], h, 0.0
        out.append({"xs": float(y_f), "zs": float(h), "v": float(math.hypot(ydot_lo, zdot_lo)),
                    "theta": float(math.atan2(zdot_lo, ydot_lo)), "t": float(t_up + t_d),
                    "x1": float(x1), "z1": float(z1)})
    return out


def first_descent(result: dict, i: int, hopper: Hopper) -> float:
    """Time from the initial apex to the first touchdown."""
    ap, ft = result["apexes"][i], result["footholds"][i]
    if not np.all(np.isfinite(ft[0])):
        return 0.0
    return math.sqrt(max(2.0 * (ap[0][1] - ft[0][1] - float(hopper.rho0)) / float(hopper.g),
                         0.0))


def snapshot_flights(cps: CoursePlans, result: dict, hopper: Hopper) -> list[dict]:
    """For each snapshot, whether its update finished within the flight in which it started.

    A snapshot in force from stride `k` (`from_jump`) is seen when the leg lifts off for
    stride `k - 1`, the last one on the old plan; its update starts then. That stride's
    flight lasts `flight_s` (liftoff to the next touchdown), and stride `k` is decided at
    its apex, `ascent_s` after the liftoff. Both are the shortest over the runs that flew
    stride `k - 1` (None where none did, or `k = 0`). `within_flight`: the update took at
    most `flight_s`; `before_decision`: at most `ascent_s`.
    """
    g, rho0 = float(hopper.g), float(hopper.rho0)
    apexes, feet, steps = result["apexes"], result["footholds"], result["steps"]
    out = []
    for k, update in zip(cps.starts[1:], cps.update_s):
        row = {"from_jump": int(k), "update_s": float(update), "flight_s": None,
               "ascent_s": None, "within_flight": None, "before_decision": None}
        out.append(row)
        flew = np.nonzero(steps >= k)[0] if 1 <= k < feet.shape[1] else []
        if not len(flew):
            continue
        # Liftoff from foothold k - 1 up to apex k, then down to foothold k (a run that
        # ended at apex k: down to the ground it lifted off from).
        z, h0, h1 = apexes[flew, k, 1], feet[flew, k - 1, 1], feet[flew, k, 1]
        h1 = np.where(np.isfinite(h1), h1, h0)
        up = np.sqrt(np.maximum(2.0 * (z - h0 - rho0) / g, 0.0))
        down = np.sqrt(np.maximum(2.0 * (z - h1 - rho0) / g, 0.0))
        row["flight_s"], row["ascent_s"] = float(np.min(up + down)), float(np.min(up))
        row["within_flight"] = bool(update <= row["flight_s"])
        row["before_decision"] = bool(update <= row["ascent_s"])
    return out

