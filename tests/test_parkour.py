"""The reactive planner on parkour courses (docs/parkour_reactive.md): course maps,
Froude-scaled templates, incremental plan updates against full rebuilds, reactive runs
with restricted areas."""

import json
import math

import jax
import numpy as np
import pytest

import jaxhop
from jaxhop._planning.policies import PairGrid, template_boxes
from jaxhop._planning.templates import (
    dimensionless_templates,
    paper_templates,
    scaled_templates,
    template_scales,
)
from jaxhop.mppc import course_from_dict, list_courses, load_course
from jaxhop.parkour import build_course_plan, course_map, leg_hopper, leg_templates
from jaxhop.parkour._map import MARGIN, PARKOUR_FAILURES, RESTRICTED, CourseMap
from jaxhop.parkour._run import (
    course_plans,
    identical_plans,
    initial_states,
    pad_plans,
    run_reactive,
    same_deployment,
)

# --- dimensionless templates -------------------------------------------------------------


def test_scaled_templates_reproduce_paper_templates_exactly():
    a, b = scaled_templates(jaxhop.Hopper()), paper_templates()
    assert np.array_equal(a.as_array(), b.as_array())
    assert a.seg_length == b.seg_length
    assert template_scales(jaxhop.Hopper()) == {"length": 1.0, "velocity": 1.0, "energy": 1.0}


def test_dimensionless_templates_are_size_independent():
    hop = jaxhop.Hopper(m=3.0, g=8.0665, rho0=0.19)
    d_ref = dimensionless_templates()
    d_leg = dimensionless_templates(scaled_templates(hop))
    f = template_scales(hop)
    # Back to the leg's units by its own scales: velocity / sqrt(g l), energy / (m g l).
    arr = scaled_templates(hop).as_array()
    assert np.allclose(arr[:, 0] / math.sqrt(hop.g * hop.rho0), d_ref[:, 0], rtol=1e-12)
    assert np.allclose(arr[:, 2] / (hop.m * hop.g * hop.rho0), d_ref[:, 2], rtol=1e-12)
    assert np.allclose(d_leg[:, 6:10], d_ref[:, 6:10])  # angles and k unchanged
    assert math.isclose(scaled_templates(hop).seg_length, 0.15 * hop.rho0)
    assert f["length"] == 0.19


@pytest.mark.slow
def test_regions_scale_like_froude_similarity():
    # Independent of the scaling code: the regions computed for the small hopper are the
    # reference regions with lengths times rho0 and speeds times sqrt(g rho0 / 9.81).
    hop = jaxhop.Hopper(m=2.0, g=8.0665, rho0=0.19)
    gf0, d0 = (np.asarray(x) for x in template_boxes(paper_templates(), jaxhop.Hopper()))
    gf1, d1 = (np.asarray(x) for x in template_boxes(scaled_templates(hop), hop))
    f = template_scales(hop)
    scale = np.array([f["length"], f["length"], f["velocity"]])[None, :, None]
    assert np.allclose(d1, d0 * scale, rtol=1e-9, atol=1e-12)
    # Gf boxes are padded by one step of a 2001-point velocity grid and 1 mm in height.
    assert np.allclose(gf1, gf0 * scale, rtol=0, atol=3e-3)


def test_extra_energy_bands_and_bad_bands():
    hop = leg_hopper()
    t = leg_templates(hop)
    assert t.n == 18  # 3 velocity bands x (5 paper + 1 extra) energy bands
    top = 2.4 * hop.m * hop.g * hop.rho0
    assert math.isclose(float(np.max(t.as_array()[:, 3])), top)
    with pytest.raises(jaxhop.InputError):
        scaled_templates(hop, extra_energy=[(2.0, 1.0)])


def _flat_map(terrain, allowed=None):
    n = terrain.n_blocks
    allowed = np.ones(n, bool) if allowed is None else allowed
    return CourseMap(terrain, terrain, allowed, np.where(allowed, 0, RESTRICTED),
                     np.asarray(terrain.goal, float))


@pytest.fixture(scope="module")
def flat_plans():
    # A short flat block (10 segments) keeps the three builds fast.
    terrain = jaxhop.make_terrain([(0.0, 1.5, 0.0)], (1.1, 1.3, 0.0), "short")
    ref = jaxhop.build_plan(terrain, progress=False)
    scaled = jaxhop.build_plan(terrain, templates=scaled_templates(jaxhop.Hopper()),
                               progress=False)
    ours = build_course_plan(_flat_map(terrain), paper_templates(), jaxhop.Hopper())
    return ref, scaled, ours


@pytest.mark.slow
def test_reference_plan_from_scaled_templates_is_identical(flat_plans):
    ref, scaled, _ = flat_plans
    assert np.array_equal(ref.order, scaled.order)
    assert np.array_equal(ref.goals, scaled.goals)
    assert np.array_equal(ref.situated, scaled.situated)
    assert (ref.prepares != scaled.prepares).nnz == 0


@pytest.mark.slow
def test_course_builder_matches_build_plan(flat_plans):
    # With every block allowed, the course builder is `jaxhop.build_plan` stage for stage.
    ref, _, ours = flat_plans
    p = ours.plan
    assert np.array_equal(ref.situated, p.situated)
    assert np.array_equal(ref.target, p.target)
    assert np.allclose(ref.goals, p.goals, rtol=0, atol=1e-12)
    assert np.allclose(ref.robustness, p.robustness)
    assert np.array_equal(ref.order, p.order)


# --- course -> terrain ---------------------------------------------------------------------


@pytest.mark.parametrize("name", list_courses())
def test_course_map_classifies_every_point_like_the_course(name):
    course = load_course(name)
    rng = np.random.default_rng(0)
    for _, env in [(0, course.environment)] + list(course.snapshots):
        m = course_map(course, env)
        blocks = np.asarray(m.true.blocks())
        plan_h = np.asarray(m.plan.heights)
        assert np.allclose(blocks[1:, 0], blocks[:-1, 1])  # no holes
        x = rng.uniform(blocks[0, 0], blocks[-1, 1], 4000)
        b = np.searchsorted(blocks[:, 1], x)
        # Heights: the course's surface.
        assert np.allclose(blocks[b, 2], env.surface(x))
        # Kinds: restricted areas first, then the edge margin (brute force on the course).
        restricted = np.any((x[:, None] > env.restricted_lo) & (x[:, None] < env.restricted_hi),
                            axis=1)
        edges = np.concatenate([env.front, env.back])
        near = np.min(np.abs(x[:, None] - edges), axis=1) < course.margin_h
        want = np.where(restricted, RESTRICTED, np.where(near, MARGIN, 0))
        tol = np.min(np.abs(x[:, None] - np.concatenate(
            [edges, edges - course.margin_h, edges + course.margin_h, env.restricted_lo,
             env.restricted_hi])), axis=1) > 1e-9
        assert np.array_equal(m.kind[b][tol], want[tol])
        assert np.array_equal(m.allowed[b], m.kind[b] == 0)
        # The planner's map raises only the margin bands on obstacle tops, by Mv.
        raised = plan_h[b] - blocks[b, 2]
        on_top = env.surface(x) > 0
        assert np.allclose(raised[tol], np.where(on_top & near, course.margin_v, 0.0)[tol])


# --- incremental update ----------------------------------------------------------------------

SMALL = {
    "name": "small", "start": 0.0, "goal": 1.6,
    "margins": {"horizontal": 0.03, "vertical": 0.05},
    "obstacles": [{"position": 0.9, "width": 0.12, "height": 0.1}],
    "restricted": [{"position": 1.2, "width": 0.2}],
    "snapshots": [
        {"from_jump": 2, "obstacles": [{"position": 0.9, "width": 0.12, "height": 0.1},
                                       {"position": 0.45, "width": 0.1, "height": 0.08}],
         "restricted": [{"position": 1.2, "width": 0.2}]},
        {"from_jump": 4, "obstacles": [{"position": 0.9, "width": 0.12, "height": 0.1},
                                       {"position": 0.451, "width": 0.1, "height": 0.08}],
         "restricted": [{"position": 1.25, "width": 0.2}]},
    ],
}
GRID = PairGrid(4, 4)


@pytest.fixture(scope="module")
def small_plans():
    course = course_from_dict(SMALL)
    hop = leg_hopper()
    tm = leg_templates(hop)
    cps = course_plans(course, hop, tm, grid=GRID, rebuild=2)
    # The first plan is a full build; the snapshots' full rebuilds are those `course_plans`
    # made for its own comparison.
    fulls = [cps.plans[0], *cps.rebuilt]
    assert len(fulls) == len(cps.maps)
    return course, hop, cps, fulls


@pytest.mark.slow
def test_incremental_update_equals_full_rebuild(small_plans):
    course, hop, cps, fulls = small_plans
    assert cps.rebuild_equal == [True, True]
    for inc, full in zip(cps.plans[1:], fulls[1:]):
        assert inc.stats["incremental"]
        assert inc.stats["recomputed_pairs"] < full.stats["n_candidate_pairs"]
        assert same_deployment(inc, full)
        assert np.array_equal(inc.plan.robustness, full.plan.robustness)
        assert (inc.plan.prepares != full.plan.prepares).nnz == 0


@pytest.mark.slow
def test_incremental_update_gives_the_same_outcomes(small_plans):
    course, hop, cps, fulls = small_plans
    padded = pad_plans(cps)
    apex0, _ = initial_states(cps, padded, 24, 1, hop)
    a = run_reactive(cps, padded, apex0, hopper=hop, controller="paper")
    cps_full = dataclass_replace(cps, plans=fulls)
    b = run_reactive(cps_full, pad_plans(cps_full), apex0, hopper=hop, controller="paper")
    assert np.array_equal(a["code"], b["code"])
    assert np.array_equal(a["steps"], b["steps"])
    assert np.array_equal(a["policies"], b["policies"])
    # And under sensor noise (same seed), where runs wander more.
    a = run_reactive(cps, padded, apex0, hopper=hop, noise="sensor", seed=3, controller="paper")
    b = run_reactive(cps_full, pad_plans(cps_full), apex0, hopper=hop, noise="sensor", seed=3,
                     controller="paper")
    assert np.array_equal(a["code"], b["code"])
    assert np.array_equal(a["steps"], b["steps"])


@pytest.mark.slow
def test_slip_course_tables_carry_the_slip_table_and_decide_as_the_plan_does(small_plans):
    # A course's padded tables must give the SLIP the deadbeat's start table (without it
    # every decision ran the multi-start solver, ten times slower on the leg), and padding
    # must not change a decision: the same policy and controls as the plan's own tables.
    from jaxhop._control.decisions import decide_slip

    course, hop, cps, _ = small_plans
    assert pad_plans(cps).tables[0].slip is None
    padded = pad_plans(cps, "slip").tables[0]
    own = cps.plans[0].plan.tables(slip=True)
    assert padded.slip is not None and padded.goals.shape[0] > own.goals.shape[0]
    apex0, _ = initial_states(cps, pad_plans(cps), 3, 2, hop)
    decide = jax.jit(decide_slip)
    for z in apex0:
        f0, u0, a0 = decide(z, own, hop)
        f1, u1, a1 = decide(z, padded, hop)
        assert bool(f0) and bool(f1) and int(a0) == int(a1)
        np.testing.assert_allclose(np.asarray(u1), np.asarray(u0), rtol=1e-12, atol=1e-12)


def dataclass_replace(obj, **kw):
    import dataclasses

    return dataclasses.replace(obj, **kw)


# A taller obstacle (its top and margin bands above `h + rho0`: it binds rises too) moves
# by 2 mm while a restricted area moves; then it is lowered and a low obstacle removed;
# then nothing changes.
TALL = {
    "name": "tall", "start": 0.0, "goal": 1.2,
    "margins": {"horizontal": 0.03, "vertical": 0.05},
    "obstacles": [{"position": 0.5, "width": 0.1, "height": 0.25},
                  {"position": 0.85, "width": 0.08, "height": 0.05}],
    "restricted": [{"position": 1.0, "width": 0.06}],
    "snapshots": [
        {"from_jump": 2, "obstacles": [{"position": 0.502, "width": 0.1, "height": 0.25},
                                       {"position": 0.85, "width": 0.08, "height": 0.05}],
         "restricted": [{"position": 1.03, "width": 0.06}]},
        {"from_jump": 3, "obstacles": [{"position": 0.502, "width": 0.1, "height": 0.22}],
         "restricted": [{"position": 1.03, "width": 0.06}]},
        {"from_jump": 4, "obstacles": [{"position": 0.502, "width": 0.1, "height": 0.22}],
         "restricted": [{"position": 1.03, "width": 0.06}]},
    ],
}


def _course_maps(spec, align=True):
    course = course_from_dict(spec)
    hop = leg_hopper()
    envs = [course.environment] + [e for _, e in course.snapshots]
    return [course_map(course, e, hop, align=align) for e in envs], hop


def _tall_maps(align=False, model="bhop"):
    maps, hop = _course_maps(TALL, align)
    return maps, hop, leg_templates(hop, model=model)


def test_course_map_segments_stay_put_when_an_obstacle_moves():
    # Floor segments of a block with one end on the lattice sit flush with it, on the
    # absolute grid k * 2l, so moving the tall obstacle by 2 mm and the restricted area by
    # 3 cm changes only segments within a segment of the moved edges (and their margin
    # bands); and every block keeps as many segments as centring gives it.
    from jaxhop._core.terrain import segments
    from jaxhop.parkour._map import CELL, _on_lattice

    maps, hop, tm = _tall_maps(align=True)
    centred, _, _ = _tall_maps(align=False)
    seg = tm.seg_length

    def landable(m, lattice_only=False):
        s = segments(m.plan, seg)
        b = np.asarray(s.block)
        keep = np.asarray(m.kind)[b] == 0
        if lattice_only:
            st, en = np.asarray(m.plan.starts), np.asarray(m.plan.ends)
            one = np.array([_on_lattice(st[k], CELL * seg) or _on_lattice(en[k], CELL * seg)
                            for k in b])
            keep &= one
        return np.asarray(s.centre)[keep]

    for m, mc in zip(maps, centred):
        assert len(landable(m)) == len(landable(mc))
        c = landable(m, lattice_only=True)
        assert len(c) > 0.5 * len(landable(m))
        k = c[:, 0] / seg - 0.5
        np.testing.assert_allclose(k, np.round(k), atol=1e-9)

    def moved(a, b):
        key = [set(map(tuple, np.round(landable(m), 9))) for m in (a, b)]
        return np.array(sorted(key[0] ^ key[1]))

    changed = moved(*maps[:2])
    # Centred, every segment of the re-cut floor blocks moves.
    assert 0 < len(changed) <= 0.5 * len(moved(*centred[:2]))
    # Moved edges: the obstacle 0.45-0.55 -> 0.452-0.552, the restricted area
    # 0.97-1.03 -> 1.0-1.06; each with its Mh = 0.03 band.
    edges = np.array([0.45, 0.452, 0.55, 0.552, 0.97, 1.0, 1.03, 1.06])
    near = np.min(np.abs(changed[:, :1] - edges[None, :]), axis=1)
    assert np.all(near <= 0.03 + seg)


def _interior_gaps(m, seg):
    """Stretches of allowed floor between two allowed segments of one height that no
    segment covers (brute force over consecutive segments)."""
    from jaxhop._core.terrain import segments

    s = segments(m.plan, seg)
    c = np.asarray(s.centre)[np.asarray(m.allowed)[np.asarray(s.block)]]
    st, en = np.asarray(m.plan.starts), np.asarray(m.plan.ends)
    gaps = []
    for (y0, h0), (y1, h1) in zip(c[:-1], c[1:]):
        lo, hi = y0 + seg / 2, y1 - seg / 2
        under = (en > lo + 1e-12) & (st < hi - 1e-12)
        if h0 == h1 and hi - lo > 1e-9 and np.all(np.asarray(m.allowed)[under]):
            gaps.append((lo, hi))
    return gaps


@pytest.mark.parametrize("name", ["mppc-hw-static", "mppc-hw-dynamic-1"])
def test_lattice_segments_leave_no_gap_inside_the_floor(name):
    # Centred, a floor block next to a lattice cut leaves half its slack uncovered at the
    # cut, in the middle of the floor (outside every domain); on the lattice grid the
    # slack goes to the block's free end, and every block keeps its segment count.
    from jaxhop._core.terrain import segments

    course = load_course(name)
    hop = leg_hopper()
    seg = leg_templates(hop).seg_length
    envs = [course.environment] + [e for _, e in course.snapshots]
    assert _interior_gaps(course_map(course, envs[0], hop, align=False), seg)
    for env in envs:
        lat, cen = (course_map(course, env, hop, align=a) for a in (True, False))
        assert _interior_gaps(lat, seg) == []
        n = [int(np.sum(np.asarray(m.allowed)[np.asarray(segments(m.plan, seg).block)]))
             for m in (lat, cen)]
        assert n[0] == n[1]


@pytest.mark.slow
@pytest.mark.parametrize("align,model", [(False, "bhop"), (True, "bhop"), (True, "slip")])
def test_update_dependency_tests_are_sufficient(align, model):
    # The tests that let an update keep old results, checked directly on the tall
    # obstacle's 2 mm move: a pair between kept policies whose collision clauses no
    # changed block can bind has the same `pair_goal` on both maps, and an apex whose
    # descent meets no changed block has the same `candidate_situated` result. For the
    # SLIP-adjusted templates the domains carry eq 37's foot lead and `Gf` eq 35's limits.
    from jaxhop._planning import stages as S
    from jaxhop.parkour import _build as B
    from jaxhop.parkour import _reach as PR

    maps, hop, tm = _tall_maps(align, model)
    old, new = (B._Context(m, tm, hop) for m in maps[:2])
    blocks = PR.changed_blocks(maps[0], maps[1])
    assert np.any(blocks[:, 2] > hop.rho0)  # the moved obstacle binds rises from the floor

    old_to_new = PR.situated_map(maps[0], old.segs, new)
    new_to_old = np.full(new.n_sit, -1)
    new_to_old[old_to_new[old_to_new >= 0]] = np.nonzero(old_to_new >= 0)[0]
    kept = (new_to_old >= 0) & new.sit_allowed
    row_aff, col_aff = new.affected(blocks)
    rows, cols = new.candidate_pairs(row_aff & kept, col_aff & kept)
    sel = kept[rows] & kept[cols]
    rows, cols = rows[sel], cols[sel]
    binds = new.pair_binds(rows, cols, blocks)
    assert binds.any() and (~binds).any()
    rng = np.random.default_rng(0)
    pick = rng.choice(np.nonzero(~binds)[0], min(1500, int((~binds).sum())), replace=False)

    # The update's own stages (its programs, compiled once for the course builds too).
    def goals(ctx, r, c):
        return S.instantiate(ctx, ctx.pair_args(r, c), GRID)

    f1, g1, m1, d1 = goals(new, rows[pick], cols[pick])
    f0, g0, m0, d0 = goals(old, new_to_old[rows[pick]], new_to_old[cols[pick]])
    assert np.array_equal(f0, f1) and f1.any()
    assert np.array_equal(g0[f1], g1[f1]) and np.array_equal(m0[f1], m1[f1])
    assert np.array_equal(d0[f1], d1[f1])
    # Apexes around the change, with and without the probe box of safety sampling.
    n = 3000
    apex = np.stack([rng.uniform(0.1, 1.0, n), rng.uniform(0.2, 0.7, n),
                     rng.uniform(-0.5, 1.0, n)], 1)
    # `touched` is given only where a touchdown can be looked up differently (a re-cut
    # block of the same height keeps its grid segments).
    landing = PR.landing_changes(maps[0], old.segs, new, blocks)
    assert landing.shape[0] > 0
    untouched = ~new.touched(apex, landing)
    assert untouched.any() and (~untouched).any()
    assert np.all(new.touched(apex, landing, new.probe) >= ~untouched)

    def rows_of(ctx, a):
        return S.prepares_rows(ctx, a)

    ids1, in1 = rows_of(new, apex[untouched])
    ids0, in0 = rows_of(old, apex[untouched])
    for a in range(ids1.shape[0]):
        assert set(ids1[a][in1[a]]) == set(old_to_new[ids0[a][in0[a]]])


@pytest.mark.slow
@pytest.mark.parametrize("model", ["bhop", "slip"])
def test_side_windows_leave_out_only_blocks_that_never_bind(model, monkeypatch):
    # A pair's collision clauses test only the higher blocks whose bounds can reach the
    # regions of the policies on its blocks (`Layout.side_windows`). On the shipped course
    # with the most blocks, screened pairs get the same goals and margins, bit for bit, as
    # from every higher block of the map (the clauses' definition), with shorter lists.
    from jaxhop._planning import stages as S
    from jaxhop._planning.policies import ascent_sides, descent_sides
    from jaxhop.parkour import _build as B

    course, hop = load_course("mppc-hw-two-rounds"), leg_hopper()
    ctx = B._Context(course_map(course, course.environment, hop),
                     leg_templates(hop, model=model), hop)
    down, up = ctx.side_windows()
    t, step = ctx.jterrain, ctx.sides_step
    assert descent_sides(t, step, down).shape[2] < descent_sides(t, step).shape[2]
    assert ascent_sides(t, hop, step, up).shape[2] < ascent_sides(t, hop, step).shape[2]
    rows, cols = ctx.candidate_pairs()
    args = ctx.pair_args(rows, cols)
    screened = np.nonzero(S.screen(ctx, args, GRID))[0]
    pick = np.random.default_rng(0).choice(screened, 2048, replace=False)
    args = tuple(a[pick] for a in args)
    windowed = S.instantiate(ctx, args, GRID)
    monkeypatch.setattr(B._Context, "side_windows", lambda self: (None, None))
    every = S.instantiate(ctx, args, GRID)
    assert windowed[0].sum() > 100
    for a, b in zip(windowed, every):
        np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module", params=[False, True], ids=["centred", "aligned"])
def tall_plans(request):
    maps, hop, tm = _tall_maps(request.param)
    plans = [build_course_plan(maps[0], tm, hop, grid=GRID)]
    for m in maps[1:]:
        plans.append(build_course_plan(m, tm, hop, grid=GRID, previous=plans[-1]))
    fulls = [build_course_plan(m, tm, hop, grid=GRID) for m in maps[1:]]
    return plans, fulls


@pytest.mark.slow
def test_update_with_tall_obstacle_equals_full_rebuild(tall_plans):
    plans, fulls = tall_plans
    for inc, full in zip(plans[1:], fulls):
        assert inc.stats["incremental"]
        assert inc.stats["recomputed_pairs"] < full.stats["n_candidate_pairs"]
        assert identical_plans(inc, full)
    # Pairs between kept policies were recomputed (a changed block binds them) and kept.
    first = plans[1].stats
    assert first["instantiated_pairs_computed"] > 0
    # Nothing changed: nothing is recomputed, the goal policies are kept.
    last = plans[3].stats
    assert last["changed_blocks"] == [] and last["recomputed_pairs"] == 0
    assert last["recomputed_robustness"] == 0 and last["reused_goal_policies"]


@pytest.mark.slow
@pytest.mark.parametrize("printed", [False, True], ids=["leg", "printed"])
def test_shift_bounds_hold_eq35s_limits_at_every_goal_velocity(printed):
    # The update's rise test needs bounds of eq 35's limits over a template's goal
    # velocities: they must hold at every velocity (checked at 200 000 random ones) and be
    # tight (the limits jump at ydot = 0 and, with the printed constants, where `h`
    # switches constants).
    import jax.numpy as jnp

    from jaxhop._core.params import Hopper
    from jaxhop._planning.regions import slip_shift_limits
    from jaxhop._planning.stages import relative_boxes
    from jaxhop._planning.templates import SlipAdjust
    from jaxhop.parkour._reach import shift_bounds

    if printed:
        hop, tm = Hopper(), paper_templates().for_slip(SlipAdjust.printed())
    else:
        hop = leg_hopper()
        tm = leg_templates(hop, model="slip")
    gf, _ = relative_boxes(tm, hop)
    lo, hi = shift_bounds(tm, gf[:, 2])
    rng = np.random.default_rng(0)
    for t in range(tm.n):
        v = rng.uniform(gf[t, 2, 0], gf[t, 2, 1], 200_000)
        a, b = (np.broadcast_to(np.asarray(x), v.shape)
                for x in slip_shift_limits(jnp.asarray(v), tm.row(t)))
        assert lo[t] <= a.min() <= lo[t] + 1e-3
        assert hi[t] - 1e-3 <= b.max() <= hi[t]


@pytest.mark.slow
@pytest.mark.parametrize("spec", [SMALL, TALL], ids=["small", "tall"])
def test_update_of_a_slip_plan_equals_full_rebuild(spec):
    # The leg's SLIP templates (eqs 35-37: shift limits that vary with the goal velocity, a
    # foot lead) are updated at each snapshot, bit for bit a full rebuild.
    maps, hop = _course_maps(spec)
    tm = leg_templates(hop, model="slip")
    assert tm.slip is not None
    plans = [build_course_plan(maps[0], tm, hop, grid=GRID)]
    for m in maps[1:]:
        plans.append(build_course_plan(m, tm, hop, grid=GRID, previous=plans[-1]))
    for inc, m in zip(plans[1:], maps[1:]):
        full = build_course_plan(m, tm, hop, grid=GRID)
        assert inc.stats["incremental"]
        assert inc.stats["recomputed_pairs"] < full.stats["n_candidate_pairs"]
        assert identical_plans(inc, full)


@pytest.mark.slow
def test_deploy_queue_equals_the_twins_tuple_heap(tall_plans):
    # `deploy`'s queue (float keys, ties by index) gives the order of the twin's heap of
    # `(key, policy)` tuples, also when many keys tie.
    from jaxhop import reference as R
    from jaxhop._planning.deploy import by_depth, by_robustness, by_safety, deploy

    p = tall_plans[0][1].plan
    args = (p.prepares, p.situated, p.safety, p.is_goal, p.robustness)
    ties = (p.prepares, p.situated, np.round(p.safety, 2) * 0, p.is_goal,
            np.round(p.robustness * 3) / 3)
    for pickbest in (by_robustness, by_depth, by_safety):
        for a in (args, ties):
            assert np.array_equal(deploy(*a, pickbest), R.deploy(*a, key=pickbest))


@pytest.mark.slow
def test_reactive_runs_never_touch_forbidden_floor(small_plans):
    course, hop, cps, _ = small_plans
    padded = pad_plans(cps)
    apex0, coverage = initial_states(cps, padded, 24, 2, hop)
    assert coverage > 0.2
    # On the static first environment: correct by construction, every covered state
    # reaches the goal.
    static = dataclass_replace(cps, starts=[0], maps=cps.maps[:1], plans=cps.plans[:1])
    res = run_reactive(static, pad_plans(static), apex0, hopper=hop, controller="paper")
    assert np.all(res["code"] == 0)
    # With the snapshots a run can be caught outside the new plan (an obstacle appears
    # under it), but it never touches down on forbidden floor.
    res = run_reactive(cps, padded, apex0, hopper=hop, controller="paper")
    assert set(np.unique(res["code"])) <= {0, 4}
    for i in range(len(apex0)):
        for k in range(int(res["steps"][i])):
            e = cps.index_at(k)
            f = cps.maps[e].forbidden_intervals()
            y = res["footholds"][i, k, 0]
            assert not np.any((y > f[:, 0] + 1e-9) & (y < f[:, 1] - 1e-9))


@pytest.mark.slow
def test_touchdown_in_restricted_area_is_classified(small_plans):
    from jaxhop._core.params import disturbance_for as disturbance
    from jaxhop.parkour._run import _step_batch

    course, hop, cps, _ = small_plans
    padded = pad_plans(cps)
    f = cps.maps[0].forbidden_intervals()
    lo, hi, kind = f[np.argmax(f[:, 1] - f[:, 0])]
    # Straight above the middle of a forbidden block no policy is situated: outside_domain.
    res = run_reactive(cps, padded, [[0.5 * (lo + hi), 0.3, 0.0]], hopper=hop, controller="paper")
    assert res["code"][0] == 4
    # A state the plan covers, stepped with every touchdown declared restricted (or a
    # margin band): the stride's code is that failure.
    apex0, _ = initial_states(cps, padded, 1, 0, hop)
    jnp = jax.numpy
    keys = jax.vmap(jax.random.fold_in, (None, 0))(jax.random.key(0), jnp.arange(1))
    for code in (RESTRICTED, MARGIN):
        forb = padded.forbidden[0].at[0].set(jnp.array([-10.0, 10.0, code]))
        out = _step_batch(jnp.asarray(apex0), jnp.array([-1]), keys, 0, padded.tables[0],
                          padded.terrains[0], forb, jnp.asarray(cps.maps[0].goal),
                          jnp.full(3, 1e-6), disturbance("none", hop), hop, "bhop")
        assert int(out[1][0]) == code
    assert kind in (RESTRICTED, MARGIN)


@pytest.mark.slow
def test_parkour_cli_reactive(tmp_path):
    import argparse

    from jaxhop.parkour._cli import add_parser

    path = tmp_path / "small.json"
    path.write_text(json.dumps(SMALL))
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    out = tmp_path / "out.json"
    args = parser.parse_args(["parkour", "--course", str(path), "--planner", "reactive",
                              "--runs", "4", "--json", str(out)])
    assert args.func(args) == 0
    res = json.loads(out.read_text())
    for key in ("course", "planner", "finished", "jumps", "flight_time", "replan_ms",
                "violations", "executed"):
        assert key in res
    # The first run's outcome depends on where the snapshot's new obstacle finds it (on
    # this course most runs meet it: docs/parkour_reactive.md); whatever it is, it is
    # reported consistently and no run touches forbidden floor.
    assert res["planner"] == "reactive" and res["violations"] == 0 and res["runs"] == 4
    assert res["finished"] == (res["failure"] is None)
    assert res["failure"] in (None, *PARKOUR_FAILURES)
    n_ok = round(res["success_rate"] * 4)
    assert abs(res["success_rate"] * 4 - n_ok) < 1e-9
    assert sum(res["failures"].values()) == 4 - n_ok
    assert res["jumps"] == len(res["executed"]) > 0
    assert set(res["executed"][0]) == {"xs", "zs", "v", "theta", "t", "x1", "z1"}
    # Each snapshot's update against the flight it started in: run 0's flight of the
    # stride before the snapshot (its `executed` entry) bounds the shortest over the runs.
    snaps = res["snapshots"]
    assert [s["from_jump"] for s in snaps] == [s["from_jump"] for s in SMALL["snapshots"]]
    for s in snaps:
        k = s["from_jump"]
        if res["jumps"] > k:
            assert s["flight_s"] <= res["executed"][k - 1]["t"] + 1e-12
        if s["flight_s"] is not None:
            assert 0 < s["ascent_s"] < s["flight_s"]
            assert s["within_flight"] == (s["update_s"] <= s["flight_s"])
            assert s["before_decision"] == (s["update_s"] <= s["ascent_s"])
