"""SLIP adjustments of BHop plans (Arslan & Saranli 2012, section VII-A, eqs 35-37)."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhop
from jaxhop import Hopper, builtin_terrain, paper_templates
from jaxhop._core.terrain import segments
from jaxhop._planning.plan import templates_for
from jaxhop._planning.policies import candidate_situated, situated_table
from jaxhop._planning.regions import foot_lead, slip_shift_limits, template_domain_contains
from jaxhop._planning.templates import SlipAdjust

HOPPER = Hopper()


def test_printed_eq35_limits_never_bind():
    # The paper's constants, evaluated independently of the package: the lower limit stays
    # below -0.6 m and the upper above +0.6 m, outside every template's dy range (+-0.25).
    cm, ca, cb, co = 1.11, 1.0, 10.0, -0.1

    def h(v):
        c = ca if v < co else cb
        return cm * (math.atan(c * (v + co)) / math.pi - (1.0 - co))

    v = np.linspace(-2.5, 2.5, 501)
    printed = SlipAdjust.printed()
    ours = np.asarray(printed.h(jnp.asarray(v)))
    np.testing.assert_allclose(ours, [h(x) for x in v], rtol=1e-12)
    assert ours.max() < -0.6 and (-ours).min() > 0.6


def test_foot_lead_is_eq37():
    t = paper_templates().for_slip()
    ydot = jnp.linspace(-2.5, 2.5, 11)
    np.testing.assert_allclose(foot_lead(ydot, t.row(0)), ydot * math.sin(0.2) / 2.5,
                               rtol=1e-12)
    np.testing.assert_array_equal(foot_lead(ydot, paper_templates().row(0)), 0.0)


def test_slip_domain_is_shifted_by_eq36():
    # Brute force of eq 36: y - py in [-l - ydot sqrt(2 zr / g) - Y, l - ydot sqrt(...) - Y].
    bhop, slip = paper_templates(), templates_for("slip")
    rng = np.random.default_rng(3)
    n = 4000
    rel = np.stack([rng.uniform(-1.0, 1.0, n), rng.uniform(0.05, 1.3, n),
                    rng.uniform(-2.5, 2.5, n)], 1)
    for t in (2, 7, 13, 18):
        got = np.asarray(jax.vmap(template_domain_contains, (0, None, None))(
            jnp.asarray(rel), slip.row(t), HOPPER))
        plain = np.asarray(jax.vmap(template_domain_contains, (0, None, None))(
            jnp.asarray(rel), bhop.row(t), HOPPER))
        y, zr, v = rel.T
        lead = v * math.sin(0.2) / 2.5
        y_td = y + v * np.sqrt(2 * zr / HOPPER.g) + lead
        tmpl = bhop.as_array()[t]
        energy = 0.5 * HOPPER.m * v**2 + HOPPER.m * HOPPER.g * zr
        want = ((v >= tmpl[0]) & (v <= tmpl[1]) & (energy >= tmpl[2]) & (energy <= tmpl[3])
                & (np.abs(y_td) <= bhop.half_length))
        edge = np.abs(np.abs(y_td) - bhop.half_length) < 1e-9
        assert np.array_equal(got[~edge], want[~edge])
        assert got.sum() > 0 and not np.array_equal(got, plain)


def test_slip_shift_limits_replace_template_dy():
    slip = templates_for("slip")
    adjust = slip.slip
    for t in range(slip.n):
        row = slip.row(t)
        for v in (-1.5, 0.0, 0.7):
            lo, hi = slip_shift_limits(jnp.asarray(v), row)
            v_lo, v_hi = float(row.v_lo), float(row.v_hi)
            want_lo = float(adjust.h(0.5 * (v_hi + v)))
            want_hi = -float(adjust.h(-0.5 * (v_lo + v)))
            # Reversal: from forward to backward motion only behind the foot, and back.
            if v < 0 < v_hi:
                want_hi = min(want_hi, 0.0)
            if v > 0 > v_lo:
                want_lo = max(want_lo, 0.0)
            # Direction: a forward stride lifts off ahead of its COM's touchdown point, the
            # foot lead `Y` behind the planned foot; mirrored backward.
            if v >= 0 and v_lo >= 0:
                want_lo = max(want_lo, -float(adjust.lead(v_lo)))
            if v <= 0 and v_hi <= 0:
                want_hi = min(want_hi, -float(adjust.lead(v_hi)))
            assert float(lo) == pytest.approx(want_lo, abs=1e-12)
            assert float(hi) == pytest.approx(want_hi, abs=1e-12)
    # Without the two rules (the printed constants' setting) eq 35 alone.
    row = paper_templates().for_slip(SlipAdjust(reversal=False, keep_direction=False)).row(12)
    assert float(slip_shift_limits(jnp.asarray(-0.5), row)[1]) == pytest.approx(
        -float(SlipAdjust().h(-0.5 * (float(row.v_lo) - 0.5))), abs=1e-12)
    # BHop templates keep their own limits.
    row = paper_templates().row(12)
    assert tuple(map(float, slip_shift_limits(jnp.asarray(0.3), row))) == (0.0, 0.25)


def _flat_slip_table():
    """Flat ground's situated table for the SLIP templates, and its middle segment."""
    terrain = builtin_terrain("flat")
    slip = templates_for("slip")
    table = situated_table(terrain, segments(terrain, slip.seg_length), slip.seg_length)
    centre = np.asarray(table.centre)
    return terrain, slip, table, centre, centre.shape[0] // 2


@pytest.mark.slow
def test_candidate_situated_uses_the_slip_foot():
    # On flat ground, an apex whose SLIP foot (lead Y ahead) lands on segment k is matched
    # to segment k's policies, and the BHop lookup puts it on another segment.
    terrain, slip, table, centre, k = _flat_slip_table()
    ydot, z = 2.0, 1.4
    t_d = math.sqrt(2 * (z - centre[k, 1] - 1.0) / HOPPER.g)
    lead = ydot * math.sin(0.2) / 2.5
    apex = jnp.array([centre[k, 0] - ydot * t_d - lead, z, ydot])
    ids, inside = candidate_situated(apex, table, slip, terrain, HOPPER)
    hits = np.asarray(ids)[np.asarray(inside)]
    assert hits.size and set(hits // slip.n) == {k}
    ids_b, inside_b = candidate_situated(apex, table, paper_templates(), terrain, HOPPER)
    assert k not in set(np.asarray(ids_b)[np.asarray(inside_b)] // slip.n)


def test_slip_cache_key_differs():
    from jaxhop._planning.cache import plan_key

    terrain = builtin_terrain("flat")
    a = plan_key(terrain, terrain.goal, templates_for("bhop"), HOPPER)
    b = plan_key(terrain, terrain.goal, templates_for("slip"), HOPPER)
    c = plan_key(terrain, terrain.goal, paper_templates().for_slip(SlipAdjust.printed()),
                 HOPPER)
    assert len({a, b, c}) == 3


def test_runs_read_the_foot_lead_only_so_planning_settings_share_one_controller():
    # Two SLIP plans that differ in eq 35's constants and the reversal / direction rules
    # run on one compiled controller: their run-time templates have one tree structure
    # (static fields included), and the foot lead of eq 37 they give is the planning
    # templates' own. BHop plans run on the same controller, with a zero lead.
    base = templates_for("slip")
    other = paper_templates().for_slip(SlipAdjust.printed(v_max=base.slip.v_max))
    assert jax.tree_util.tree_structure(base) != jax.tree_util.tree_structure(other)
    runs = [t.for_runs() for t in (base, other)]
    assert jax.tree_util.tree_structure(runs[0]) == jax.tree_util.tree_structure(runs[1])
    ydot = jnp.linspace(-3.0, 3.0, 61)
    for t, r in zip((base, other), runs):
        assert np.array_equal(np.asarray(foot_lead(ydot, r)), np.asarray(foot_lead(ydot, t)))
        assert np.array_equal(np.asarray(foot_lead(ydot, r)),
                              ydot * math.sin(0.2) / base.slip.v_max)
    bhop = templates_for("bhop").for_runs()
    assert jax.tree_util.tree_structure(bhop) == jax.tree_util.tree_structure(runs[0])
    assert np.array_equal(np.asarray(foot_lead(ydot, bhop)), np.zeros_like(ydot))


def test_templates_for_rejects_unknown_model():
    from jaxhop import InputError

    with pytest.raises(InputError, match="model"):
        templates_for("ballistic")


@pytest.mark.slow
def test_fitted_eq35_band_holds_most_slip_strides():
    # The default h(v) was fitted to the 10th/90th percentiles of simulated strides; on a
    # fresh sample (other seed) the band [h(v_avg), -h(-v_avg)] must hold roughly 80 % of
    # the BHop-equivalent shifts, and the printed constants' band (which holds everything,
    # being +-0.7 m wide at least) must not be what we use.
    from jaxhop._models.slip.stride import flat_touchdown, slip_apex_map

    rng = np.random.default_rng(11)
    n = 3000
    ydot = rng.uniform(-2.5, 2.5, n)
    zr = (rng.uniform(120.0, 1120.0, n) - 0.5 * HOPPER.m * ydot**2) / (HOPPER.m * HOPPER.g)
    ydot, zr = ydot[zr > 0.01], zr[zr > 0.01]
    k = ydot.size
    kc = rng.uniform(10.0, 60.0, k) * HOPPER.m * HOPPER.g
    u = np.stack([rng.uniform(-np.pi / 3, np.pi / 3, k), kc,
                  kc * np.exp(rng.uniform(np.log(0.5), np.log(2.0), k))], 1)
    apex = np.stack([np.zeros(k), zr + 1.0, ydot], 1)
    nxt, code = jax.jit(jax.vmap(lambda a, c: slip_apex_map(a, c, 0.0, HOPPER)))(apex, u)
    foot = jax.vmap(lambda a, t: flat_touchdown(a, t, 0.0, HOPPER)[0])(apex, u[:, 0])
    nxt, code, foot = np.asarray(nxt), np.asarray(code), np.asarray(foot)
    zr1 = nxt[:, 1] - 1.0
    e1 = 0.5 * HOPPER.m * nxt[:, 2] ** 2 + HOPPER.m * HOPPER.g * zr1
    ok = (code == 0) & (zr1 > 0) & (np.abs(nxt[:, 2]) <= 2.5) & (e1 >= 120) & (e1 <= 1120)
    assert ok.sum() > 200
    dy = nxt[ok, 0] - nxt[ok, 2] * np.sqrt(2 * zr1[ok] / HOPPER.g) - foot[ok]
    v = 0.5 * (ydot[ok] + nxt[ok, 2])
    h = SlipAdjust().h
    inside = (dy >= np.asarray(h(jnp.asarray(v)))) & (dy <= -np.asarray(h(jnp.asarray(-v))))
    assert 0.65 < inside.mean() < 0.92


def _random_strides(seed, n, ydot, th, zr_lo=0.1):
    """Simulated flat-ground strides from apexes at y = 0 with random height, leg
    stiffnesses (kc 10-60 mg, kd within a factor 2 of it) and the given speeds and
    touchdown angles (functions of the seeded generator): `(apex, u, next_apex, code)`."""
    from jaxhop._models.slip.stride import slip_apex_map

    rng = np.random.default_rng(seed)
    ydot = ydot(rng, n)
    zr = rng.uniform(zr_lo, 0.8, n)
    kc = rng.uniform(10.0, 60.0, n) * HOPPER.m * HOPPER.g
    th = th(rng, ydot)
    u = np.stack([th, kc, kc * np.exp(rng.uniform(np.log(0.5), np.log(2.0), n))], 1)
    apex = np.stack([np.zeros(n), zr + 1.0, ydot], 1)
    nxt, code = jax.jit(jax.vmap(lambda a, c: slip_apex_map(a, c, 0.0, HOPPER)))(apex, u)
    return apex, u, np.asarray(nxt), np.asarray(code)


@pytest.mark.slow
def test_a_reversing_stride_lifts_off_behind_its_foot():
    # The physics behind the reversal rule of `slip_shift_limits`, checked on simulated
    # strides: the leg force points away from the foot, so a stance that turns forward
    # motion backward ends with the COM (and the BHop-equivalent liftoff point, further
    # along the backward ascent) behind the foot; mirrored for backward-to-forward.
    from jaxhop._models.slip.stride import flat_touchdown

    # The foot planted ahead (the touchdown angle's sign the speed's): slows or reverses.
    apex, u, nxt, code = _random_strides(
        5, 3000, lambda r, n: r.uniform(-1.0, 1.0, n),
        lambda r, v: np.sign(v) * r.uniform(0.0, 0.5, v.size))
    ydot = apex[:, 2]
    foot = np.asarray(jax.vmap(lambda a, t: flat_touchdown(a, t, 0.0, HOPPER)[0])(
        apex, u[:, 0]))
    zr1 = nxt[:, 1] - 1.0
    ok = (code == 0) & (zr1 > 0)
    dy = nxt[:, 0] - nxt[:, 2] * np.sqrt(np.maximum(2 * zr1, 0.0) / HOPPER.g) - foot
    fwd_back = ok & (ydot > 0) & (nxt[:, 2] < 0)
    back_fwd = ok & (ydot < 0) & (nxt[:, 2] > 0)
    assert fwd_back.sum() > 100 and back_fwd.sum() > 100
    assert np.all(dy[fwd_back] < 0) and np.all(dy[back_fwd] > 0)
    # Not a property of every stride: strides that keep their direction end on both sides.
    keep = ok & (ydot > 0) & (nxt[:, 2] > 0)
    assert (dy[keep] > 0).any() and (dy[keep] < 0).any()


@pytest.mark.slow
def test_a_stride_moving_forward_before_and_after_lifts_off_ahead_of_its_touchdown():
    # The physics behind the direction rule of `slip_shift_limits`, on simulated strides
    # with the foot on either side: the horizontal speed changes sign at most once in
    # stance, so a stride whose apex speeds are both forward moves forward all along. Its
    # BHop-equivalent liftoff point (the ascent traced back to the height rho0) lies ahead
    # of its BHop-equivalent touchdown point (the descent traced to rho0); mirrored for
    # backward strides.
    apex, _, nxt, code = _random_strides(
        11, 4000, lambda r, n: r.uniform(-1.0, 1.0, n),
        lambda r, v: r.uniform(-0.5, 0.5, v.size), zr_lo=0.05)
    ydot, zr = apex[:, 2], apex[:, 1] - 1.0
    zr1 = nxt[:, 1] - 1.0
    ok = (code == 0) & (zr1 > 0)
    down = ydot * np.sqrt(2 * zr / HOPPER.g)
    up = nxt[:, 0] - nxt[:, 2] * np.sqrt(np.maximum(2 * zr1, 0.0) / HOPPER.g)
    fwd = ok & (ydot >= 0) & (nxt[:, 2] >= 0)
    back = ok & (ydot <= 0) & (nxt[:, 2] <= 0)
    assert fwd.sum() > 300 and back.sum() > 300
    assert np.all(up[fwd] >= down[fwd]) and np.all(up[back] <= down[back])


@pytest.mark.slow
def test_a_stride_moving_backward_before_and_after_never_moves_forward():
    # Why the leg's SLIP templates keep only forward bands: the leg force points away from
    # the foot, so the horizontal speed changes sign at most once in stance; a stride whose
    # apex speeds are both backward moves backward all along, from apex to apex, whatever
    # the foot placement (simulated strides, both directions of touchdown angle).
    from jaxhop.parkour import leg_templates

    _, _, nxt, code = _random_strides(8, 3000, lambda r, n: -r.uniform(0.0, 1.0, n),
                                      lambda r, v: r.uniform(-0.5, 0.5, v.size))
    back = (code == 0) & (nxt[:, 1] > 1.0) & (nxt[:, 2] < 0)
    assert back.sum() > 300
    assert np.all(nxt[back, 0] < 0)
    # The BHop plan's backward band asks for exactly such strides with a forward travel on
    # the leg's narrow tops; the leg's SLIP templates have no backward band.
    tm = leg_templates(model="slip")
    rows = tm.as_array()
    assert tm.slip is not None and np.all(rows[:, 0] >= 0) and tm.n == 12
    assert np.any(leg_templates().as_array()[:, 0] < 0)


@functools.cache
def _decide_program():
    """`decide_slip` with recovery, compiled once for this file's tests: on tables as runs
    read them (`bucketed`: padded to shape buckets, unnamed maps, the templates' foot lead
    and segment length traced) every plan of the reference map's size and every hopper
    size share the program."""
    from jaxhop._control.decisions import decide_slip

    return jax.jit(lambda z, tb, hop: decide_slip(z, tb, hop, recover=True))


def _decide(apex, tables, hopper):
    return _decide_program()(apex, tables, hopper)


@functools.cache
def _premise_programs():
    """The table-start deadbeat of a decision and the stride (its `Tolerances`, all static,
    select the compiled program), jitted once for every test here that checks a premise
    with them (eager, each call traces its solver loops again)."""
    from jaxhop._models.slip.deadbeat import DeadbeatSearch, deadbeat_slip
    from jaxhop._models.slip.stride import slip_stride

    deadbeat = jax.jit(lambda a, g, h, table, terrain, w: deadbeat_slip(
        a, g, h, HOPPER, DeadbeatSearch(table=table, fallback=False), terrain=terrain, wind=w))
    stride = jax.jit(lambda a, u, terrain, w, tol: slip_stride(a, u, terrain, HOPPER, w, tol))
    # The foothold height and the wind as float64 arrays whatever the caller passes: JAX
    # picks the program by the arguments' types, and a Python float is weakly typed.
    real = functools.partial(jnp.asarray, dtype=jnp.float64)
    return (lambda a, g, h, table, terrain, w: deadbeat(a, g, real(h), table, terrain, real(w)),
            lambda a, u, terrain, w, tol: stride(a, u, terrain, real(w), tol))


def _run_tables(tables):
    """`tables` as runs read them (`bucketed`)."""
    from jaxhop._planning.plan import bucketed

    return bucketed(tables, tables.terrain)[0]


def _perceived_plan(templates):
    """The plan of `templates` on the perceived map of `--noise ground` seed 0, and the true
    map."""
    from jaxhop._cli.main import _perceived
    from jaxhop._planning.plan import build_plan

    true = builtin_terrain("reference")
    return build_plan(_perceived(true, 0), None, templates, progress=False), true


@pytest.fixture(scope="module")
def perceived_slip_plan():
    """The SLIP plan on the perceived map of `--noise ground` seed 0, and the true map."""
    return _perceived_plan(templates_for("slip"))


@pytest.mark.slow
def test_slip_reaches_the_goal_where_reversing_goals_made_it_cycle(perceived_slip_plan):
    # Under ground noise seed 0 the planner's goal block is 0.117 m too high. Without the
    # reversal rule the SLIP plan's last intermediate goals asked for forward shifts while
    # reversing, and runs from these apexes cycled through three policies until
    # max_steps (0 of 48 sweep states succeeded). The success test is the goal
    # tolerance: the true apex within 0.05 of the goal in every coordinate.
    from jaxhop._control.decisions import in_global_domain
    from jaxhop._execution.batches import run_batch

    plan, true = perceived_slip_plan
    starts = np.array([[8.984, 1.51, 0.162], [8.953, 1.487, -0.097], [9.021, 1.506, -0.085],
                       [8.613, 1.777, 1.604]])
    assert in_global_domain(starts, plan.tables(), HOPPER).all()
    out = run_batch(plan, starts, jaxhop.RunSettings(model="slip", controller="paper"),
                    key=jax.random.key(0), true_terrain=true)
    assert np.all(out["code"] == 0), out["code"]
    assert np.all(out["steps"] <= 30), out["steps"]
    last = np.array([a[int(s)] for a, s in zip(out["apexes"], out["steps"])])
    assert np.all(np.abs(last - plan.goal) <= 0.05)


@pytest.mark.slow
def test_a_slip_miss_that_stays_put_is_decided_again():
    # A plan built without the direction rule (`SlipAdjust.keep_direction=False`: eq 35's
    # limits alone) on the perceived map of `--noise ground` seed 0. This apex in the goal
    # area lies only in the domain of a policy whose goal is 0.17 m ahead with a backward
    # speed: out of a SLIP stride's reach, its best miss is a stride in place that lands in
    # the same domain again no nearer the goal. Runs through here hopped in place for 20-25
    # strides (about 30 in all). The adaptive controller decides again without that policy
    # (the nearest other domain, a recovery), and the run from here reaches the goal within
    # 12 strides. (With the direction rule no apex of a 0.02 m x 0.05 m x 0.05 m/s grid
    # over 7-9.6 m of this map's domains meets the premise.)
    import dataclasses

    from jaxhop._control.decisions import SLIP_ACCEPT, first_match
    from jaxhop._execution.batches import run_batch
    from jaxhop._models.slip.kernels import SEARCH_TOL

    adjust = dataclasses.replace(templates_for("slip").slip, keep_direction=False)
    plan, true = _perceived_plan(paper_templates().for_slip(adjust))
    tables = plan.tables(slip=True)
    apex = jnp.array([9.0216, 1.4916, -0.0265])
    match = jax.jit(lambda z, tb: first_match(z, tb, HOPPER))  # compiled: 1 s, not 8 s eager
    found, sit, inst = match(apex, tables)
    goal = tables.goals[inst]
    assert found and goal[0] - apex[0] > 0.1 and goal[2] < 0
    # The premise, from the deadbeat and the stride themselves: the best miss stays put.
    # (The decision's table-start deadbeat, without the multi-start solver.)
    h = tables.table.centre[sit // tables.templates.n, 1]
    deadbeat, stride = _premise_programs()
    u, _ = deadbeat(apex, goal, h, tables.slip, tables.terrain, 0.0)
    pred, code, _ = stride(apex, u, tables.terrain, 0.0, SEARCH_TOL)
    scale = np.asarray(SLIP_ACCEPT)
    miss = float(np.max(np.abs(pred - goal) / scale))
    assert code == 0 and abs(float(pred[0] - apex[0])) < 0.05 and miss > 1
    assert miss >= float(np.max(np.abs(apex - goal) / scale))
    assert int(match(pred, tables)[1]) == int(sit)

    _, _, chosen, recovered = _decide(apex, _run_tables(tables), HOPPER)
    assert int(chosen) != int(inst) and bool(recovered)
    # The default stride limit, so that the run shares the compiled pool step of the other
    # runs on this map.
    out = run_batch(plan, np.asarray(apex)[None],
                    jaxhop.RunSettings(model="slip", controller="adaptive"),
                    key=jax.random.key(0), true_terrain=true)
    assert out["code"][0] == 0 and out["steps"][0] <= 12, (out["code"], out["steps"])


@pytest.fixture(scope="module")
def reference_slip_plan():
    from jaxhop._planning.plan import build_plan

    return build_plan(builtin_terrain("reference"), None, templates_for("slip"),
                      progress=False)


@pytest.mark.slow
def test_a_slip_run_in_a_headwind_captures_the_goal_at_rest(reference_slip_plan):
    # In the paper's wind (-0.2 m/s^2, a headwind on the way to the goal) a SLIP 10 cm short
    # of the goal and nearly at rest cannot stop there in one stride: the wind-aware
    # deadbeat's best stride covers 2 cm of the 10. Without capture strides runs circled
    # 4-8 cm short of the goal until max_steps (reference, wind, seed 0: 758 of 4 426 runs).
    # A capture stride aims instead at an apex half way there, moving forward, from which
    # one more stride stops at the goal.
    from jaxhop._control.decisions import capture_target
    from jaxhop._core.params import disturbance_for
    from jaxhop._execution.batches import run_batch
    from jaxhop._models.slip.stride import STRIDE_TOL

    plan = reference_slip_plan
    tables = plan.tables(slip=True)
    windy = disturbance_for("wind")
    apex, goal = jnp.array([9.40, 1.30, 0.03]), jnp.asarray(plan.goal, float)
    # The premise, from the deadbeat and the stride themselves: one stride misses.
    deadbeat, stride = _premise_programs()
    u, _ = deadbeat(apex, goal, 0.0, tables.slip, tables.terrain, windy.wind)
    pred, code, _ = stride(apex, u, tables.terrain, windy.wind, STRIDE_TOL)
    assert code == 0 and float(np.max(np.abs(np.asarray(pred - goal)))) > 0.05
    # The capture stride's target: from there the same deadbeat and stride stop at the goal.
    near, target = capture_target(apex, goal, jnp.full(3, 0.05), 0.0, HOPPER)
    assert near and 0.0 < float(target[2]) < 0.3 and apex[0] < target[0] < goal[0]
    u, _ = deadbeat(target, goal, 0.0, tables.slip, tables.terrain, windy.wind)
    stop, code, _ = stride(target, u, tables.terrain, windy.wind, STRIDE_TOL)
    assert code == 0 and float(np.max(np.abs(np.asarray(stop - goal)))) <= 0.01, stop
    starts = np.array([[9.40, 1.30, 0.03], [9.38, 1.30, 0.0], [9.2, 1.45, 0.5]])
    out = run_batch(plan, starts, jaxhop.RunSettings(model="slip", controller="adaptive"),
                    key=jax.random.key(0), disturbance=windy)
    assert (out["code"] == 0).all() and (out["steps"] <= 6).all(), (out["code"], out["steps"])


@pytest.mark.slow
def test_a_slip_nearly_at_rest_in_a_headwind_still_hops_forward(reference_slip_plan):
    # mppc-hw-dynamic-3 under wind, on the leg (rho0 0.19 m, g 8.0665), here in the
    # reference hopper's Froude units: from an apex nearly at rest the plan's next goal lies
    # 0.1 leg lengths ahead, moving forward. The windless table's start, polished in the
    # headwind, ended beyond the stride's reversal: the stride flew back at -0.41 m/s here
    # (-0.28 m/s on the leg, 18 tolerances from the goal and outside every domain: 12 of 12
    # runs ended there). Started from the stride's windless equivalent (`windless_equivalent`) the
    # deadbeat stays on the forward side and misses the goal in the wind about as much as
    # the same deadbeat misses it without wind (3.4 tolerances on the leg: this goal is out
    # of one stride's reach either way).
    from jaxhop._control.decisions import SLIP_ACCEPT
    from jaxhop._core.params import disturbance_for
    from jaxhop._models.slip.stride import STRIDE_TOL
    from jaxhop.parkour import leg_hopper

    leg = leg_hopper()
    length = HOPPER.rho0 / leg.rho0
    speed = math.sqrt(HOPPER.g * HOPPER.rho0 / (leg.g * leg.rho0))
    to_ref = np.array([length, length, speed])
    y0 = 8.7  # on the reference terrain's last block, 8.5-10 m at height 0
    apex = jnp.asarray(np.array([0.0, 0.4895, 0.0545]) * to_ref + [y0, 0.0, 0.0])
    goal = jnp.asarray(np.array([0.0986348, 0.488388, 0.12351932]) * to_ref + [y0, 0.0, 0.0])
    tables = reference_slip_plan.tables(slip=True)
    deadbeat, stride = _premise_programs()
    scale = np.asarray(SLIP_ACCEPT)

    def miss(wind):
        u, _ = deadbeat(apex, goal, 0.0, tables.slip, tables.terrain, wind)
        nxt, code, _ = stride(apex, u, tables.terrain, wind, STRIDE_TOL)
        assert int(code) == 0
        return np.asarray(nxt), float(np.max(np.abs(np.asarray(nxt - goal)) / scale))

    _, calm = miss(0.0)
    nxt, windy = miss(disturbance_for("wind").wind)
    assert nxt[2] > 0.0 and windy <= 1.5 * calm, (nxt, windy, calm)


@pytest.mark.slow
def test_a_slip_under_speed_noise_alone_reaches_the_goal(reference_slip_plan):
    # Sensor noise on ydot alone leaves y and z exact, and the apex filter fuses them with
    # full trust. With the prediction believed to 1e-5 m, the SLIP apex map's linearisation
    # error (mm to cm) was read as wind: after one stride the estimate was -10 to -32 m/s^2
    # and the next stride flew off at -2 to -6 m/s (4 of these 6 runs failed, outside_domain
    # or collision; 0.23 of 256 sweep states succeeded). Now every run reaches the goal.
    from jaxhop._execution.batches import run_batch

    starts = np.array([[0.1, 2.05, 0.5], [0.5, 2.2, 0.5], [0.8, 1.4, 0.5], [0.9, 2.65, 0.5],
                       [2.0, 1.6, 0.5], [5.6, 1.8, 0.5]])
    out = run_batch(reference_slip_plan, starts, jaxhop.RunSettings(model="slip"),
                    key=jax.random.key(0), disturbance=jaxhop.Disturbance(sensor=(0, 0, 0.05)))
    assert (out["code"] == 0).all() and (out["steps"] <= 12).all(), (out["code"], out["steps"])
    # No stride flies off at the speeds a wind of tens of m/s^2 gave.
    assert np.nanmax(np.abs(out["apexes"][:, :, 2])) < 2.5


@pytest.mark.slow
def test_without_disturbance_both_slip_controllers_run_alike_until_a_capture_stride(
        reference_slip_plan):
    # Without disturbance the adaptive controller's observer, recovery and sensed footholds
    # do nothing (the estimate stays 0, the footholds are the map's, no state needs
    # recovery), and the paper's SLIP controller runs through the same compiled program with
    # them switched off. From (5.6, 1.8, 0.5) the two used to start 3.5e-15 apart. Only a
    # capture stride near the goal, where the plan's goal stride misses, may part them: the
    # runs are equal to the last bit before it, and the adaptive run is no longer.
    from jaxhop._control.decisions import CAPTURE_TOLERANCES
    from jaxhop._execution.batches import run_batch

    starts = np.array([[5.6, 1.8, 0.5], [2.0, 1.6, 0.5], [6.6, 1.8, 0.5]])
    out = {c: run_batch(reference_slip_plan, starts, jaxhop.RunSettings(model="slip", controller=c),
                        key=jax.random.key(0)) for c in ("paper", "adaptive")}
    paper, adaptive = out["paper"], out["adaptive"]
    assert (paper["code"] == 0).all() and (adaptive["code"] == 0).all()
    assert (adaptive["steps"] <= paper["steps"]).all() and (adaptive["recoveries"] == 0).all()
    goal, near = np.asarray(reference_slip_plan.goal), CAPTURE_TOLERANCES * 0.05
    for i in range(len(starts)):
        fp, fa = paper["footholds"][i], adaptive["footholds"][i]
        same = ((paper["policies"][i] == adaptive["policies"][i])
                & np.all((fp == fa) | (np.isnan(fp) & np.isnan(fa)), axis=1))
        k = int(np.argmin(same)) if not same.all() else paper["steps"][i]
        np.testing.assert_array_equal(paper["apexes"][i, :k + 1], adaptive["apexes"][i, :k + 1])
        np.testing.assert_array_equal(paper["footholds"][i, :k], adaptive["footholds"][i, :k])
        if k < paper["steps"][i]:  # parted by a capture stride, near the goal
            assert np.all(np.abs(adaptive["apexes"][i, k] - goal) <= near), i


@pytest.mark.slow
def test_a_sweeps_slip_domain_keeps_the_states_whose_first_stride_stays_in_the_domain(
        reference_slip_plan):
    # In the BHop plan's domains with the SLIP adjustments, but left by the first SLIP
    # stride: 0.2 m before the map's end moving on at 0.5 m/s (the foot would have to land
    # past 10 m to turn back) and at the edge over the hole at 4.2 m. The check is the
    # first stride of whole runs (the paper's controller, no noise) and the domain test of
    # the apex it reaches.
    from jaxhop._control.decisions import in_global_domain
    from jaxhop._execution.batches import run_batch, slip_verified

    plan = reference_slip_plan
    tables = plan.tables()
    starts = np.array([[4.0, 1.2, 0.5], [9.8, 1.4, 0.5], [9.8, 1.2, 0.5], [2.0, 1.6, 0.5],
                       [6.6, 1.8, 0.5]])
    assert in_global_domain(starts, tables, HOPPER).all()
    verified = slip_verified(starts, plan)
    one = run_batch(plan, starts, jaxhop.RunSettings(model="slip", controller="paper"),
                    key=jax.random.key(0))
    nxt = one["apexes"][:, 1]
    completed = np.all(np.isfinite(nxt), axis=1)
    expected = completed & in_global_domain(np.where(completed[:, None], nxt, 0.0), tables,
                                            HOPPER)
    assert verified.tolist() == expected.tolist()
    assert verified.tolist() == [False, False, True, True, True]


def _froude_tables(tables, hopper):
    """`tables` of the reference hopper's plan, every length, speed and energy Froude-scaled
    to `hopper`: the same plan for a hopper of another size."""
    from jaxhop._core.params import froude_scales
    from jaxhop._planning.templates import scaled_templates

    f = froude_scales(hopper)
    length, speed = f["length"], f["velocity"]
    t = tables.table
    table = type(t)(t.centre * length, t.seg_block, t.edge_distance * length, t.block_first,
                    t.block_count, t.block_left * length)
    terrain = type(tables.terrain)(tables.terrain.starts * length, tables.terrain.ends * length,
                                   tables.terrain.heights * length)
    goals = tables.goals * jnp.array([length, length, speed])
    return type(tables)(table, scaled_templates(hopper, base=tables.templates), terrain,
                        tables.best_pos, tables.best_inst, goals, tables.slip)


@pytest.mark.slow
def test_a_slip_decision_for_a_small_leg_is_the_reference_decision_in_froude_units(
        reference_slip_plan):
    # Froude similarity: the same plan scaled to the MPPC leg (0.19 m, 8.0665 m/s^2, 1 kg)
    # must choose the same policy from the scaled apex and, where the stride reaches the
    # goal, the same touchdown angle and stiffnesses scaled by m g / rho0 (a goal out of
    # reach gets C2's least-squares compromise, whose position and speed weights are not
    # Froude-scaled). The acceptance of a candidate's predicted miss is part of it:
    # unscaled (0.05 m on a 0.19 m leg) the leg accepts first candidates that miss by up to
    # 26 % of its leg length, which the reference hopper rejects (5 %).
    from jaxhop._control.decisions import in_global_domain
    from jaxhop._execution.batches import sweep_grid
    from jaxhop._models.slip.kernels import SEARCH_TOL
    from jaxhop.parkour import leg_hopper

    leg = leg_hopper()
    length, g_ratio = leg.rho0 / HOPPER.rho0, leg.g / HOPPER.g
    speed = math.sqrt(g_ratio * length)
    stiff = (leg.m * leg.g / leg.rho0) / (HOPPER.m * HOPPER.g / HOPPER.rho0)
    tables = reference_slip_plan.tables(slip=True)
    tables, small = _run_tables(tables), _run_tables(_froude_tables(tables, leg))
    grid = sweep_grid(reference_slip_plan.terrain)
    inside = grid[np.asarray(in_global_domain(grid, reference_slip_plan.tables(), HOPPER))]
    states = inside[np.linspace(0, inside.shape[0] - 1, 24).round().astype(int)]
    to_leg = np.array([length, length, speed])
    stride = _premise_programs()[1]
    reached = 0
    for z in states:
        f0, u0, a0, r0 = _decide(jnp.asarray(z), tables, HOPPER)
        f1, u1, a1, r1 = _decide(jnp.asarray(z * to_leg), small, leg)
        assert (bool(f0), int(a0), bool(r0)) == (bool(f1), int(a1), bool(r1)), z
        pred, _, _ = stride(jnp.asarray(z), u0, tables.terrain, 0.0, SEARCH_TOL)
        if np.max(np.abs(np.asarray(pred) - np.asarray(tables.goals[a0]))) < 1e-4:
            reached += 1
            np.testing.assert_allclose(u1[0], u0[0], atol=1e-5)
            np.testing.assert_allclose(u1[1:], u0[1:] * stiff, rtol=1e-4)
    assert reached >= 4
    # The twin scales its acceptance the same way; the reference hopper keeps the constants.
    from jaxhop._control.decisions import SLIP_ACCEPT, SLIP_STAGE_C2, _slip_scales
    from jaxhop.reference._execute import slip_scales

    assert np.array_equal(np.asarray(_slip_scales(HOPPER)[0]), SLIP_ACCEPT)
    assert float(_slip_scales(HOPPER)[1]) == SLIP_STAGE_C2
    np.testing.assert_allclose(np.asarray(_slip_scales(leg)[0]),
                               0.05 * np.array([length, length, speed]), rtol=1e-14)
    np.testing.assert_allclose(slip_scales(leg)[0], np.asarray(_slip_scales(leg)[0]),
                               rtol=1e-14)
    assert slip_scales(leg)[1] == pytest.approx(1e-4 * length**2, rel=1e-14)


@pytest.mark.slow
def test_goal_policies_reach_a_goal_at_rest_on_its_own_segment_only():
    # The direction rule with its goal-policy slack: a goal at rest lying in a segment is
    # reached by that segment's slow forward template (runs creep onto it), not by the
    # segment just ahead of it, whose every touchdown is past the goal (a forward stride
    # from there cannot come back), and not by any segment without the slack.
    import dataclasses

    from jaxhop._planning.policies import goal_policy_margin

    terrain, slip, table, centre, k = _flat_slip_table()
    t = int(np.nonzero((np.asarray(slip.v_lo) == 0.0) & (np.asarray(slip.v_hi) > 0.0))[0][0])
    py, h = centre[k]
    goal = jnp.array([py + 0.3 * slip.half_length, h + 1.2, 0.0])

    def reached(seg, tm):
        return bool(goal_policy_margin(goal, t, seg, table, tm, terrain, HOPPER)[0])

    assert reached(k, slip) and not reached(k + 1, slip)
    strict = dataclasses.replace(slip, slip=dataclasses.replace(slip.slip,
                                                                  keep_direction=False))
    assert reached(k + 1, strict)  # eq 35 alone allows it


@pytest.mark.slow
def test_situating_a_bhop_plan_after_a_slip_plan_uses_the_bhop_regions():
    # Situating caches each template set's boxes of Gf and the domain (once per process).
    # The SLIP templates have eq 33's rows but other regions (eqs 35-36): a BHop plan built
    # after a SLIP plan in one process got the SLIP boxes, and 10-14 % more candidate pairs
    # than the NumPy twin.
    from jaxhop._planning.policies import template_boxes
    from jaxhop._planning.stages import relative_boxes

    slip, bhop = templates_for("slip"), templates_for("bhop")
    for t in (slip, bhop):
        for got, want in zip(relative_boxes(t, HOPPER), template_boxes(t, HOPPER)):
            assert np.array_equal(got, np.asarray(want))
    assert not np.array_equal(relative_boxes(slip, HOPPER)[1], relative_boxes(bhop, HOPPER)[1])
