"""The SLIP deadbeat's start table (`jaxhop._models.slip.table`) and the staged table-start solve.

Independent checks: table entries against the twin's `solve_ivp` strides of a full-size
hopper (the table is built for a unit hopper: Froude scaling must carry it to any size);
the interpolant's Newton refinement against a plane whose root is known; the staged solve
against the targets' apex map (reachable targets from random strides) and against the
twin's staged solve on the same table.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop import Hopper
from jaxhop import reference as R
from jaxhop._core.batching import pad_terrain
from jaxhop._models.slip.deadbeat import DeadbeatSearch, deadbeat_slip
from jaxhop._models.slip.kernels import KAPPA_HI, KAPPA_LO, SEARCH_TOL
from jaxhop._models.slip.stride import slip_apex_map, slip_stride
from jaxhop._models.slip.table import (
    DEFAULT_GRID,
    TableGrid,
    _refine,
    deadbeat_slips,
    slip_table,
    table_starts,
)
from jaxhop.reference import _slip as RS

HOP = Hopper()
#: Maps are padded to this many blocks (`reference`'s), so that one program serves them all.
BLOCKS = 8


@pytest.fixture(scope="module")
def table():
    return slip_table(progress=False)


@jax.jit
def _solve_and_stride(apex, goal, h, table, terrain, wind):
    search = DeadbeatSearch(table=table, fallback=False, accept=1e-4)
    u, ok, pred, code = deadbeat_slip(apex, goal, h, HOP, search, terrain=terrain, wind=wind,
                                      predict=True)
    ref, ref_code, _ = slip_stride(apex, u, terrain, HOP, wind, SEARCH_TOL)
    return u, ok, pred, code, ref, ref_code


def solve_and_stride(apex, goal, h, table, terrain, wind=0.0):
    """A decision's deadbeat over `terrain` (table starts only, accepting C2 <= 1e-4) with
    its predicted stride, and `slip_stride` with its controls: `(u, ok, pred, code, ref,
    ref_code)`. One compiled program for every test here (the map padded to `BLOCKS`
    blocks, the arguments float64 arrays)."""
    real = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    return _solve_and_stride(real(apex), real(goal), real(h), table,
                             pad_terrain(terrain, BLOCKS).unnamed(), real(wind))


@pytest.mark.slow
def test_table_entries_scale_to_a_full_size_hopper(table):
    """Grid entries against the twin's stride of an 80 kg, 1 m hopper (g = 9.81) with the
    same dimensionless inputs: Froude scaling makes them equal up to the integration."""
    g = DEFAULT_GRID
    axes = g.axes()
    rng = np.random.default_rng(0)
    vs = np.sqrt(HOP.g * HOP.rho0)
    mg = HOP.m * HOP.g / HOP.rho0
    checked = 0
    for _ in range(40):
        idx = tuple(int(rng.integers(0, a.size)) for a in axes)
        zeta, nu, eps, th, s = (a[i] for a, i in zip(axes, idx))
        value = np.asarray(table.values[idx])
        apex = np.array([0.0, zeta * HOP.rho0, nu * vs])
        goal = np.array([0.0, eps * HOP.rho0, 0.0])
        kc = (KAPPA_LO + s * (KAPPA_HI - KAPPA_LO)) * mg
        nxt, code, _ = RS.trial(apex, goal, 0.0, th, kc, R.Hopper())
        if code != 0:
            continue
        checked += 1
        assert np.all(np.isfinite(value)), idx
        np.testing.assert_allclose(value, [nxt[0] / HOP.rho0, nxt[2] / vs], atol=1e-5)
    assert checked >= 15


def test_refine_finds_the_root_of_a_linear_plane():
    """On a plane that is linear in (th, s), Newton steps on the interpolant land on the
    exact root from a far cell."""
    grid = TableGrid(th=(-0.6, 0.6, 25), s=(0.0, 1.0, 7))
    th = np.linspace(*grid.th)[:, None]
    s = np.linspace(*grid.s)[None, :]
    plane = np.stack([1.5 * th - 0.4 * s + 0.1, 0.3 * th + 0.8 * s - 0.2], axis=-1)
    root = np.linalg.solve([[1.5, -0.4], [0.3, 0.8]], [0.0 - 0.1, 0.0 + 0.2])
    p, err = _refine(jnp.asarray(plane), jnp.array([-0.5, 0.9]), jnp.zeros(2), grid)
    np.testing.assert_allclose(np.asarray(p), root, atol=1e-10)
    assert float(err) < 1e-20


def reachable(seed, n):
    """Apexes and reachable targets: next apexes of random admissible strides."""
    rng = np.random.default_rng(seed)
    mg = HOP.m * HOP.g / HOP.rho0
    apex = np.stack([rng.uniform(-1, 1, 2 * n), rng.uniform(1.1, 1.6, 2 * n),
                     rng.uniform(-2.5, 2.5, 2 * n)], axis=1)
    kc = rng.uniform(KAPPA_LO, KAPPA_HI, 2 * n) * mg
    u = np.stack([rng.uniform(-0.45, 0.45, 2 * n), kc, kc * rng.uniform(0.5, 2.0, 2 * n)],
                 axis=1)
    goal, code = jax.jit(jax.vmap(slip_apex_map, (0, 0, None, None)))(
        jnp.asarray(apex), jnp.asarray(u), 0.0, HOP)
    keep = np.nonzero(np.asarray(code) == 0)[0][:n]
    return apex[keep], np.asarray(goal)[keep]


@pytest.mark.slow
def test_staged_solve_reaches_targets(table):
    """>= 99 % of reachable targets within 1 mm and 1 mm/s, checked on strides at the
    simulation's tolerance; the multi-start fallback stays the exception."""
    apex, goal = reachable(3, 128)
    u, ok, stage = deadbeat_slips(apex, goal, 0.0, HOP, table)
    nxt, code = jax.jit(jax.vmap(slip_apex_map, (0, 0, None, None)))(
        jnp.asarray(apex), jnp.asarray(u), 0.0, HOP)
    err = np.max(np.abs(np.asarray(nxt) - goal), axis=1)
    hit = (np.asarray(code) == 0) & (err <= 1e-3)
    assert hit.mean() >= 0.99, (hit.mean(), err[~hit])
    assert ok.mean() >= 0.99
    assert set(np.unique(stage)) <= {1, 2, 3}
    assert (stage == 3).mean() <= 0.15


@pytest.mark.slow
def test_staged_solve_equals_twin(table):
    """The twin's staged solve on the same table (finite-difference Jacobian, solve_ivp
    strides) reaches the same reachable targets, checked on its own strides, with the same
    `ok` flags. (The controls need not be equal: a target can have two solutions, and the
    two Jacobians may lead the polish to different ones.)"""
    apex, goal = reachable(4, 8)
    u, ok, stage = deadbeat_slips(apex, goal, 0.0, HOP, table)
    values = table.data()
    for i in range(apex.shape[0]):
        ur, okr, _ = R.deadbeat_slip(apex[i], goal[i], 0.0, R.Hopper(),
                                     R.DeadbeatSearch(table=values), full=True)
        assert okr == bool(ok[i])
        nxt, code = RS.slip_apex_map(apex[i], ur, 0.0, R.Hopper())
        assert code == 0
        np.testing.assert_allclose(nxt, goal[i], atol=1e-3)


@pytest.mark.slow
def test_starts_avoid_touchdowns_off_the_foothold(table):
    """With a terrain, a touchdown angle whose foot lands on another block is no start."""
    from jaxhop._core.terrain import make_terrain

    terrain = make_terrain([(-3.0, 0.3, 0.0), (0.3, 3.0, 0.4)])
    apex = jnp.array([0.0, 1.6, 1.0])
    goal = jnp.array([0.5, 1.5, 1.0])
    starts, _ = table_starts(table, apex, goal, 0.0, HOP, 3, terrain)
    # A foot at y = 1.0 * t_fall + rho0 sin(th) beyond 0.3 lands on the step at 0.4.
    t_fall = np.sqrt(2 * (1.6 - np.cos(np.asarray(starts[:, 0]))) / HOP.g)
    assert np.all(t_fall + np.sin(np.asarray(starts[:, 0])) < 0.3 + 1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("apex, goal", [
    ([0.652257, 1.28109479, 0.99839622], [0.61809854, 1.53402949, -0.59375]),
    ([0.4, 1.3, 0.5], [0.37872505, 1.54988505, -0.09375]),
])
def test_polish_reaches_the_box_minimum_on_the_stiffness_bound(table, apex, goal):
    """Targets out of one stride's reach whose least C2 over the control box lies at the
    stiffest spring (brute force over a 241 x 21 grid of `(th_td, s)`): the staged solve
    without the multi-start solver ends at least as low as the grid's best point."""
    from jaxhop._models.slip.kernels import SEARCH_TOL, _residual, kc_limits
    from jaxhop._models.slip.table import deadbeat_table

    apex, goal = jnp.asarray(apex), jnp.asarray(goal)
    p = jnp.stack(jnp.meshgrid(jnp.linspace(-0.6, 0.6, 241), jnp.linspace(0.0, 1.0, 21),
                               indexing="ij"), -1).reshape(-1, 2)
    r = jax.jit(jax.vmap(lambda q: _residual(q, apex, goal, 0.0, HOP, SEARCH_TOL)))(p)
    c2 = np.sum(np.asarray(r) ** 2, axis=1)
    assert p[np.argmin(c2), 1] == 1.0 and c2.min() > 1e-3  # on the bound, out of reach
    th, kc, c, _ = jax.jit(lambda a, g: deadbeat_table(a, g, 0.0, HOP, SEARCH_TOL, table,
                                                        fallback=False, accept=1e-4))(apex, goal)
    assert float(kc) == pytest.approx(kc_limits(HOP)[1])
    assert float(c) <= c2.min()


@pytest.mark.slow
def test_no_table_start_still_reaches_the_goal(table):
    """An apex from which no touchdown angle of the table lands on the foothold's block:
    without the fallback, the solve's controls (the flat-ground starts' longer polish)
    reach the goal on the twin's stride (solve_ivp) over the same map within 1 mm."""
    from jaxhop import builtin_terrain

    terrain = builtin_terrain("reference")
    apex = jnp.array([8.25, 1.5, 0.5])
    goal = jnp.array([8.76673, 1.43491, 1.08242])
    _, errs = table_starts(table, apex, goal, 0.35, HOP, 3, terrain)
    assert not np.any(np.isfinite(np.asarray(errs)))
    u, ok, *_ = solve_and_stride(apex, goal, 0.35, table, terrain)
    assert bool(ok)
    twin_terrain = R.Terrain.from_blocks(terrain.blocks())
    nxt, code, _ = RS.slip_stride(np.asarray(apex), np.asarray(u), twin_terrain, R.Hopper())
    assert code == 0
    np.testing.assert_allclose(nxt, goal, atol=1e-3)


@pytest.mark.slow
def test_predicted_stride_is_the_stride_of_the_controls(table):
    """`deadbeat_slip(predict=True)` returns the stride its controls give without running
    it where no control was clipped: it must equal `slip_stride` with those controls on the
    same map (apex, and whether the stride succeeds, clearance checks included), clipped or
    not, with and without wind, next to a tall block that some strides sweep over."""
    from jaxhop._core.terrain import make_terrain
    from jaxhop._models.flight import OK

    terrain = make_terrain([(-4.0, 1.1, 0.0), (1.1, 1.3, 0.8), (1.3, 5.0, 0.0)])
    rng = np.random.default_rng(7)
    n = 48
    apex = np.stack([rng.uniform(-0.6, 0.4, n), rng.uniform(1.15, 1.6, n),
                     rng.uniform(-0.5, 2.5, n)], axis=1)
    goal = np.stack([apex[:, 0] + rng.uniform(-0.5, 1.8, n), rng.uniform(1.0, 1.7, n),
                     rng.uniform(-0.5, 3.0, n)], axis=1)
    wind = np.where(np.arange(n) % 2 == 0, 0.0, rng.uniform(-0.5, 0.5, n))

    out = [solve_and_stride(apex[i], goal[i], 0.0, table, terrain, wind[i]) for i in range(n)]
    ok, pred, code, ref, ref_code = (np.stack([np.asarray(o[k]) for o in out])
                                     for k in range(1, 6))
    np.testing.assert_array_equal(code == OK, ref_code == OK)
    good = ref_code == OK
    np.testing.assert_allclose(pred[good], ref[good], rtol=0, atol=1e-12)
    # Every branch is taken: strides without clipping that succeed, strides without
    # clipping that the tall block stops (the clearance checks), and clipped controls.
    assert np.sum(ok & good) >= 5
    assert np.sum(ok & ~good) >= 1
    assert np.sum(~ok) >= 5
    with pytest.raises(ValueError, match="terrain"):
        deadbeat_slip(jnp.asarray(apex[0]), jnp.asarray(goal[0]), 0.0, HOP,
                      DeadbeatSearch(table=table), predict=True)
