"""The hopping models a run can use: each one's stride and its reactive decision.

`BHOP` strides with the BHop map (eqs 25-29) and decides with the BHop deadbeat on the
first matching policy (Fig. 8); `SLIP` strides with the SLIP model (eqs 12-16, a diffrax
solve) and decides with the SLIP deadbeat on the best SLIP-reachable match
(`docs/decisions.md`, "SLIP on BHop plans"). Public functions take the names `"bhop"` and
`"slip"` and convert them once with `model_for`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._core.batching import bounded_while
from .._core.errors import InputError
from .._core.params import REFERENCE_HOPPER, Hopper
from .._core.programs import jit
from .._core.terrain import Terrain
from .._models.bhop import ascent, deadbeat_bhop, safe_sqrt, stance
from .._models.flight import COLLISION, OK, liftoff_clear, touchdown
from .._planning.plan import PlanTables
from .._planning.policies import candidate_situated
from .._planning.regions import foot_lead
from .foothold import mapped_height
from .observer import Q_MIN_SLIP, Observer, observe, slip_prediction, slip_terms


def bhop_stride(apex, u, terrain: Terrain, hopper: Hopper, wind=0.0):
    """One BHop stride on the terrain: descent, touchdown, stance, rise to the next apex.

    Returns:
        `(next_apex, code, foothold)`: `code` is `OK` or a failure; `foothold = (y, h)`.
    """
    code, block, _, y_foot, v_td = touchdown(apex, jnp.array([0.0, -hopper.rho0]), terrain,
                                             hopper, wind)
    h = terrain.heights[block]
    y_lo, v_lo = stance(y_foot, v_td, u)
    clear = liftoff_clear(y_foot, y_lo, v_lo, h, terrain, hopper, wind)
    nxt = ascent(y_lo, v_lo, h, hopper, wind)
    code = jnp.where(code == OK, jnp.where(clear, OK, COLLISION), code)
    return nxt, code, jnp.stack([y_foot, h])


_NO_MATCH = jnp.iinfo(jnp.int32).max

# Recovery outside the domains (docs/decisions.md, "Adaptive controller"): the nearest
# deployed domain is taken when it lies within RECOVERY_DISTANCE (scaled, see
# `domain_distance`) of the measured apex: at most one range width outside on the worst
# axis (the paper's sensor noise, +-0.05 m in z, is +-39 J, the narrowest energy band 40 J).
RECOVERY_DISTANCE = 1.0


def domain_distance(apex, ids, tables: PlanTables, hopper: Hopper):
    """Scaled distance from `apex` to the domains of situated policies `ids` (eqs 38-41).

    Per axis, how far the apex lies outside the domain's range in units of that range:
    the touchdown `y` of a ballistic fall to the segment's height against the segment
    `[-l, l]` (over `2 l`), `ydot` against `[v_lo, v_hi]` (over its width), the energy over
    the segment's virtual ground against `[e_lo, e_hi]` (over its width); the distance is
    the largest of the three (0 inside the domain's ranges). A segment the apex is not
    above (`z <= h + rho0`) is at `inf`.
    """
    tm = tables.templates
    seg, t = ids // tm.n, ids % tm.n
    py, h = tables.table.centre[seg, 0], tables.table.centre[seg, 1]
    zr = apex[1] - h - hopper.rho0
    y_td = apex[0] + apex[2] * safe_sqrt(2.0 * zr / hopper.g) + foot_lead(apex[2], tm)
    l = tm.half_length

    def beyond(x, lo, hi):
        return jnp.maximum(jnp.maximum(lo - x, x - hi), 0.0) / (hi - lo)

    energy = 0.5 * hopper.m * apex[2] ** 2 + hopper.m * hopper.g * zr
    d = jnp.maximum(jnp.maximum(beyond(y_td - py, -l, l), beyond(apex[2], tm.v_lo[t],
                                                                    tm.v_hi[t])),
                    beyond(energy, tm.e_lo[t], tm.e_hi[t]))
    return jnp.where(zr > 0, d, jnp.inf)


def recovery_candidates(apex, tables: PlanTables, hopper: Hopper):
    """Situated ids a recovery considers: on every block, the segment nearest to where the
    foot falls through the block's top height (all templates)."""
    tb, tm = tables.table, tables.templates
    h = tables.terrain.heights
    t_fall = safe_sqrt(2.0 * (apex[1] - h - hopper.rho0) / hopper.g)
    y = apex[0] + apex[2] * t_fall + foot_lead(apex[2], tm)
    k = jnp.floor((y - tb.block_left) / tm.segment).astype(jnp.int32)
    seg = tb.block_first + jnp.clip(k, 0, jnp.maximum(tb.block_count - 1, 0))
    seg = jnp.where(tb.block_count > 0, seg, 0)
    ids = (seg[:, None] * tm.n + jnp.arange(tm.n)[None, :]).reshape(-1)
    return ids, jnp.repeat(tb.block_count > 0, tm.n)


def _match_positions(apex, tables: PlanTables, hopper: Hopper, recover: bool = False,
                     exclude=None):
    """Situated candidates near the apex and their deployment position (`_NO_MATCH` where
    the domain does not contain the apex), and whether the apex was recovered.

    With `recover`, an apex in no deployed domain takes the nearest deployed domain among
    `recovery_candidates` (`domain_distance`, ties to the earlier deployed) if it lies
    within `RECOVERY_DISTANCE`; the candidates are then followed by those. Where neither
    holds and the tables carry `hold_pos`, the undeployed situated domains containing the
    apex take part in hold order (a holding stride, also reported as recovered; for them
    `best_inst` names the undeployed instantiated policy).

    `exclude(ids) -> mask`: situated policies left out, as if their domains did not hold
    the apex and were not near it.
    """
    ids, inside = candidate_situated(apex, tables.table, tables.templates, tables.terrain,
                                     hopper)
    pos = jnp.where(inside, tables.best_pos[ids], _NO_MATCH)
    if exclude is not None:
        pos = jnp.where(exclude(ids), _NO_MATCH, pos)
    if not recover:
        return ids, pos, jnp.asarray(False)
    rec, valid = recovery_candidates(apex, tables, hopper)
    best = tables.best_pos[rec]
    if exclude is not None:
        best = jnp.where(exclude(rec), _NO_MATCH, best)
    d = jnp.where(valid & (best < _NO_MATCH), domain_distance(apex, rec, tables, hopper),
                  jnp.inf)
    near = jnp.min(d)
    pick = jnp.argmin(jnp.where(d == near, best, _NO_MATCH))
    recovered = jnp.all(pos == _NO_MATCH) & (near <= RECOVERY_DISTANCE)
    rec_pos = jnp.where(recovered & (jnp.arange(rec.shape[0]) == pick), best, _NO_MATCH)
    if tables.hold_pos is not None:
        # Holding: no deployed domain holds the apex or lies near it (a snapshot took the
        # route away); the undeployed situated domains containing it, in hold order.
        hold = jnp.all(pos == _NO_MATCH) & ~recovered
        hold_pos = jnp.where(hold & inside, tables.hold_pos[ids], _NO_MATCH)
        recovered = recovered | (hold & jnp.any(hold_pos < _NO_MATCH))
        pos = jnp.minimum(pos, hold_pos)
    return jnp.concatenate([ids, rec]), jnp.concatenate([pos, rec_pos]), recovered


def first_match(apex, tables: PlanTables, hopper: Hopper, recover: bool = False):
    """The first deployed policy whose domain contains `apex`.

    Only the first deployed instantiated policy of each situated policy can ever be the
    first match (they share a domain), so the order reduces to `best_pos` per situated
    policy; the situated candidates are those on the segment of the nominal touchdown.
    With `recover`, the nearest deployed domain where none contains it (`_match_positions`).

    Returns:
        `(found, situated, instantiated)`, and with `recover` whether it was recovered.
    """
    ids, pos, recovered = _match_positions(apex, tables, hopper, recover)
    k = jnp.argmin(pos)
    found = pos[k] < _NO_MATCH
    out = (found, ids[k], tables.best_inst[ids[k]])
    return out + (recovered,) if recover else out


def _in_domain(apexes, tables: PlanTables, hopper: Hopper):
    return jax.vmap(lambda z: first_match(z, tables, hopper)[0])(apexes)


_in_domain_jit = jit(_in_domain)


def in_global_domain(apexes, tables: PlanTables, hopper: Hopper) -> np.ndarray:
    """Which apexes lie in the union of the deployed policies' domains."""
    return np.asarray(_in_domain_jit(jnp.asarray(apexes, float), tables, hopper))


def clip_to_template(u, tmpl):
    """BHop controls within a template's limits; a non-finite deadbeat takes the upper ones."""
    lo = jnp.stack([tmpl.dy_lo, tmpl.th_lo, tmpl.k_lo])
    hi = jnp.stack([tmpl.dy_hi, tmpl.th_hi, tmpl.k_hi])
    return jnp.clip(jnp.where(jnp.isfinite(u), u, hi), lo, hi)


def sensed_foothold(apex, foot_offset, terrain: Terrain, hopper: Hopper, wind=0.0):
    """The foothold a descent from `apex` lands on (`foothold.py`): `(landed, (y, h))`."""
    code, block, _, y_foot, _ = touchdown(apex, foot_offset, terrain, hopper, wind)
    return code == OK, jnp.stack([y_foot, terrain.heights[block]])


def decide_bhop(apex, tables: PlanTables, hopper: Hopper, wind=None, heights=None,
                h_touch=None):
    """BHop controls for one measured apex: first match, deadbeat to its goal (eqs 25-29),
    clip to its template's limits.

    `wind`: the adaptive controller (`None`: the paper's): the deadbeat inverts the flight
    with this estimated wind, and an apex in no domain is recovered (`first_match`). Its
    deadbeat takes the foothold height sensed at touchdown `h_touch` where finite, else the
    height of the policy's block in the corrected map `heights` (`jaxhop._control.foothold`).

    Returns:
        `(found, u, instantiated)`, and with `wind` whether the apex was recovered.
    """
    adaptive = wind is not None
    found, s, a, *recovered = first_match(apex, tables, hopper, recover=adaptive)
    nt = tables.templates.n
    h = tables.table.centre[s // nt, 1]
    if heights is not None:
        h = heights[tables.table.seg_block[s // nt]]
    if h_touch is not None:
        h = jnp.where(jnp.isfinite(h_touch), h_touch, h)
    u = deadbeat_bhop(apex, tables.goals[a], h, hopper, *([wind] if adaptive else []))
    return (found, clip_to_template(u, tables.templates.row(s % nt)), a, *recovered)


# SLIP decisions (docs/decisions.md, "SLIP on BHop plans"): the deadbeat is tried on the
# first SLIP_CANDIDATES matching policies in deployment order; the first whose predicted
# apex lands within SLIP_ACCEPT of its goal wins, else the smallest scaled miss.
# SLIP_ACCEPT and SLIP_STAGE_C2 are in the units of the reference hopper (80 kg, 1 m) and
# are Froude-scaled to the hopper (`_slip_scales`).
SLIP_CANDIDATES = 2
SLIP_ACCEPT = (0.05, 0.05, 0.05)
# A decision's deadbeat tries the table's further starts where the best one ends with a C2
# above this (an apex error of 1 cm; `table.deadbeat_table`). It runs the
# multi-start solver only where the table has no start: where every table start misses, so
# does the multi-start solver on nearly every target (docs/slip.md, "Deadbeat").
SLIP_STAGE_C2 = 1e-4
# Capture strides (docs/decisions.md, "Capture strides"): within CAPTURE_TOLERANCES goal
# tolerances of the global goal on every axis, the second candidate of the adaptive SLIP
# decision is an apex from which one stride stops at the goal, moving at the speed that
# covers the way there in CAPTURE_FALLS falls from the goal's height.
CAPTURE_TOLERANCES = 4.0
CAPTURE_FALLS = 3.0


def _slip_scales(hopper: Hopper):
    """`SLIP_ACCEPT` and `SLIP_STAGE_C2` for `hopper`: positions times `L = rho0 / 1 m`, the
    speed times `V = sqrt(g rho0 / 9.81 m^2/s^2)`, C2 (m^2) times `L^2`; exactly the
    constants for the reference hopper (traced: the hopper may be)."""
    _, g0, l0 = REFERENCE_HOPPER
    length = hopper.rho0 / l0
    speed = jnp.sqrt((hopper.g / g0) * length)
    scale = jnp.asarray(SLIP_ACCEPT) * jnp.stack([length, length, speed])
    return scale, SLIP_STAGE_C2 * length**2


def _first_accepted(one, goals, h, valid, fixed=False):
    """`one(goal, h) -> (u, miss, pred)` on the valid candidates in order, each only where
    every earlier one missed (`miss > 1`). One while loop: under `vmap` a candidate costs
    nothing in a batch whose lanes all accepted an earlier one (or have none valid).
    Candidates not tried keep `miss = inf`. `fixed`: `bounded_while`'s fixed loop."""
    n = goals.shape[0]
    order = jnp.argsort(~valid, stable=True)
    n_valid = jnp.sum(valid)

    def more(carry):
        i, _, misses, _ = carry
        return (i < n_valid) & jnp.all(misses > 1.0)

    def next_one(carry):
        i, us, misses, preds = carry
        c = order[i]
        u, m, p = one(goals[c], h[c])
        return i + 1, us.at[c].set(u), misses.at[c].set(m), preds.at[c].set(p)

    carry = (jnp.asarray(0), jnp.zeros((n, 3)), jnp.full((n,), jnp.inf),
             jnp.full((n, 3), jnp.nan))
    _, us, misses, preds = bounded_while(more, next_one, carry, n, fixed)
    return us, misses, preds


def capture_target(apex, goal, tolerance, h, hopper: Hopper):
    """`(near, target)` of a capture stride (`decide_slip`): whether `apex` lies within
    `CAPTURE_TOLERANCES` goal `tolerance`s of the goal at rest `goal` on every axis, and the
    apex `(y_g - 1.5 v t, z_g, v)` to aim at instead, from which one stride stops at the
    goal: `t` the fall from the goal's height to a foothold at height `h`, `v` the speed
    that covers the way to the goal in `CAPTURE_FALLS` such falls. The stop covers about
    `v t` in its descent and half that in its stance, so the target lies half way to the
    goal."""
    near = jnp.all(jnp.abs(apex - goal) <= CAPTURE_TOLERANCES * tolerance)
    t_fall = safe_sqrt(2.0 * (goal[1] - h - hopper.rho0) / hopper.g)
    v = (goal[0] - apex[0]) / (CAPTURE_FALLS * jnp.maximum(t_fall, 1e-3))
    return near, jnp.stack([goal[0] - 1.5 * v * t_fall, goal[1], v])


def decide_slip(apex, tables: PlanTables, hopper: Hopper, recover: bool = False, heights=None,
                wind=None, recover_again=True, capture=None):
    """SLIP controls for one measured apex: the deadbeat on the best SLIP-reachable match.

    The BHop plan's domains and goals ignore what the SLIP stance cannot do (the paper's
    eqs 35-37 only approximate it), so the goal of the first match may be out of one SLIP
    stride's reach (e.g. stopping at the global goal from a foothold a few cm off). The
    controller runs the SLIP deadbeat (eqs 12-16) for the `SLIP_CANDIDATES` highest-priority
    matching policies, predicts each stride over the policy's foothold height, and takes the
    first in deployment order whose prediction lies within `SLIP_ACCEPT` of its goal; when
    none does, the one with the smallest miss relative to `SLIP_ACCEPT`. The deadbeat's
    trial strides and the prediction run at `decision_tol()` (an apex within 7e-5 of the
    executed 1e-10 stride on a CPU, 1e-5 elsewhere: far inside `SLIP_ACCEPT`).

    A chosen miss whose predicted apex lies in the same policy's domain again, no nearer its
    goal, would repeat from there stride after stride (a goal ahead of a hopper standing
    still that the BHop plan allows, docs/decisions.md, "Strides that stay put"): the
    decision is then taken again without that policy (the next matches, or with `recover`
    the nearest other domain), where there is one. `recover_again` (traced): whether that
    second decision may be a recovery (False: the paper's controller run by the adaptive
    controller's program, which treats a recovered apex as outside the domains).

    `capture = (goal, tolerance, on)` (the adaptive controller; `on` traced): near the
    run's global goal at rest, where the plan's goal stride cannot stop a SLIP a few cm
    away, the second candidate is a capture stride (`capture_target`), taken only where its
    prediction lands within `SLIP_ACCEPT` of its target, as the goal policy's stride
    (docs/decisions.md, "Capture strides").

    With `recover` (the adaptive controller) an apex in no domain is recovered
    (`first_match`). `heights`: the block heights of the controller's corrected map
    (`jaxhop._control.foothold`), for the deadbeat and its prediction. `wind`: the estimated flight
    acceleration the deadbeat inverts and the prediction flies with (`None`: none).

    Returns:
        `(found, u, instantiated)`, and with `recover` whether the apex was recovered.
    """
    from .._models.slip.deadbeat import DeadbeatSearch, deadbeat_slip
    from .._models.slip.kernels import decision_tol

    nt = tables.templates.n
    terrain = tables.terrain if heights is None else tables.terrain.with_heights(heights)
    scale, stage_c2 = _slip_scales(hopper)

    tol = decision_tol()

    def one(apex, goal, h_):
        search = DeadbeatSearch(tol=tol, table=tables.slip, fallback=False, accept=stage_c2)
        u, _, pred, code = deadbeat_slip(apex, goal, h_, hopper, search, terrain=terrain,
                                         wind=wind, predict=True)
        miss = jnp.max(jnp.abs(pred - goal) / scale)
        return u, jnp.where((code == OK) & jnp.all(jnp.isfinite(pred)), miss, jnp.inf), pred

    near = jnp.asarray(False)
    if capture is not None:
        goal, tolerance, on = capture
        goal = jnp.asarray(goal, float)
        is_goal = jnp.all(tables.goals == goal, axis=1)
        h_goal = mapped_height(jnp.stack([goal[0], goal[1] - hopper.rho0]), terrain.heights,
                               terrain)
        near, target = capture_target(apex, goal, tolerance, h_goal, hopper)
        near = near & jnp.any(is_goal) & jnp.isfinite(h_goal) & on

    def choose(apex, exclude):
        ids, pos, recovered = _match_positions(apex, tables, hopper, recover, exclude)
        neg, k = jax.lax.top_k(-pos, SLIP_CANDIDATES)
        valid = -neg < _NO_MATCH
        sit = ids[k]
        inst = tables.best_inst[sit]
        goals = tables.goals[inst]
        h = tables.table.centre[sit // nt, 1]
        if heights is not None:
            h = heights[tables.table.seg_block[sit // nt]]
        captures = near & (jnp.arange(SLIP_CANDIDATES) == 1)
        if capture is not None:  # near the goal the capture stride replaces the second match
            valid = valid | captures
            sit = jnp.where(captures, -1, sit)
            inst = jnp.where(captures, jnp.argmax(is_goal), inst)
            goals = jnp.where(captures[:, None], target, goals)
            h = jnp.where(captures, h_goal, h)
        if tables.slip is None:
            u, miss, pred = jax.vmap(one, (None, 0, 0))(apex, goals, h)
        else:
            u, miss, pred = _first_accepted(lambda g, h_: one(apex, g, h_), goals, h, valid,
                                            tol.fixed_loops)
        miss = jnp.where(valid & ~(captures & (miss > 1.0)), miss, jnp.inf)
        good = miss <= 1.0
        pick = jnp.where(jnp.any(good), jnp.argmax(good), jnp.argmin(miss))
        # No candidate at all (outside every domain) or no completed stride: the first match.
        pick = jnp.where(jnp.isfinite(miss[pick]), pick, 0)
        # A miss that lands back in the same domain no nearer its goal is a loop: the same
        # apex gives the same decision (docs/decisions.md, "Strides that stay put").
        found_next, sit_next, _ = first_match(pred[pick], tables, hopper)
        away = jnp.max(jnp.abs(apex - goals[pick]) / scale) <= miss[pick]
        stuck = (~jnp.any(good) & jnp.isfinite(miss[pick]) & found_next
                 & (sit_next == sit[pick]) & away)
        captured = captures[pick] & good[pick]
        return ((valid[0] | captured, u[pick], inst[pick].astype(jnp.int32),
                 recovered & ~captured), sit[pick].astype(jnp.int32), stuck)

    # Both decisions are turns of one loop, so the decision (its deadbeat's nested solves)
    # is traced and compiled once: the second turn runs only where the first one is stuck
    # (under `vmap`, only in a batch where some lane is) and leaves out the first's policy.
    def turn(carry):
        k, _, stuck, sit, first, _ = carry
        again = k > 0
        out, sit_k, stuck_k = choose(apex, lambda ids: again & (ids == sit))
        keep = lambda a, b: jax.tree.map(lambda x, y: jnp.where(again, x, y), a, b)  # noqa: E731
        return (k + 1, ~again & stuck_k, keep(stuck, stuck_k), keep(sit, sit_k),
                keep(first, out), out)

    no, zero = jnp.asarray(False), jnp.asarray(0, jnp.int32)
    blank = (no, jnp.zeros(3, jnp.result_type(float)), zero, no)
    carry = (zero, jnp.asarray(True), no, zero, blank, blank)
    _, _, stuck, _, first, again = bounded_while(lambda c: c[1], turn, carry, 2,
                                                 tol.fixed_loops)
    # Where no other policy is left, `again` found nothing and the first decision stands.
    use = stuck & again[0] & (recover_again | ~again[3])
    out = jax.tree.map(lambda a, b: jnp.where(use, a, b), again, first)
    return out if recover else out[:3]


class Model(eqx.Module):
    """A hopping model: its stride on a terrain and the reactive controller's decision.

    Static (no traced leaves): a model selects code, so each one compiles its own run loop.
    `chunk` is the batch size of a full vmapped chunk; `pooled` whether batches of runs go
    through the lane pool by default (`jaxhop._execution.pool`); `instant_stance` whether the stance
    is instantaneous with the foot below the COM (BHop) rather than a compression of the
    leg from and back to its rest length (SLIP), which is how figures redraw a run;
    `observes` whether the adaptive controller's disturbance observer (`jaxhop._control.observer`)
    serves its deadbeat.
    """

    name: str = eqx.field(static=True)
    chunk: int = eqx.field(static=True)
    pooled: bool = eqx.field(static=True)
    instant_stance: bool = eqx.field(static=True)
    observes: bool = eqx.field(static=True)

    def stride(self, apex, u, terrain: Terrain, hopper: Hopper, wind=0.0, energy=None):
        """One stride: `(next_apex, code, foothold)`."""
        raise NotImplementedError

    def decide(self, apex, tables: PlanTables, hopper: Hopper):
        """Controls for one measured apex: `(found, u, instantiated)`."""
        raise NotImplementedError

    def decide_adaptive(self, apex, tables: PlanTables, hopper: Hopper, wind, heights,
                        h_touch, on=None, capture=None):
        """The adaptive controller's decision with the estimated `wind` (`None`: the
        model's deadbeat is wind-blind) on the corrected map's block `heights`, with the
        foothold height `h_touch` sensed for an instantaneous stance (else NaN),
        recovering an apex in no domain: `(found, u, instantiated, recovered)`. `on`
        (traced, `None`: on): the adaptive parts switched on (the run loop drops a
        recovered decision where they are off). `capture = (goal, tolerance)`: the run's
        global goal and its tolerance, for a SLIP's capture strides (`None`: none)."""
        raise NotImplementedError

    def foot_offset(self, u, hopper: Hopper):
        """The foot relative to the COM in flight with controls `u`."""
        raise NotImplementedError

    def observe(self, obs: Observer, measured, sensor, hopper: Hopper, landing=0.0,
                stride_error=None) -> Observer:
        """The observer's update with the apex measured after its pending stride
        (`jaxhop._control.observer.observe`)."""
        raise NotImplementedError


class _BHop(Model):
    def stride(self, apex, u, terrain, hopper, wind=0.0, energy=None):
        return bhop_stride(apex, u, terrain, hopper, wind)

    def decide(self, apex, tables, hopper):
        return decide_bhop(apex, tables, hopper)

    def decide_adaptive(self, apex, tables, hopper, wind, heights, h_touch, on=None,
                        capture=None):
        return decide_bhop(apex, tables, hopper, wind, heights, h_touch)

    def foot_offset(self, u, hopper):
        return jnp.array([0.0, -hopper.rho0])

    def observe(self, obs, measured, sensor, hopper, landing=0.0, stride_error=None):
        return observe(obs, measured, sensor, hopper, landing=landing,
                       stride_error=stride_error)


class _Slip(Model):
    def stride(self, apex, u, terrain, hopper, wind=0.0, energy=None):
        from .._models.slip.stride import slip_stride

        return slip_stride(apex, u, terrain, hopper, wind, energy=energy)

    def decide(self, apex, tables, hopper):
        return decide_slip(apex, tables, hopper)

    def decide_adaptive(self, apex, tables, hopper, wind, heights, h_touch, on=None,
                        capture=None):
        on = jnp.asarray(True) if on is None else on
        capture = None if capture is None else (*capture, on)
        return decide_slip(apex, tables, hopper, recover=True, heights=heights, wind=wind,
                           recover_again=on, capture=capture)

    def foot_offset(self, u, hopper):
        return hopper.rho0 * jnp.stack([jnp.sin(u[0]), -jnp.cos(u[0])])

    def observe(self, obs, measured, sensor, hopper, landing=0.0, stride_error=None):
        return observe(obs, measured, sensor, hopper, slip_terms, slip_prediction()[1],
                       landing, stride_error, Q_MIN_SLIP)


# SLIP strides cost a deadbeat solve per lane and run lengths vary more (a vmapped while loop
# runs until the chunk's longest run ends), so SLIP batches use smaller chunks and the pool.
BHOP = _BHop("bhop", chunk=256, pooled=False, instant_stance=True, observes=True)
SLIP = _Slip("slip", chunk=32, pooled=True, instant_stance=False, observes=True)
MODELS = {m.name: m for m in (BHOP, SLIP)}


def model_for(model: str | Model) -> Model:
    """The `Model` of a name (`"bhop"`, `"slip"`); a `Model` is returned as it is."""
    if isinstance(model, Model):
        return model
    if model not in MODELS:
        raise InputError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    return MODELS[model]


def decide(apex, tables: PlanTables, hopper: Hopper, model: str | Model = "bhop"):
    """Controls for one measured apex with the model's controller: `(found, u, instantiated)`.

    `"bhop"`: BHop deadbeat (eqs 25-29) clipped to the template's limits; `"slip"`: the
    position-aware SLIP deadbeat (eqs 12-16) within the SLIP limits.
    """
    return model_for(model).decide(apex, tables, hopper)

