"""Fixed-shape loops (`bounded_while`, `run_once(fixed=True)`, `Tolerances.fixed_loops`):
the same results as the data-dependent loops they replace, and no data-dependent loop left
in a SLIP decision on the accelerator path.

Independent checks: plain `lax.while_loop`s of random lengths, run lane by lane; the
decision's deadbeat with the data-dependent loops; the decision's jaxpr, walked.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhop
from jaxhop._core.batching import bounded_while, run_once
from jaxhop._models.slip import kernels
from jaxhop._models.slip.stride import Tolerances

HOP = jaxhop.Hopper()
MG = float(HOP.m * HOP.g)


def _collatz(n, limit):
    """Collatz steps from `n` until 1 or `limit` steps: lanes end after very different
    numbers of turns."""
    def cond(c):
        return (c[0] != 1) & (c[1] < limit)

    def body(c):
        x, k = c
        return jnp.where(x % 2 == 0, x // 2, 3 * x + 1), k + 1

    return cond, body, (n, jnp.zeros_like(n))


def test_a_fixed_loop_ends_as_the_while_loop_lane_by_lane():
    starts = jnp.arange(1, 65)
    expected = [jax.lax.while_loop(*_collatz(n, 200)) for n in starts]  # one lane at a time
    for turns in (200, 250):
        fixed = jax.jit(jax.vmap(lambda n, t=turns: bounded_while(*_collatz(n, 200), t, True)))
        out = fixed(starts)
        assert np.array_equal(out[0], [int(e[0]) for e in expected])
        assert np.array_equal(out[1], [int(e[1]) for e in expected])
    # Too few turns stop the long lanes early: the bound is the caller's to get right.
    short = jax.vmap(lambda n: bounded_while(*_collatz(n, 200), 20, True))(starts)
    assert np.any(np.asarray(short[1]) < [int(e[1]) for e in expected])
    # Not fixed: the while loop itself.
    assert "while" in str(jax.make_jaxpr(lambda n: bounded_while(*_collatz(n, 200), 9))(3))
    assert "while" not in str(jax.make_jaxpr(
        lambda n: bounded_while(*_collatz(n, 200), 9, True))(3))


def test_a_fixed_run_once_selects_as_the_while_loop_runs():
    flags = jnp.array([True, False, True, False])
    init = jnp.array([1.0, 2.0, 3.0, 4.0])

    def twice(zero, x):
        return 2.0 * (x + zero)

    for fixed in (False, True):
        out = jax.vmap(lambda f, x, fx=fixed: run_once(f, lambda z: twice(z, x), x, fx))(
            flags, init)
        assert np.array_equal(out, [2.0, 2.0, 6.0, 4.0])


def _small_slip_plan():
    from jaxhop._planning.plan import build_plan, templates_for

    terrain = jaxhop.make_terrain([(0.0, 1.5, 0.0)], (1.1, 1.3, 0.0), "short")
    return build_plan(terrain, templates=templates_for("slip"), progress=False)


def _while_loops(jaxpr) -> int:
    """The `while` equations of `jaxpr` and of every jaxpr inside it."""
    count = 0
    for eqn in jaxpr.eqns:
        count += eqn.primitive.name == "while"
        for value in eqn.params.values():
            for sub in value if isinstance(value, (list, tuple)) else [value]:
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    count += _while_loops(inner)
    return count


@pytest.mark.slow
def test_an_accelerator_decision_has_no_data_dependent_loop(monkeypatch):
    from jaxhop._control.decisions import decide_slip

    plan = _small_slip_plan()
    tables = plan.tables(slip=True)
    apex = jnp.array([0.5, 1.5, 0.5])

    def loops(tol):
        # The decision's setting, as `decision_tol` picks it on a CPU or an accelerator.
        monkeypatch.setattr(kernels, "decision_tol", lambda platform=None: tol)
        jaxpr = jax.make_jaxpr(lambda z, tb: decide_slip(z, tb, HOP, recover=True))(apex, tables)
        return _while_loops(jaxpr.jaxpr)

    assert kernels.decision_tol("cpu") is kernels.DECISION_TOL
    assert kernels.decision_tol("gpu") is kernels.FIXED_DECISION_TOL
    assert loops(kernels.DECISION_TOL) >= 10  # adaptive strides, early exits: the walk finds them
    assert loops(kernels.FIXED_DECISION_TOL) == 0


# Two compilations of the decision's deadbeat, a minute and a half: with the heavy tests.
@pytest.mark.heavy
@pytest.mark.slow
def test_fixed_loops_give_the_deadbeat_of_the_while_loops():
    # The decision's deadbeat (table starts, a map, wind, the predicted stride) with
    # fixed-shape strides, its loops data-dependent or fixed: the same outcomes, controls
    # and predictions to the last bits (XLA fuses the two programs differently; measured:
    # at most 7e-12 N/m of a kc near 1e4 N/m, 7e-16 m of a prediction).
    from jaxhop._models.slip.deadbeat import DeadbeatSearch, deadbeat_slip
    from jaxhop._models.slip.table import slip_table

    table = slip_table(progress=False)
    terrain = jaxhop.make_terrain([(-4.0, 1.1, 0.0), (1.1, 1.3, 0.3), (1.3, 5.0, 0.0)])
    rng = np.random.default_rng(3)
    n = 8
    apex = np.stack([rng.uniform(-0.6, 0.4, n), rng.uniform(1.15, 1.6, n),
                     rng.uniform(0.0, 2.0, n)], axis=1)
    goal = np.stack([apex[:, 0] + rng.uniform(0.3, 1.2, n), rng.uniform(1.1, 1.6, n),
                     rng.uniform(0.0, 2.0, n)], axis=1)
    wind = np.where(np.arange(n) % 2 == 0, 0.0, rng.uniform(-0.3, 0.3, n))

    def solve(fixed):
        search = DeadbeatSearch(tol=Tolerances(steps=10, fixed_loops=fixed), table=table,
                                fallback=False, accept=1e-4)
        return jax.jit(jax.vmap(lambda a, g, w: deadbeat_slip(
            a, g, 0.0, HOP, search, terrain=terrain, wind=w, predict=True)))(apex, goal, wind)

    (u0, ok0, pred0, code0), (u1, ok1, pred1, code1) = solve(False), solve(True)
    assert np.asarray(ok0).sum() >= n // 2  # most targets solved
    assert np.array_equal(ok0, ok1) and np.array_equal(code0, code1)
    np.testing.assert_allclose(u1, u0, rtol=1e-12, atol=0)
    np.testing.assert_allclose(pred1, pred0, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_an_accelerator_observer_predicts_with_fixed_shape_strides(monkeypatch):
    # On an accelerator the SLIP observer's apex prediction runs the decision's fixed-shape
    # strides: no data-dependent loop in its update. Its innovations are then rounding
    # below a floor that must still hold the fixed strides' error against the executed
    # 1e-10 stride, or an undisturbed run would estimate a wind.
    from jaxhop._control import observer
    from jaxhop._control.decisions import SLIP
    from jaxhop._models.slip.stride import STRIDE_TOL, slip_apex_map

    obs = observer.observer_init()._replace(
        apex=jnp.array([0.0, 1.3, 1.0]), u=jnp.array([0.1, 30 * MG, 30 * MG]),
        pending=jnp.asarray(True))

    def update_loops():
        jaxpr = jax.make_jaxpr(lambda o, m: SLIP.observe(o, m, jnp.zeros(3), HOP))(
            obs, jnp.array([0.5, 1.3, 1.0]))
        return _while_loops(jaxpr.jaxpr)

    tol, floor = observer.slip_prediction()
    assert tol.steps == 0 and tol.rtol == STRIDE_TOL.rtol and floor == observer.NU_MIN_SLIP
    assert update_loops() >= 2  # diffrax's adaptive solves: the walk finds them
    monkeypatch.setattr(kernels, "decision_tol", lambda platform=None: kernels.FIXED_DECISION_TOL)
    tol, floor = observer.slip_prediction()
    assert tol == kernels.FIXED_DECISION_TOL and floor == observer.NU_MIN_SLIP_FIXED
    assert update_loops() == 0
    # Random admissible strides over flat ground: the fixed-shape prediction against the
    # executed stride (rtol 1e-10), well inside the floor.
    rng = np.random.default_rng(5)
    n = 64
    apex = np.stack([np.zeros(n), rng.uniform(1.1, 1.6, n), rng.uniform(0.3, 2.5, n)], 1)
    u = np.stack([rng.uniform(0.0, 0.3, n), rng.uniform(15, 50, n) * MG,
                  rng.uniform(15, 50, n) * MG], 1)
    wind = np.where(np.arange(n) % 2 == 0, 0.0, -0.2)

    def both(a, c, w):
        exact = slip_apex_map(a, c, 0.0, HOP, STRIDE_TOL, w)
        o = obs._replace(apex=a, u=c, h=jnp.asarray(0.0), wind=w)
        return exact, observer.slip_terms(o, HOP)[0]

    (exact, code), pred = jax.jit(jax.vmap(both))(jnp.asarray(apex), jnp.asarray(u),
                                                   jnp.asarray(wind))
    good = np.asarray(code) == 0
    assert good.sum() >= 40
    err = np.abs(np.asarray(pred) - np.asarray(exact))[good]
    assert err.max() < observer.NU_MIN_SLIP_FIXED / 3, err.max()
