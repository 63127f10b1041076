"""The SLIP part of the NumPy/SciPy twin (`jaxhop.reference._slip`) against the JAX path.

The twin integrates the stance with `scipy.integrate.solve_ivp` (DOP853, terminal events)
and the JAX path with diffrax (Tsit5), both at rtol = atol = 1e-10, so strides agree to
~1e-9, not bit for bit; result codes and footholds must be identical. The deadbeat twin runs
the JAX solver's damped Gauss-Newton iteration with a finite-difference Jacobian, so where
the goal is reachable both reach it to ~1e-8, and where it is not (the controls clip), both
stop at the same constrained point to ~1e-6. Sweep states: the SLIP decision (first match and
deadbeat) of sampled sweep states must agree; runs of `jaxhop._execution.batches.run_batch(model=
"slip")` and the twin must agree over their first strides and in most outcomes (see
`test_slip_sweep_subsample_against_jax` for why not in every step count).

Default tests share two compiled JAX functions (a vmapped stride and a vmapped deadbeat);
`@pytest.mark.slow` adds more strides and targets and the sweep through `run_batch`, whose
compilation alone takes minutes.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from slip_programs import deadbeats

import jaxhop
from jaxhop import Hopper, build_plan, make_templates, paper_templates
from jaxhop import reference as R
from jaxhop._control.decisions import decide
from jaxhop._core.terrain import make_terrain
from jaxhop._execution.batches import run_batch, sweep_grid
from jaxhop._models.flight import COLLISION, HOLE, OFF_MAP, OK
from jaxhop._models.slip.kernels import KAPPA_HI, KAPPA_LO, RATIO_HI, RATIO_LO
from jaxhop._models.slip.stride import slip_apex_map, slip_stride
from jaxhop.reference import _slip as RS

HOP, RH = Hopper(), R.Hopper()
MG = HOP.m * HOP.g / HOP.rho0
# Steps up and down, a hole (0.2-0.8), a wall taller than a rising COM (at 2.4) and the
# map's ends within reach.
BLOCKS = [(-2.0, -0.6, 0.0), (-0.6, 0.2, 0.15), (0.8, 1.6, 0.0), (1.6, 2.4, -0.2),
          (2.4, 2.8, 1.3)]
TERRAIN = make_terrain(BLOCKS)
R_TERRAIN = R.Terrain.from_blocks(BLOCKS)

stride_batch = jax.jit(jax.vmap(slip_stride, (0, 0, None, None, 0)))
apex_map_batch = jax.jit(jax.vmap(slip_apex_map, (0, 0, 0, None)))


def random_strides(seed, n):
    """Random apexes over `TERRAIN`, admissible random controls, half of them with wind.

    The last quarter starts low in front of the tall wall, moving towards it, so that some
    strides hit it on the way up after liftoff (the twin without that check fails the test).
    """
    rng = np.random.default_rng(seed)
    apex = np.stack([rng.uniform(-1.5, 2.2, n), rng.uniform(1.2, 1.8, n),
                     rng.uniform(-2.5, 2.5, n)], axis=1)
    wall = n - n // 4
    apex[wall:] = np.stack([rng.uniform(1.6, 2.2, n - wall), rng.uniform(0.9, 1.4, n - wall),
                            rng.uniform(0.0, 2.5, n - wall)], axis=1)
    kc = rng.uniform(KAPPA_LO, KAPPA_HI, n) * MG
    u = np.stack([rng.uniform(-0.45, 0.45, n), kc, kc * rng.uniform(RATIO_LO, RATIO_HI, n)],
                 axis=1)
    wind = np.where(rng.uniform(size=n) < 0.5, 0.0, -0.2)
    return apex, u, wind


def compare_strides(seed, n):
    apex, u, wind = random_strides(seed, n)
    nxt, code, foot = (np.asarray(x) for x in stride_batch(jnp.asarray(apex), jnp.asarray(u),
                                                           TERRAIN, HOP, jnp.asarray(wind)))
    ref = [RS.slip_stride(apex[i], u[i], R_TERRAIN, RH, wind[i]) for i in range(n)]
    r_code = np.array([r[1] for r in ref])
    np.testing.assert_array_equal(r_code, code)
    np.testing.assert_allclose(np.array([r[2] for r in ref]), foot, rtol=0, atol=1e-12)
    ok = code == OK
    err = np.abs(np.array([r[0] for r in ref])[ok] - nxt[ok])
    assert np.max(err) < 1e-7, np.max(err)
    return code, err


@pytest.mark.slow
def test_strides_equal_jax():
    code, err = compare_strides(seed=0, n=200)
    # Every kind of stride happened: completed, collisions, holes, off the map.
    counts = np.bincount(code, minlength=4)
    assert counts[OK] >= 60 and counts[COLLISION] >= 5, counts
    assert counts[HOLE] >= 1 and counts[OFF_MAP] >= 1, counts


@pytest.mark.slow
def test_strides_equal_jax_many():
    code, err = compare_strides(seed=1, n=2000)
    assert (code == OK).sum() >= 600


def test_stride_twin_against_independent_solve():
    """The twin's flat apex map against an energy check: with kc = kd the apex energy is
    conserved (independent of both implementations' event handling)."""
    apex, u, _ = random_strides(3, 24)
    u[:, 2] = u[:, 1]
    energies = []
    for a, c in zip(apex, u):
        nxt, code = RS.slip_apex_map(a, c, 0.0, RH)
        if code == OK:
            energies.append((0.5 * a[2] ** 2 + RH.g * a[1], 0.5 * nxt[2] ** 2 + RH.g * nxt[1]))
    e = np.asarray(energies)
    assert len(e) >= 12
    assert np.max(np.abs(e[:, 1] - e[:, 0]) / e[:, 0]) < 1e-8


def reachable_targets(seed, n):
    """Apexes reached by random controls over flat footholds at random heights."""
    rng = np.random.default_rng(seed)
    apex, u, _ = random_strides(seed, n)
    h = rng.choice([0.0, 0.15, -0.2], n)
    apex[:, 1] += h
    goal, code = apex_map_batch(jnp.asarray(apex), jnp.asarray(u), jnp.asarray(h), HOP)
    ok = np.asarray(code) == OK
    return apex[ok], np.asarray(goal)[ok], h[ok]


def compare_deadbeat(apex, goal, h):
    u, ok = deadbeats(apex, goal, h)
    for i in range(len(apex)):
        ur, okr = R.deadbeat_slip(apex[i], goal[i], h[i], RH)
        assert okr == ok[i], i
        nxt_j, cj = RS.slip_apex_map(apex[i], u[i], h[i], RH)
        nxt_r, cr = RS.slip_apex_map(apex[i], ur, h[i], RH)
        if ok[i] and np.max(np.abs(nxt_j - goal[i])) < 1e-6:
            # Both reach the goal; the controls that do so are then the same.
            assert np.max(np.abs(nxt_r - goal[i])) < 1e-6, i
            np.testing.assert_allclose(ur, u[i], rtol=1e-5, atol=1e-5)
        else:
            np.testing.assert_allclose(ur, u[i], rtol=1e-4, atol=1e-4)
    return ok


@pytest.mark.slow
def test_deadbeat_equals_jax():
    apex, goal, h = reachable_targets(10, 7)
    assert len(apex) >= 4
    ok = compare_deadbeat(apex, goal, h)
    assert ok.sum() >= 3


@pytest.mark.slow
def test_deadbeat_least_squares_reaches_targets():
    apex, goal, h = reachable_targets(11, 4)
    assert len(apex) >= 1
    for a, g, hh in zip(apex[:1], goal[:1], h[:1]):
        u, ok = R.deadbeat_slip(a, g, hh, RH, R.DeadbeatSearch(method="lm"))
        nxt, code = RS.slip_apex_map(a, u, hh, RH)
        assert ok and code == OK
        assert np.max(np.abs(nxt - g)) < 1e-6


@pytest.mark.slow
@pytest.mark.heavy
def test_deadbeat_equals_jax_many():
    apex, goal, h = reachable_targets(12, 32)
    assert len(apex) >= 20
    compare_deadbeat(apex, goal, h)


# --- sweep -----------------------------------------------------------------------------------

SUBSET = [6, 7, 8, 9, 11, 12, 13, 14]  # as tests/test_reference.py


def _flat_plans():
    terrain = jaxhop.builtin_terrain("flat")
    templates = make_templates(paper_templates().as_array()[SUBSET])
    jp = build_plan(terrain, templates=templates, progress=False)
    rt = R.Terrain.from_blocks(terrain.blocks(), terrain.goal)
    rtm = R.Templates(jp.templates.as_array(), jp.templates.seg_length)
    rp = R.Plan(R.situate(rt, rtm, RH), np.asarray(jp.goal), jp.situated, jp.target,
                jp.goals, jp.safety, jp.margin, jp.is_goal, jp.robustness, jp.prepares,
                jp.order, jp.stats, {})
    grid = sweep_grid(terrain)
    initial = grid[jaxhop.in_global_domain(grid, jp.tables(), HOP)]
    return terrain, jp, R.Controller(rp), initial


def _subsample(initial, n, seed):
    rng = np.random.default_rng(seed)
    return initial[np.sort(rng.choice(len(initial), n, replace=False))]


@pytest.mark.slow
def test_slip_decisions_equal_jax():
    """The SLIP deadbeat to the first match of sampled sweep states, twin vs JAX (the
    twin's `decide_slip` with one candidate; the slow sweep test runs the full decision)."""
    terrain, jp, ctrl, initial = _flat_plans()
    states = _subsample(initial, 4, seed=0)
    tables = jp.tables()
    match = jax.jit(jax.vmap(lambda a, t: decide(a, t, HOP, "bhop"), (0, None)))
    found, _, inst = match(jnp.asarray(states), tables)
    h = np.asarray(tables.table.centre)[np.asarray(jp.situated)[np.asarray(inst)]
                                        // jp.templates.n, 1]
    u, _ = deadbeats(states, np.asarray(jp.goals)[np.asarray(inst)], h)
    for i, z in enumerate(states):
        f, ur, a = ctrl.decide_slip(z, n_candidates=1)
        assert f and bool(found[i]) and a == int(inst[i])
        np.testing.assert_allclose(ur, u[i], rtol=1e-4, atol=1e-4)


@pytest.mark.slow
@pytest.mark.heavy
def test_slip_sweep_subsample_against_jax():
    """`run_batch(model="slip")` against the twin's runs from the same initial apexes.

    SLIP runs on a BHop plan often aim at goals outside the SLIP's reach within its control
    limits; the deadbeat then stops at a clipped point after its 16 iterations, where the
    two implementations differ by ~1e-6 (finite differences against forward mode). The
    closed loop amplifies that over a long run (runs that circle the goal box take 10-30
    strides), so only the first strides of every run, and the outcome of most runs, must
    agree; step counts are compared and printed.
    """
    terrain, jp, ctrl, initial = _flat_plans()
    sub = _subsample(initial, 12, seed=1)
    out = run_batch(jp, sub, jaxhop.RunSettings(model="slip", controller="paper"),
                    execution=jaxhop.ExecSettings(chunk=16))
    # The run loop decides with the table-start deadbeat: so does the twin, on its values.
    tab = jp.tables(slip=True).slip
    ctrl.slip_table = tab.data()
    same_code = same_steps = 0
    for i, z0 in enumerate(sub):
        code, steps, apexes = R.run_one(ctrl, z0, model="slip")
        k = min(3, len(apexes), int(np.isfinite(out["apexes"][i, :, 0]).sum()))
        np.testing.assert_allclose(apexes[:k], out["apexes"][i, :k], rtol=0, atol=1e-4)
        same_code += code == out["code"][i]
        same_steps += (code == out["code"][i]) and steps == out["steps"][i]
    print(f"\nSLIP sweep subsample: outcome equal {same_code}/{len(sub)}, outcome and step "
          f"count equal {same_steps}/{len(sub)}")
    assert same_code >= 0.75 * len(sub)
    assert (out["code"] == OK).sum() >= 6
