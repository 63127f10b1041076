"""The adaptive controller: disturbance observer, wind-aware deadbeat, recovery, and the
same runs as the paper's controller when nothing disturbs them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from slip_programs import deadbeats

import jaxhop
from jaxhop._control.decisions import (
    RECOVERY_DISTANCE,
    bhop_stride,
    domain_distance,
    first_match,
    in_global_domain,
)
from jaxhop._control.observer import after_stride, observe, observer_init
from jaxhop._control.runloop import RunConfig
from jaxhop._core.params import Disturbance, Hopper
from jaxhop._core.terrain import builtin_terrain, make_terrain
from jaxhop._execution.batches import run_batch, sweep_grid
from jaxhop._models.bhop import deadbeat_bhop
from jaxhop._models.flight import OK
from jaxhop._planning.cache import get_plan

HOP = Hopper()
# A long flat floor: strides of about 0.5 m for 40 strides.
FLOOR = make_terrain([(-5.0, 60.0, 0.0)])


def _stride_loop(wind, sensor, n, seed):
    """`n` strides on the floor with the true `wind`, deadbeat to goals 0.5 m ahead with the
    observer's estimate; returns the estimates after each stride."""
    rng = np.random.default_rng(seed)
    sensor = jnp.asarray(sensor, float)
    obs = observer_init()
    apex = jnp.array([0.0, 1.6, 0.5])
    upd = jax.jit(observe)
    stride = jax.jit(bhop_stride)
    out = []
    for _ in range(n):
        measured = apex + jnp.asarray(rng.uniform(-1, 1, 3)) * sensor
        obs = upd(obs, measured, sensor, HOP)
        out.append(float(obs.wind))
        goal = jnp.array([measured[0] + 0.5, 1.6, 0.5])
        u = deadbeat_bhop(measured, goal, 0.0, HOP, obs.wind)
        nxt, code, foot = stride(apex, u, FLOOR, HOP, wind)
        assert int(code) == OK
        obs = after_stride(obs, measured, u, foot[1], True)
        apex = nxt
    return np.asarray(out)


def test_observer_converges_to_a_constant_wind():
    est = _stride_loop(-0.2, (0.0, 0.0, 0.0), 6, 0)
    assert est[0] == 0.0  # nothing measured before the first stride
    assert abs(est[1] + 0.2) < 1e-3  # after one stride
    assert np.all(np.abs(est[1:] + 0.2) < 1e-9)


def test_observer_averages_the_wind_out_of_sensor_noise():
    est = _stride_loop(-0.2, (0.05, 0.05, 0.05), 30, 1)
    assert abs(est[-1] + 0.2) < 0.05


def test_observer_stays_near_zero_without_wind_under_sensor_noise():
    for seed in (2, 3):
        est = _stride_loop(0.0, (0.05, 0.05, 0.05), 30, seed)
        assert np.all(np.abs(est[10:]) < 0.06)
        assert abs(est[-1]) < 0.04


def test_observer_keeps_zero_exactly_without_disturbance():
    assert np.all(_stride_loop(0.0, (0.0, 0.0, 0.0), 8, 0) == 0.0)


@pytest.mark.parametrize("wind", [-0.2, 0.35, -1.0])
def test_adaptive_deadbeat_reaches_the_goal_in_the_wind(wind):
    rng = np.random.default_rng(5)
    for _ in range(5):
        apex = jnp.array([rng.uniform(0, 2), rng.uniform(1.4, 2.0), rng.uniform(-1, 1)])
        goal = jnp.array([apex[0] + rng.uniform(-0.4, 0.8), rng.uniform(1.3, 1.9),
                          rng.uniform(-1, 1)])
        u = deadbeat_bhop(apex, goal, 0.0, HOP, wind)
        nxt, code, _ = bhop_stride(apex, u, FLOOR, HOP, wind)
        assert int(code) == OK
        np.testing.assert_allclose(np.asarray(nxt), np.asarray(goal), atol=1e-9)
        # Wind-blind controls miss by about the wind times the flight time.
        blind, _, _ = bhop_stride(apex, deadbeat_bhop(apex, goal, 0.0, HOP), FLOOR, HOP, wind)
        assert abs(float(blind[2] - goal[2])) > 0.1 * abs(wind)


def test_adaptive_deadbeat_without_wind_is_the_paper_deadbeat_bit_for_bit():
    apex, goal = jnp.array([0.3, 1.7, 0.6]), jnp.array([1.1, 1.8, 0.8])
    f = jax.jit(deadbeat_bhop)
    assert np.array_equal(np.asarray(f(apex, goal, 0.0, HOP)),
                          np.asarray(f(apex, goal, 0.0, HOP, jnp.asarray(0.0))))


@pytest.fixture(scope="module")
def flat_plan():
    terrain = builtin_terrain("flat")
    return get_plan(terrain, np.asarray(terrain.goal))


@pytest.mark.slow
def test_recovery_takes_the_nearest_domain(flat_plan):
    tables = flat_plan.tables()
    # Over the flat floor, the foot landing mid-segment 7, ydot = 0.5: the templates'
    # energies end at 1120 J (eq 33). 1200 J lies 80 J above the band (640, 1120) of the
    # velocity band (0, 1), template 2 * 5 + 4: scaled distance 80 / 480. Template 13
    # (400-640 J): 560 / 240; template 9 ((-1, 0), 640-1120 J): 0.5 / 1 on ydot.
    seg, v = 7, 0.5
    z = 1.0 + (1200.0 - 0.5 * 80 * v**2) / (80 * 9.81)
    y = 7.5 * 0.15 - v * np.sqrt(2 * (z - 1.0) / 9.81)
    apex = jnp.array([y, z, v])
    found, _, _ = first_match(apex, tables, HOP)
    assert not bool(found)
    found, s, a, recovered = first_match(apex, tables, HOP, recover=True)
    assert bool(found) and bool(recovered)
    assert int(s) == seg * 20 + 14
    assert int(flat_plan.situated[int(a)]) == int(s)
    ids = seg * 20 + jnp.array([14, 13, 9])
    np.testing.assert_allclose(np.asarray(domain_distance(apex, ids, tables, HOP)),
                               [80 / 480, 560 / 240, 0.5], rtol=1e-9)
    # Beyond RECOVERY_DISTANCE of every domain: no recovery.
    far = 1120.0 + 480.0 * (RECOVERY_DISTANCE + 0.1)
    z = 1.0 + (far - 0.5 * 80 * v**2) / (80 * 9.81)
    found, _, _, recovered = first_match(jnp.array([y, z, v]), tables, HOP, recover=True)
    assert not bool(found) and not bool(recovered)


@pytest.mark.slow
def test_adaptive_equals_paper_without_disturbance(flat_plan):
    grid = sweep_grid(flat_plan.terrain, dy=0.2, dz=0.2)
    initial = grid[in_global_domain(grid, flat_plan.tables(), flat_plan.hopper)]
    assert initial.shape[0] > 20
    runs = {c: run_batch(flat_plan, initial, jaxhop.RunSettings(controller=c),
                         disturbance=Disturbance())
            for c in ("paper", "adaptive")}
    for k in ("code", "steps", "apexes", "footholds", "policies"):
        np.testing.assert_array_equal(runs["paper"][k], runs["adaptive"][k])
    assert not runs["adaptive"]["recoveries"].any()


def test_controller_option_is_checked():
    from jaxhop._core.errors import InputError

    with pytest.raises(InputError):
        RunConfig(goal=jnp.zeros(3), controller="smart")


# --- SLIP: the same observer and a wind-aware deadbeat through diffrax ----------------------

MG = float(HOP.m * HOP.g)


def _slip_targets(wind, n, seed):
    """Apexes and the apexes that random admissible SLIP controls reach from them over flat
    ground at 0 in the `wind`: reachable goals by construction."""
    from jaxhop._models.slip.stride import STRIDE_TOL, slip_apex_map

    rng = np.random.default_rng(seed)
    apex = np.stack([rng.uniform(0, 1, n), rng.uniform(1.1, 1.4, n), rng.uniform(0.5, 2.5, n)],
                    1)
    u = np.stack([rng.uniform(0.05, 0.3, n), rng.uniform(20, 40, n) * MG,
                  rng.uniform(20, 40, n) * MG], 1)
    fly = jax.jit(jax.vmap(lambda a, c, w: slip_apex_map(a, c, 0.0, HOP, STRIDE_TOL, w),
                           (0, 0, None)))
    goal, code = fly(jnp.asarray(apex), jnp.asarray(u), wind)
    assert np.all(np.asarray(code) == OK)
    return jnp.asarray(apex), goal, jnp.asarray(u), fly


@pytest.mark.slow
def test_slip_adaptive_deadbeat_reaches_the_goal_in_the_wind():
    from jaxhop._models.slip.stride import slip_stride

    wind = 0.3
    apex, goal, _, fly = _slip_targets(wind, 3, 3)
    u, ok = deadbeats(apex, goal, np.zeros(len(apex)), wind)
    assert np.all(ok)
    # The executed stride on a floor, flown in the same wind, ends on the goal.
    nxt, code, _ = jax.vmap(lambda a, c: slip_stride(a, c, FLOOR, HOP, wind))(apex, u)
    assert np.all(np.asarray(code) == OK)
    assert np.max(np.abs(np.asarray(nxt - goal))) < 1e-4
    # Its wind-blind controls (the same solver at wind 0) miss by about the wind's
    # effect over a flight: more than 0.05 m or m/s.
    blind, _ = deadbeats(apex, goal, np.zeros(len(apex)), 0.0)
    missed, _ = fly(apex, blind, wind)
    assert np.all(np.max(np.abs(np.asarray(missed - goal)), axis=1) > 0.05)


def _slip_observer_loop(wind, n, seed):
    """`n` SLIP strides with random admissible controls in the true `wind`; the observer's
    estimate after each stride's apex."""
    from jaxhop._control.decisions import SLIP
    from jaxhop._models.slip.stride import slip_stride

    rng = np.random.default_rng(seed)
    update = jax.jit(lambda o, m, s, h: SLIP.observe(o, m, s, h))
    stride = jax.jit(lambda a, c, w: slip_stride(a, c, FLOOR, HOP, w))
    obs, apex, sensor = observer_init(), jnp.array([0.0, 1.25, 1.0]), jnp.zeros(3)
    out = []
    for _ in range(n):
        obs = update(obs, apex, sensor, HOP)
        out.append(float(obs.wind))
        u = jnp.array([0.085 + rng.uniform(-0.01, 0.01), 30 * MG, 30 * MG])
        nxt, code, foot = stride(apex, u, wind)
        assert int(code) == OK
        obs = after_stride(obs, apex, u, foot[1], True)
        apex = nxt
    return np.asarray(out)


@pytest.mark.slow
def test_slip_observer_converges_to_a_constant_wind():
    est = _slip_observer_loop(-0.2, 5, 0)
    assert est[0] == 0.0
    assert np.all(np.abs(est[3:] + 0.2) < 1e-3)
    # Without wind and without noise the SLIP's integration noise stays below the
    # observer's floor: the estimate stays exactly 0.
    assert np.all(_slip_observer_loop(0.0, 4, 0) == 0.0)


def test_descent_measurement_gives_the_wind_before_the_first_touchdown():
    from jaxhop._control.observer import observe_descent

    obs = observer_init()
    # No sensor noise: one velocity change over 0.2 s of descent gives the wind.
    est = observe_descent(obs, 0.5, 0.5 - 0.2 * 0.2, 0.2, jnp.zeros(3))
    assert abs(float(est.wind) + 0.2) < 1e-9
    # With the paper's sensor noise (+-0.05 m/s) one such measurement is worth little
    # against an estimate already learnt: the gain follows the two variances.
    learnt = obs._replace(wind=jnp.asarray(-0.2), var=jnp.asarray(1e-4))
    est = observe_descent(learnt, 0.5, 0.5 - 0.2 * 0.2 + 0.05, 0.2, jnp.full(3, 0.05))
    r = 2 * 0.05**2 / (3 * 0.2**2)
    np.testing.assert_allclose(float(est.wind), -0.2 + (1e-4 + 1e-6) / (1e-4 + 1e-6 + r)
                               * 0.05 / 0.2, rtol=1e-6)
    # No descent to measure in: the estimate is kept.
    assert float(observe_descent(learnt, 0.5, 9.0, 0.0, jnp.zeros(3)).wind) == -0.2


def _filter_loop(wind, sensor, n, seed):
    """`_stride_loop`, deciding on the observer's filtered apex as the run loop does;
    returns the true apexes, the measurements, the estimates and their covariances."""
    rng = np.random.default_rng(seed)
    sensor = jnp.asarray(sensor, float)
    obs = observer_init()
    apex = jnp.array([0.0, 1.6, 0.5])
    upd, stride = jax.jit(observe), jax.jit(bhop_stride)
    rows = []
    for _ in range(n):
        measured = apex + jnp.asarray(rng.uniform(-1, 1, 3)) * sensor
        obs = upd(obs, measured, sensor, HOP)
        rows.append((apex, measured, obs.estimate, obs.est_var))
        goal = jnp.array([obs.estimate[0] + 0.5, 1.6, 0.5])
        u = deadbeat_bhop(obs.estimate, goal, 0.0, HOP, obs.wind)
        nxt, code, foot = stride(apex, u, FLOOR, HOP, wind)
        assert int(code) == OK
        obs = after_stride(obs, obs.estimate, u, foot[1], True)
        apex = nxt
    return [np.asarray(x) for x in zip(*rows)]


@pytest.mark.parametrize("wind", [0.0, -0.2])
def test_apex_filter_beats_the_raw_measurement(wind):
    # Uniform noise of half-width 0.05 has a standard deviation of 0.0289 per axis; the
    # filter, which knows the stride's dynamics, must do clearly better on every axis
    # once it has a few strides behind it, and its covariance must describe its errors
    # (never overconfident by more than 2x, nor cautious by more than 3x).
    true, meas, est, cov = _filter_loop(wind, (0.05, 0.05, 0.05), 60, 4)
    raw = np.sqrt(np.mean((meas[10:] - true[10:]) ** 2, axis=0))
    filt = np.sqrt(np.mean((est[10:] - true[10:]) ** 2, axis=0))
    assert np.all(np.abs(raw - 0.05 / np.sqrt(3)) < 0.01)
    assert np.all(filt < 0.75 * raw), (filt, raw)
    stated = np.sqrt(np.mean(np.diagonal(cov[10:], axis1=1, axis2=2), axis=0))
    assert np.all((stated > filt / 2) & (stated < 3 * filt)), (stated, filt)
    # The first apex has nothing to fuse: it is the measurement.
    assert np.array_equal(est[0], meas[0])


def test_apex_filter_is_the_measurement_without_sensor_noise():
    true, meas, est, _ = _filter_loop(-0.2, (0.0, 0.0, 0.0), 8, 0)
    assert np.array_equal(est, meas) and np.array_equal(meas, true)


def _posterior_information_form(x0, p0, h, r, m):
    """The Gaussian posterior in information form, written independently of the gain form
    `fuse_descent` uses: `P = (P0^-1 + H^T R^-1 H)^-1`, `x = P (P0^-1 x0 + H^T R^-1 m)`."""
    info = np.linalg.inv(p0) + h.T @ np.linalg.inv(r) @ h
    p = np.linalg.inv(info)
    return p @ (np.linalg.inv(p0) @ x0 + h.T @ np.linalg.inv(r) @ m), p


def test_descent_measurement_over_a_hole_times_the_fall_to_the_nearest_block():
    # Over the hole of `reference` (4.2-5.2 m) the map has no block under the apex. The
    # foot lands on a block beside it, so the leg is placed half way through the fall to
    # the nearest one: a wind-blind first decision there turned runs from (5.0, 1.8, 0.5)
    # back into the hole in the paper's headwind.
    from jaxhop._control.observer import DESCENT_FRACTION, descent_time

    terrain = builtin_terrain("reference")

    def fall(z, h):  # by hand: DESCENT_FRACTION of the fall to the foot at rest length on h
        return DESCENT_FRACTION * np.sqrt(2.0 * (z - h - HOP.rho0) / HOP.g)

    cases = [((5.0, 1.8), 0.2),   # over the hole, 0.2 m from the block at 5.2 m (h 0.2)
             ((4.3, 1.8), -0.2),  # over the hole, 0.1 m past the block ending at 4.2 m
             ((4.7, 1.8), 0.2),   # half way: both 0.5 m away, the higher one
             ((3.0, 1.8), 0.1),   # on a block: its own height
             ((10.4, 1.5), 0.0)]  # past the map's end: the last block
    for (y, z), h in cases:
        t = descent_time(jnp.array([y, z, 0.5]), terrain.heights, terrain, HOP)
        np.testing.assert_allclose(float(t), fall(z, h), rtol=1e-12, err_msg=str((y, z)))


def test_descent_fusion_is_the_gaussian_posterior_of_both_measurements():
    from jaxhop._control.observer import PROCESS_VAR, R_MIN, fuse_descent

    g, t = 9.81, 0.23
    sensor = np.array([0.05, 0.04, 0.03])
    est = np.array([1.2, 1.7, 0.6])
    est_var = np.array([[4e-4, 1e-5, 2e-5], [1e-5, 6e-4, 0.0], [2e-5, 0.0, 3e-4]])
    obs = observer_init()._replace(estimate=jnp.asarray(est), est_var=jnp.asarray(est_var),
                                   wind=jnp.asarray(-0.1), var=jnp.asarray(0.04))
    descent = np.array([1.36, 1.44, 0.57])
    new = fuse_descent(obs, jnp.asarray(descent), t, jnp.asarray(sensor), g)
    # The same measurement written as (y, z + g t^2 / 2, ydot) of the state (y, z, ydot, a).
    h = np.array([[1, 0, t, t * t / 2], [0, 1, 0, 0], [0, 0, 1, t]], float)
    p0 = np.zeros((4, 4))
    p0[:3, :3], p0[3, 3] = est_var, 0.04 + PROCESS_VAR
    x, p = _posterior_information_form(np.r_[est, -0.1], p0, h,
                                       np.diag(sensor**2 / 3 + R_MIN),
                                       descent + np.array([0, g * t * t / 2, 0]))
    np.testing.assert_allclose(np.asarray(new.estimate), x[:3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(new.wind), x[3], rtol=0, atol=1e-10)
    np.testing.assert_allclose(np.asarray(new.est_var), p[:3, :3], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(float(new.var), p[3, 3], rtol=1e-9)
    # No descent to measure in: nothing changes.
    kept = fuse_descent(obs, jnp.asarray(descent), 0.0, jnp.asarray(sensor), g)
    assert np.array_equal(np.asarray(kept.estimate), est) and float(kept.wind) == -0.1


def test_stride_error_is_process_noise_of_the_prediction():
    # A hopper the model does not describe (`jaxhop.mujoco`): its stride error, uniform of
    # half-widths w, adds w^2 / 3 to the apex prediction's covariance and w_v^2 / 3 to the
    # wind innovation's noise. Checked against the Gaussian posterior in information
    # form; no stride error is jaxhop's observer bit for bit.
    from jaxhop._control.observer import PROCESS_VAR, Q_MIN, R_MIN, bhop_terms

    sensor = jnp.full(3, 0.05)
    w = np.array([0.03, 0.05, 0.05])
    apex = jnp.array([0.0, 1.6, 0.5])
    u = deadbeat_bhop(apex, jnp.array([0.6, 1.5, 0.4]), 0.0, HOP)
    obs = observer_init()._replace(
        apex=apex, u=u, h=jnp.asarray(0.0), pending=jnp.asarray(True),
        wind=jnp.asarray(-0.1), var=jnp.asarray(0.01),
        est_var=jnp.diag(jnp.array([3e-4, 4e-4, 5e-4])))
    pred, h_wind, jac = bhop_terms(obs, HOP)
    measured = np.asarray(pred) + np.array([0.02, -0.03, 0.04])
    plain = observe(obs, jnp.asarray(measured), sensor, HOP)
    zero = observe(obs, jnp.asarray(measured), sensor, HOP, stride_error=jnp.zeros(3))
    assert all(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
               for a, b in zip(plain, zero))
    new = observe(obs, jnp.asarray(measured), sensor, HOP, stride_error=jnp.asarray(w))
    pred, h_wind, jac = (np.asarray(x) for x in (pred, h_wind, jac))
    est_var, r_apex = np.asarray(obs.est_var), np.diag(0.05**2 / 3 * np.ones(3))
    # the wind: a scalar Gaussian prior and one measurement of the speed
    p = 0.01 + PROCESS_VAR
    r = 0.05**2 / 3 + jac[2] @ est_var @ jac[2] + R_MIN + w[2] ** 2 / 3
    wind = (-0.1 / p + h_wind[2] * (measured[2] - pred[2] + h_wind[2] * -0.1) / r) / (
        1 / p + h_wind[2] ** 2 / r)
    var = 1 / (1 / p + h_wind[2] ** 2 / r)
    np.testing.assert_allclose(float(new.wind), wind, rtol=1e-9)
    np.testing.assert_allclose(float(new.var), var, rtol=1e-9)
    # the apex: the prediction with the new wind, its covariance with the stride error
    prior = pred + h_wind * (wind - -0.1)
    p0 = jac @ est_var @ jac.T + var * np.outer(h_wind, h_wind) + np.diag(Q_MIN + w**2 / 3)
    x, cov = _posterior_information_form(prior, p0, np.eye(3), r_apex, measured)
    np.testing.assert_allclose(np.asarray(new.estimate), x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(new.est_var), cov, rtol=1e-9)
    # it trusts the prediction less: its position leans further towards the measurement
    # and its covariance is larger than without the stride error
    assert np.all(np.abs(np.asarray(new.estimate) - measured)[:2]
                  < np.abs(np.asarray(plain.estimate) - measured)[:2])
    assert np.trace(np.asarray(new.est_var)) > np.trace(np.asarray(plain.est_var))


@pytest.mark.parametrize("wind_var", [1.0, 1e-6])
def test_descent_measurement_narrows_the_apex_estimate(wind_var):
    # An apex measured raw (uniform noise, half-width 0.05 on every axis) and a second
    # measurement of the same flight, fused: the position error must shrink (z by about
    # 1/sqrt(2)). The speed's error shrinks only where the wind is known; with the
    # prior's wind (variance 1), the change of speed in flight measures the wind instead.
    # 4 000 seeded draws, a true flight without wind.
    from jaxhop._control.observer import fuse_descent

    rng = np.random.default_rng(7)
    g, t, w = 9.81, 0.2, np.full(3, 0.05)
    true = np.array([2.0, 1.8, 0.5])
    at_t = np.array([true[0] + true[2] * t, true[1] - 0.5 * g * t * t, true[2]])
    n = 4000
    meas = true + rng.uniform(-1, 1, (n, 3)) * w
    desc = at_t + rng.uniform(-1, 1, (n, 3)) * w

    def one(m, d):
        obs = observer_init()._replace(estimate=m, est_var=jnp.diag(jnp.asarray(w**2 / 3)),
                                       var=jnp.asarray(wind_var))
        return fuse_descent(obs, d, t, jnp.asarray(w), g).estimate

    est = np.asarray(jax.jit(jax.vmap(one))(jnp.asarray(meas), jnp.asarray(desc)))
    raw = np.sqrt(np.mean((meas - true) ** 2, axis=0))
    fused = np.sqrt(np.mean((est - true) ** 2, axis=0))
    shrinks = fused < 0.8 * raw
    assert np.all(shrinks[:2]) and shrinks[2] == (wind_var < 1e-3), (fused, raw)
    assert abs(fused[1] / raw[1] - 1 / np.sqrt(2)) < 0.03, (fused, raw)
