"""The NumPy reference twin (`jaxhop.reference`) against the JAX pipeline.

Bit-for-bit equality is not possible: XLA on CPU contracts `a * b + c` into fused
multiply-adds and turns divisions by a loop-invariant scalar into multiplications by its
reciprocal, so values differ from NumPy's in the last bit or two (1e-16). Everything
continuous is therefore compared to 1e-9 or better. One discrete choice was sensitive to
that noise: `pair_goal` takes the argmax of a margin grid in which many cells tie exactly in
exact arithmetic (the `Gf` y-interval has the same half-width, 0.05 m, at every cell). Both
implementations round the margins to 1e-9 before the argmax, so the first tied cell wins in
both, and goals, deployment order and every run's outcome and step count must be identical.
A goal that still differs must sit on a tied cell (`_tie_ok`), which would point at a
margin within 1e-9 of a rounding boundary.

Default tests use 8 of the 20 paper templates (`|ydot| <= 1`, all but the lowest energy) to
stay fast; `@pytest.mark.slow` runs the full template set.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhop
from jaxhop import Disturbance, Hopper, build_plan, make_templates, paper_templates
from jaxhop import reference as R
from jaxhop._control.decisions import decide
from jaxhop._execution.batches import run_batch, sweep_grid
from jaxhop._models.flight import touchdown
from jaxhop._planning.policies import template_boxes

SUBSET = [6, 7, 8, 9, 11, 12, 13, 14]
TIE = 1e-9
CHUNK = 256  # one compilation of the JAX runs per plan


def _templates(full):
    rows = paper_templates().as_array()
    return paper_templates() if full else make_templates(rows[SUBSET])


def _terrain(name):
    if name == "flat":
        return jaxhop.builtin_terrain("flat")
    return jaxhop.random_terrain(jax.random.key(2), 4.0)  # a 0.2 m well and a 0.5 m hole


def _to_ref(terrain, templates):
    return (R.Terrain.from_blocks(terrain.blocks(), terrain.goal),
            R.Templates(templates.as_array(), templates.seg_length))


def _ref_plan_from_jax(jp, sit):
    """A reference `Plan` holding the JAX plan's policies (to compare what follows on equal
    inputs)."""
    return R.Plan(sit, np.asarray(jp.goal), jp.situated, jp.target, jp.goals, jp.safety,
                  jp.margin, jp.is_goal, jp.robustness, jp.prepares, jp.order, jp.stats, {})


_CACHE = {}


def _plans(name, full=False):
    key = (name, full)
    if key not in _CACHE:
        terrain, templates = _terrain(name), _templates(full)
        rt, rtm = _to_ref(terrain, templates)
        jp = build_plan(terrain, templates=templates, progress=False)
        rp = R.build_plan(rt, terrain.goal, rtm, R.Hopper())
        _CACHE[key] = terrain, templates, jp, rp
    return _CACHE[key]


CASES = [pytest.param("flat", False, id="flat"), pytest.param("random", False, id="random"),
         pytest.param("flat", True, id="flat-full", marks=pytest.mark.slow),
         pytest.param("random", True, id="random-full", marks=pytest.mark.slow)]


# --- models --------------------------------------------------------------------------------


def test_bhop_map_and_deadbeat():
    rng = np.random.default_rng(0)
    hopper = Hopper()
    for _ in range(200):
        apex = np.array([rng.uniform(0, 3), rng.uniform(1.2, 2.5), rng.uniform(-2, 2)])
        u = np.array([rng.uniform(-0.25, 0.25), rng.uniform(-0.5, 0.5), rng.uniform(0.7, 1.4)])
        h = rng.uniform(-0.2, 0.2)
        ref = R.bhop_apex_map(apex, u, h, R.Hopper(), wind=-0.2)
        jx = np.asarray(jaxhop.bhop_apex_map(jnp.asarray(apex), jnp.asarray(u), h, hopper,
                                             -0.2))
        np.testing.assert_allclose(ref, jx, rtol=0, atol=1e-12)
        goal = R.bhop_apex_map(apex, u, h, R.Hopper())
        if goal[1] - h - 1.0 < 1e-3:  # lifted off downwards: not invertible
            continue
        ub = R.deadbeat_bhop(apex, goal, h, R.Hopper())
        np.testing.assert_allclose(ub, u, atol=1e-9)  # the twin's own round trip
        jb = np.asarray(jaxhop.deadbeat_bhop(jnp.asarray(apex), jnp.asarray(goal), h, hopper))
        np.testing.assert_allclose(ub, jb, rtol=0, atol=1e-12)


@pytest.mark.parametrize("wind", [0.0, -0.2])
def test_touchdown(wind):
    terrain = jaxhop.builtin_terrain("reference")
    rt = R.Terrain.from_blocks(terrain.blocks())
    rng = np.random.default_rng(1)
    apexes = np.stack([rng.uniform(-0.5, 10.5, 3000), rng.uniform(0.5, 3.0, 3000),
                       rng.uniform(-3, 3, 3000)], 1)
    code, block, t, y, v = R.touchdown(apexes, rt, R.Hopper(), wind)
    out = jax.jit(jax.vmap(lambda a: touchdown(a, jnp.array([0.0, -1.0]), terrain, Hopper(),
                                               wind)))(jnp.asarray(apexes))
    jcode, jblock, jt, jy, jv = (np.asarray(o) for o in out)
    assert np.array_equal(code, jcode)
    ok = code == 0
    assert np.array_equal(block[ok], jblock[ok])
    np.testing.assert_allclose(t, jt, atol=1e-12)
    np.testing.assert_allclose(y, jy, atol=1e-12)
    np.testing.assert_allclose(v, jv, atol=1e-12)
    assert set(np.unique(code)) >= {0, 1, 2, 3}  # every outcome is exercised
    for i in range(0, 3000, 7):  # the scalar path used for single strides
        c1, b1, t1, y1, v1 = R.touchdown_one(apexes[i], rt, R.Hopper(), wind)
        assert c1 == code[i] and (c1 != 0 or b1 == block[i])
        assert (t1, y1, *v1) == (t[i], y[i], *v[i])


@pytest.mark.slow
def test_regions_and_boxes():
    templates = paper_templates()
    rtm = R.Templates(templates.as_array(), templates.seg_length)
    regions = [R.TemplateRegions(rtm, i, R.Hopper()) for i in range(rtm.n)]
    gf, d = (np.asarray(x) for x in template_boxes(templates, Hopper()))
    rgf, rd = R.template_boxes(regions)
    np.testing.assert_allclose(rgf, gf, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rd, d, rtol=0, atol=1e-12)
    # Off round numbers: at e.g. ydot = -2.2 the k_hi root of template 6 is exactly tangent
    # (discriminant 0), and rounding alone decides whether the interval exists.
    v = np.linspace(-5, 5, 401) + 0.0031
    bounds = jax.jit(jax.vmap(jaxhop.goal_height_bounds, (0, None, None)))
    for i, reg in enumerate(regions):
        lo, hi = bounds(jnp.asarray(v), templates.row(i), Hopper())
        lo, hi = np.asarray(lo), np.asarray(hi)
        rlo, rhi = reg.goal_height_bounds(v)
        # Emptiness may differ only where the interval closes (width ~ rounding).
        flip = np.isfinite(rlo) != np.isfinite(lo)
        assert np.all(np.where(np.isfinite(rlo), rhi - rlo, hi - lo)[flip] < 1e-12)
        fin = np.isfinite(rlo) & np.isfinite(lo)
        np.testing.assert_allclose(rlo[fin], lo[fin], atol=1e-12)
        np.testing.assert_allclose(rhi[fin], hi[fin], atol=1e-12)


# --- plan --------------------------------------------------------------------------------


def _tie_ok(rp, jp, a):
    """Whether JAX's goal for policy `a` sits on a cell that ties the reference's best."""
    sit, nt = rp.situation, rp.situation.templates.n
    i, j = int(jp.situated[a]), int(jp.target[a])
    gw, dw = R.world_boxes(sit, *R.template_boxes(sit.regions))
    margin, vs, zs = R.pair_goal(sit, i % nt, i // nt, j % nt, j // nt,
                                 R.pair_box(gw, dw, i, j), margins=True)
    ia = int(np.argmin(np.abs(vs - jp.goals[a, 2])))
    ib = int(np.argmin(np.abs(zs - jp.goals[a, 1])))
    return margin[ia, ib] >= margin.max() - TIE


@pytest.mark.slow
@pytest.mark.parametrize("name,full", CASES)
def test_instantiated_policies(name, full):
    _, _, jp, rp = _plans(name, full)
    for k in ("n_segments", "n_situated", "n_candidate_pairs", "n_instantiated",
              "n_goal_policies", "n_dropped"):
        assert rp.stats[k] == jp.stats[k], k
    assert np.array_equal(rp.situated, jp.situated)
    assert np.array_equal(rp.target, jp.target)
    assert np.array_equal(rp.is_goal, jp.is_goal)
    diff = np.nonzero(np.abs(rp.goals - jp.goals).max(axis=1) > 1e-9)[0]
    assert diff.size <= 1e-4 * rp.goals.shape[0], diff.size
    assert all(_tie_ok(rp, jp, a) for a in diff)
    same = np.setdiff1d(np.arange(rp.goals.shape[0]), diff)
    np.testing.assert_allclose(rp.margin, jp.margin, atol=1e-9)  # ties have equal margins
    np.testing.assert_allclose(rp.safety[same], jp.safety[same], atol=1e-9)
    assert np.array_equal(rp.robustness[same], jp.robustness[same])


@pytest.mark.slow
@pytest.mark.parametrize("name,full", CASES)
def test_prepares_safety_sampling_and_deployment(name, full):
    """On the JAX plan's goals, the twin gives the same P, scores and total order."""
    terrain, templates, jp, rp = _plans(name, full)
    p, rob = R.prepares_and_robustness(rp.situation, jp.goals)
    rob[jp.is_goal] = 1.0
    assert (p != jp.prepares).nnz == 0
    assert np.array_equal(rob, jp.robustness)
    order = R.deploy(jp.prepares, jp.situated, jp.safety, jp.is_goal, jp.robustness)
    assert np.array_equal(order, jp.order)
    for key, pick in ((R.safety_key, "safety"), (R.depth_key, "depth")):
        order = R.deploy(jp.prepares, jp.situated, jp.safety, jp.is_goal, jp.robustness, key)
        jorder = jaxhop.deploy(jp.prepares, jp.situated, jp.safety, jp.is_goal, jp.robustness,
                               jaxhop.PICKBEST[pick])
        assert np.array_equal(order, jorder), pick
    # The twin's own order satisfies the deployment invariant on the twin's own plan.
    assert jaxhop.check_order(rp.order, rp.prepares, rp.situated, rp.is_goal)
    assert np.abs(rp.goals - jp.goals).max() <= 1e-9
    assert np.array_equal(rp.order, jp.order)


# --- execution ------------------------------------------------------------------------------


def _initial(terrain, ctrl, step=1):
    grid = sweep_grid(terrain)
    return grid[R.in_global_domain(ctrl, grid)][::step]


@pytest.mark.slow
@pytest.mark.parametrize("name,full", CASES)
def test_first_match_and_decision(name, full):
    terrain, _, jp, rp = _plans(name, full)
    ctrl = R.Controller(_ref_plan_from_jax(jp, rp.situation))
    grid = sweep_grid(terrain)
    found = R.in_global_domain(ctrl, grid)
    assert np.array_equal(found, jaxhop.in_global_domain(grid, jp.tables(), Hopper()))
    tables = jp.tables()
    jdecide = jax.jit(jax.vmap(lambda z: decide(z, tables, Hopper())))
    sample = grid[::7]
    jf, ju, ja = (np.asarray(o) for o in jdecide(jnp.asarray(sample)))
    for z, f, u, a in zip(sample, jf, ju, ja):
        rf, ru, ra = ctrl.decide(z)
        assert rf == f
        if f:
            assert ra == a
            np.testing.assert_allclose(ru, u, atol=1e-9)
            assert ctrl.first_match_scan(z) == (True, a)


@pytest.mark.slow
@pytest.mark.parametrize("name,full", CASES)
@pytest.mark.parametrize("noise", ["none", "wind"])
def test_sweep_outcomes(name, full, noise):
    """Same outcome and step count for every initial condition (wind: a subsample, with the
    velocity tolerance that wind allows, docs/decisions.md)."""
    terrain, _, jp, rp = _plans(name, full)
    ctrl = R.Controller(_ref_plan_from_jax(jp, rp.situation))
    kw = {} if noise == "none" else {"wind": -0.2, "tolerance": (0.05, 0.05, 0.15)}
    initial = _initial(terrain, ctrl, 1 if noise == "none" else 20)
    ref = R.run_batch(ctrl, initial, **kw)
    jx = run_batch(jp, initial,
                   jaxhop.RunSettings(tolerance=kw.get("tolerance"), controller="paper"),
                   disturbance=Disturbance(wind=kw.get("wind", 0.0)),
                   execution=jaxhop.ExecSettings(chunk=CHUNK))
    assert np.array_equal(ref["code"], jx["code"])
    assert np.array_equal(ref["steps"], jx["steps"])
    if noise == "none":
        assert np.all(ref["code"] == 0)


@pytest.mark.slow
def test_sensor_noise_with_shared_draws():
    """Sensor noise: the twin cannot reproduce JAX's RNG, so it is fed JAX's draws."""
    terrain, _, jp, rp = _plans("flat")
    ctrl = R.Controller(_ref_plan_from_jax(jp, rp.situation))
    initial = _initial(terrain, ctrl, 15)
    key, sensor, max_steps = jax.random.key(3), jnp.array([0.05, 0.05, 0.05]), 60

    def draws(i):
        run = jax.random.fold_in(key, i)
        return jax.vmap(lambda k: jax.random.uniform(jax.random.fold_in(run, k), (3,),
                                                     minval=-1.0, maxval=1.0) * sensor)(
            jnp.arange(max_steps))

    noise = np.asarray(jax.vmap(draws)(jnp.arange(initial.shape[0])))
    ref = R.run_batch(ctrl, initial, noise=noise)
    jx = run_batch(jp, initial, jaxhop.RunSettings(controller="paper"), key=key,
                   disturbance=Disturbance(sensor=sensor),
                   execution=jaxhop.ExecSettings(chunk=CHUNK))
    assert np.array_equal(ref["code"], jx["code"])
    assert np.array_equal(ref["steps"], jx["steps"])


@pytest.mark.slow
@pytest.mark.parametrize("name,full", CASES)
def test_end_to_end_sweep(name, full):
    """Twin plan + twin sweep against JAX plan + JAX sweep (nominal)."""
    terrain, _, jp, rp = _plans(name, full)
    rsum, rinit, rres = R.sweep(rp)
    jinit = sweep_grid(terrain)
    jinit = jinit[jaxhop.in_global_domain(jinit, jp.tables(), Hopper())]
    jres = run_batch(jp, jinit, jaxhop.RunSettings(controller="paper"),
                     execution=jaxhop.ExecSettings(chunk=CHUNK))
    jsum = R.summarize(jres, 0.0)
    assert np.array_equal(rinit, jinit)
    assert rsum["success_rate"] == jsum["success_rate"] == 1.0
    assert rsum["failures"] == jsum["failures"]
    assert np.array_equal(rres["code"], jres["code"])
    assert np.array_equal(rres["steps"], jres["steps"])
