"""SLIP stride and deadbeat checked against independent computations.

The model and deadbeat are those of Arslan & Saranli 2012, section IV-A (eqs 10-16).
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from scipy.integrate import solve_ivp
from slip_programs import deadbeats

from jaxhop._core.params import Hopper
from jaxhop._core.terrain import make_terrain
from jaxhop._models.flight import COLLISION, HOLE, OK
from jaxhop._models.slip.bracket import golden_minimise
from jaxhop._models.slip.deadbeat import DeadbeatSearch, deadbeat_slip
from jaxhop._models.slip.kernels import (
    KAPPA_HI,
    KAPPA_LO,
    RATIO_HI,
    RATIO_LO,
)
from jaxhop._models.slip.stride import (
    COLLAPSED,
    Tolerances,
    _field,
    _liftoff,
    compress,
    decompress,
    slip_apex_map,
    slip_stride,
)

HOP = Hopper()
MG = HOP.m * HOP.g / HOP.rho0
FLAT = make_terrain([(-20.0, 20.0, 0.0)])

stride_batch = jax.jit(jax.vmap(slip_stride, (0, 0, None, None)))
apex_map_batch = jax.jit(jax.vmap(slip_apex_map, (0, 0, None, None)))


def random_strides(seed, n):
    """Random admissible apex states over flat ground at 0 and random admissible controls."""
    rng = np.random.default_rng(seed)
    apex = np.stack([rng.uniform(-1, 1, n), rng.uniform(1.1, 1.6, n),
                     rng.uniform(-2.5, 2.5, n)], axis=1)
    kc = rng.uniform(KAPPA_LO, KAPPA_HI, n) * MG
    u = np.stack([rng.uniform(-0.45, 0.45, n), kc, kc * rng.uniform(RATIO_LO, RATIO_HI, n)],
                 axis=1)
    return apex, u


def reference_stride(apex, u, h=0.0, hopper=HOP):
    """The same stride with scipy's solve_ivp (DOP853, rtol 1e-11); None if it fails."""
    m, g, r0 = hopper.m, hopper.g, hopper.rho0
    y, z, ydot = apex
    th, kc, kd = u
    t_d = np.sqrt(2 * (z - h - r0 * np.cos(th)) / g)
    y_foot = y + ydot * t_d + r0 * np.sin(th)

    def basis(a):
        return np.array([-np.sin(a), np.cos(a)]), np.array([-np.cos(a), -np.sin(a)])

    def field(k):
        return lambda t, x: [x[2], x[3],
                             x[0] * x[3] ** 2 - k / m * (x[0] - r0) - g * np.cos(x[1]),
                             (-2 * x[2] * x[3] + g * np.sin(x[1])) / x[0]]

    def event(fn, direction):
        fn.terminal, fn.direction = True, direction
        return fn

    fallen = event(lambda t, x: min(x[0] * np.cos(x[1]), x[0] - COLLAPSED * r0), -1)
    v = np.array([ydot, -g * t_d])
    e_r, e_th = basis(th)
    x0 = [r0, th, v @ e_r, v @ e_th / r0]
    if x0[2] >= 0:
        return None
    kw = dict(method="DOP853", rtol=1e-11, atol=1e-12)
    s1 = solve_ivp(field(kc), (0, 5), x0, events=[event(lambda t, x: x[2], 1), fallen], **kw)
    if len(s1.t_events[0]) == 0:
        return None
    s2 = solve_ivp(field(kd), (0, 5), s1.y_events[0][0],
                   events=[event(lambda t, x: x[0] - r0, 1), fallen], **kw)
    if len(s2.t_events[0]) == 0:
        return None
    rho, th_lo, rhod, thd = s2.y_events[0][0]
    e_r, e_th = basis(th_lo)
    p = np.array([y_foot, h]) + rho * e_r
    v = rhod * e_r + rho * thd * e_th
    if v[1] <= 0:
        return None
    return np.array([p[0] + v[0] * v[1] / g, p[1] + v[1] ** 2 / (2 * g), v[0]])


def _compare_with_scipy(seed, n, need):
    apex, u = random_strides(seed, n)
    nxt, code, _ = stride_batch(jnp.asarray(apex), jnp.asarray(u), FLAT, HOP)
    nxt, code = np.asarray(nxt), np.asarray(code)
    compared = 0
    for i in range(n):
        ref = reference_stride(apex[i], u[i])
        if ref is None:
            assert code[i] != OK, i
            continue
        assert code[i] == OK, i
        np.testing.assert_allclose(nxt[i], ref, rtol=0, atol=1e-6)
        compared += 1
    assert compared >= need


def test_strides_match_solve_ivp_fast():
    _compare_with_scipy(seed=0, n=14, need=10)


@pytest.mark.slow
def test_strides_match_solve_ivp():
    _compare_with_scipy(seed=1, n=160, need=100)


@pytest.mark.slow
def test_decision_strides_stay_within_a_tenth_of_a_millimetre_of_solve_ivp():
    # A controller's decision polishes and predicts at DECISION_TOL (docs/slip.md): its
    # strides must stay far inside the decision's 5 cm acceptance (measured: 5e-5 at most
    # on 2 000 strides; 1e-4, a looser tolerance, moves apexes by up to 7.6e-4).
    from jaxhop._models.slip.kernels import DECISION_TOL

    apex, u = random_strides(7, 40)
    loose = jax.jit(jax.vmap(lambda a, v: slip_stride(a, v, FLAT, HOP, 0.0, DECISION_TOL)))
    nxt, code, _ = loose(jnp.asarray(apex), jnp.asarray(u))
    nxt, code = np.asarray(nxt), np.asarray(code)
    compared = 0
    for i in range(40):
        ref = reference_stride(apex[i], u[i])
        if ref is None or code[i] != OK:
            continue
        np.testing.assert_allclose(nxt[i], ref, rtol=0, atol=1e-4)
        compared += 1
    assert compared >= 20


def test_fixed_shape_stance_of_a_bare_spring_matches_the_closed_form():
    # Without gravity and rotation the radial motion is harmonic: the bottom lies at
    # rho0 - v / w_c after a quarter period of kc, and the leg leaves at rho0 with speed
    # v w_d / w_c. The fixed-shape phases must place both events there.
    hop = Hopper(g=1e-12)
    fixed = Tolerances(steps=10)

    def stance(v, kc, ratio):
        x_b, code_b = compress(0.0, jnp.stack([0.0, -v]), kc, hop, fixed)
        x_lo, code_lo = decompress(x_b, ratio * kc, hop, fixed)
        return x_b, x_lo, code_b, code_lo

    v, kc, ratio = np.array([1.0, 2.5, 0.3]), np.array([20.0, 60.0, 12.0]) * MG, np.array(
        [1.0, 0.5, 2.0])
    x_b, x_lo, code_b, code_lo = jax.jit(jax.vmap(stance))(v, kc, ratio)
    wc, wd = np.sqrt(kc / hop.m), np.sqrt(ratio * kc / hop.m)
    zero = np.zeros(3)
    assert np.all(code_b == OK) and np.all(code_lo == OK)
    np.testing.assert_allclose(x_b, np.stack([1.0 - v / wc, zero, zero, zero], 1), atol=1e-7)
    np.testing.assert_allclose(x_lo, np.stack([zero + 1.0, zero, v * wd / wc, zero], 1),
                               atol=1e-6)


@pytest.mark.slow
def test_fixed_shape_strides_agree_with_the_exact_stride():
    # An accelerator's decisions take a fixed number of steps per phase; on 2 000 random
    # strides (half of them under wind) they end as the 1e-10 stride does, with apexes
    # within 1e-5 of it (docs/slip.md, "Fixed-shape trial strides").
    from jaxhop._models.slip.kernels import DECISION_TOL, FIXED_DECISION_TOL, decision_tol

    assert decision_tol("cpu") is DECISION_TOL and decision_tol("gpu") is FIXED_DECISION_TOL

    apex, u = random_strides(21, 2000)
    wind = np.where(np.arange(2000) % 2 == 0, 0.0, -0.2)
    runs = jax.vmap(slip_stride, (0, 0, None, None, 0, None))
    exact = jax.jit(lambda a, v, w: runs(a, v, FLAT, HOP, w, Tolerances())[:2])
    fixed = jax.jit(lambda a, v, w: runs(a, v, FLAT, HOP, w, FIXED_DECISION_TOL)[:2])
    assert FIXED_DECISION_TOL.steps > 0
    ref, ref_code = (np.asarray(x) for x in exact(apex, u, wind))
    nxt, code = (np.asarray(x) for x in fixed(apex, u, wind))
    np.testing.assert_array_equal(code, ref_code)
    ok = code == OK
    assert ok.sum() >= 1000
    assert np.abs(nxt - ref)[ok].max() <= 1e-5


@pytest.mark.slow
def test_apex_map_equals_stride_on_flat_ground_and_vmap_equals_loop():
    apex, u = random_strides(2, 4)
    a, c, _ = stride_batch(jnp.asarray(apex), jnp.asarray(u), FLAT, HOP)
    b, d = apex_map_batch(jnp.asarray(apex), jnp.asarray(u), 0.0, HOP)
    np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_array_equal(c, d)
    single = jax.jit(slip_apex_map)
    for i in range(4):
        np.testing.assert_allclose(single(apex[i], u[i], 0.0, HOP)[0], b[i], atol=1e-12)


@pytest.mark.slow
def test_equal_stiffness_conserves_apex_energy():
    apex, u = random_strides(3, 24)
    u[:, 2] = u[:, 1]
    nxt, code = apex_map_batch(jnp.asarray(apex), jnp.asarray(u), 0.0, HOP)
    ok = np.asarray(code) == OK
    assert ok.sum() >= 12

    def energy(a):
        return 0.5 * HOP.m * a[:, 2] ** 2 + HOP.m * HOP.g * a[:, 1]

    rel = np.abs(energy(np.asarray(nxt)) - energy(apex)) / energy(apex)
    assert np.max(rel[ok]) < 1e-8


@pytest.mark.slow
def test_slip_strides_in_device_chunks_equal_single_strides():
    from jaxhop._models.slip.stride import slip_strides

    apex, u = random_strides(6, 40)
    nxt, code, foot = slip_strides(apex, u, FLAT, HOP)
    assert nxt.shape == (40, 3) and code.shape == (40,) and foot.shape == (40, 2)
    single = jax.jit(slip_stride)
    for i in range(0, 40, 7):
        n1, c1, f1 = single(jnp.asarray(apex[i]), jnp.asarray(u[i]), FLAT, HOP)
        assert int(c1) == code[i]
        np.testing.assert_allclose(nxt[i], np.asarray(n1), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(foot[i], np.asarray(f1), rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="must both be"):
        slip_strides(apex, u[:, :2], FLAT, HOP)


@pytest.mark.slow
def test_bottom_kd_lifts_off_with_the_target_energy():
    # `energy=` replaces kd by eq 12 evaluated at the actual bottom: whatever the ground
    # height (0 here, or 0.1 m lower than a planner would think), the next apex carries the
    # target energy, unless the kd limits clip it.
    apex, u = random_strides(4, 32)
    def energy(a):
        return 0.5 * HOP.m * a[..., 2] ** 2 + HOP.m * HOP.g * a[..., 1]

    target = energy(apex) * np.random.default_rng(5).uniform(0.9, 1.1, 32)
    stride = jax.jit(jax.vmap(lambda a, v, e, t: slip_stride(a, v, t, HOP, energy=e),
                              (0, 0, 0, None)))
    for ground in (0.0, -0.1):
        terrain = make_terrain([(-20.0, 20.0, ground)])
        nxt, code, _ = stride(jnp.asarray(apex), jnp.asarray(u), jnp.asarray(target), terrain)
        nxt, code = np.asarray(nxt), np.asarray(code)
        ok = code == OK
        assert ok.sum() >= 12
        rel = np.abs(energy(nxt) - target) / target
        # Strides that needed kd outside [0.5, 2] kc end elsewhere; most do not.
        hit = rel < 1e-8
        assert hit[ok].mean() > 0.6
    # A NaN target keeps u's kd.
    plain = jax.jit(jax.vmap(slip_stride, (0, 0, None, None)))(
        jnp.asarray(apex), jnp.asarray(u), FLAT, HOP)[0]
    nan = stride(jnp.asarray(apex), jnp.asarray(u), jnp.full(32, jnp.nan), FLAT)[0]
    np.testing.assert_allclose(np.asarray(nan), np.asarray(plain), rtol=1e-12, atol=1e-12)


GRAD_APEX = jnp.array([0.0, 1.3, 1.2])
GRAD_U = jnp.array([0.15, 30.0, 36.0])  # (th_td, kc / MG, kd / MG): all O(1) for one FD step
TIGHT = Tolerances(1e-12, 1e-12)


def _scaled_map(v, tol):
    return slip_apex_map(GRAD_APEX, v * jnp.array([1.0, MG, MG]), 0.0, HOP, tol)[0]


@pytest.mark.slow
def test_apex_map_gradients_match_finite_differences():
    forward = Tolerances(1e-12, 1e-12, diffrax.ForwardMode())
    jac = jax.jit(jax.jacfwd(lambda v: _scaled_map(v, forward)))(GRAD_U)
    f = jax.jit(lambda v: _scaled_map(v, TIGHT))
    step = 1e-5
    fd = np.stack([(f(GRAD_U.at[j].add(step)) - f(GRAD_U.at[j].add(-step))) / (2 * step)
                   for j in range(3)], axis=1)
    np.testing.assert_allclose(jac, fd, rtol=1e-5, atol=1e-6)
    assert np.all(np.abs(jac[:, 0]) > 1e-2)  # th_td moves every apex coordinate


@pytest.mark.slow
def test_reverse_mode_gradients_equal_forward_mode():
    forward = Tolerances(1e-12, 1e-12, diffrax.ForwardMode())
    jac_fwd = jax.jit(jax.jacfwd(lambda v: _scaled_map(v, forward)))(GRAD_U)
    jac_rev = jax.jit(jax.jacrev(lambda v: _scaled_map(v, TIGHT)))(GRAD_U)
    np.testing.assert_allclose(jac_rev, jac_fwd, rtol=1e-8, atol=1e-10)


def test_liftoff_event_does_not_fire_at_touchdown():
    # At touchdown rho = rho0 exactly, so rho - rho0 = 0 already; only an up-crossing is
    # liftoff. Decompressing straight from a touchdown state must run through the stance.
    x_td = jnp.array([HOP.rho0, 0.1, -2.0, -1.0])
    x_lo, code = jax.jit(decompress)(x_td, 20 * MG, HOP)
    assert int(code) == OK
    assert abs(float(x_lo[0]) - HOP.rho0) < 1e-9 and float(x_lo[2]) > 0
    assert float(x_lo[1]) < 0.1 - 0.05  # the leg swept forward: a real stance happened

    # The pitfall itself: without a direction the event fires at t = 0.
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(_field), diffrax.Tsit5(), 0.0, 5.0, None, x_td, args=(20 * MG, HOP),
        stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-8),
        event=diffrax.Event(_liftoff, optx.Newton(1e-12, 1e-12)), throw=False)
    assert float(sol.ts[-1]) < 1e-6


@pytest.mark.parametrize("lower, upper, best", [(5.0, 10.0, 7.3), (-4.0, -1.0, -3.6),
                                                (0.0, 1.0, 0.2), (98.0, 981.0, 500.0)])
def test_golden_section_bracket_not_starting_at_zero(lower, upper, best):
    got = golden_minimise(lambda x: (x - best) ** 2, lower, upper)
    assert abs(float(got) - best) < 1e-6 * max(1.0, abs(best))


@pytest.mark.parametrize("phase, start, kappa, fell", [
    ("compress", (0.0, 2.0), 30.0, False),  # (th_td, downward speed): an ordinary bottom
    ("compress", (0.0, 8.0), 10.0, True),   # a soft leg collapses below COLLAPSED * rho0
    ("decompress", (0.8, 1.2, 0.0, 1.0), 10.0, False),  # bottom state: an ordinary liftoff
    ("decompress", (0.8, 1.4, 0.0, 1.0), 10.0, True),   # the body tips to the foot's level
    ("decompress", (0.9, 1.2, 0.0, 3.0), 10.0, True),   # ... at rho = 0.996, just before
])
def test_a_stance_phase_ends_at_the_first_of_its_two_events(phase, start, kappa, fell):
    """A stance phase ends at its own event (bottom: rho' = 0; liftoff: rho = rho0) or where
    the body falls, whichever comes first. solve_ivp with the two as separate terminal
    events decides which; the phase's code and end state must be that event's."""
    k = kappa * MG
    if phase == "compress":
        th, speed = start
        v = np.array([0.0, -speed])
        x0 = [HOP.rho0, th, -speed * np.cos(th), speed * np.sin(th) / HOP.rho0]
        x_end, code = jax.jit(compress)(th, jnp.asarray(v), k, HOP)
    else:
        x0 = list(start)
        x_end, code = jax.jit(decompress)(jnp.asarray(x0), k, HOP)

    def field(t, x):
        return [x[2], x[3], x[0] * x[3] ** 2 - k / HOP.m * (x[0] - HOP.rho0)
                - HOP.g * np.cos(x[1]), (-2 * x[2] * x[3] + HOP.g * np.sin(x[1])) / x[0]]

    def own(t, x):
        return x[2] if phase == "compress" else x[0] - HOP.rho0

    def fallen(t, x):
        return min(x[0] * np.cos(x[1]), x[0] - COLLAPSED * HOP.rho0)

    own.terminal, own.direction = True, 1
    fallen.terminal, fallen.direction = True, -1
    ref = solve_ivp(field, (0, 5), x0, method="DOP853", rtol=1e-11, atol=1e-12,
                    events=[own, fallen])
    assert (len(ref.t_events[0]), len(ref.t_events[1])) == ((0, 1) if fell else (1, 0))
    assert int(code) == (COLLISION if fell else OK)
    np.testing.assert_allclose(np.asarray(x_end), ref.y[:, -1], rtol=0, atol=1e-6)


def test_golden_section_pitfall_still_present_or_fixed():
    # Documents why `golden_minimise` rescales: if optimistix fixes GoldenSearch, this test
    # still passes (the wrapper is then merely redundant).
    sol = optx.minimise(lambda x, _: (x - 7.3) ** 2, optx.GoldenSearch(rtol=0.0, atol=1e-8),
                        jnp.array(7.5), options=dict(lower=5.0, upper=10.0), throw=False)
    raw = float(sol.value)
    assert abs(raw - 7.3) < 1e-6 or not (5.0 <= raw <= 10.0) or abs(raw - 7.3) > 1e-3


@pytest.mark.slow
def test_stride_failures_on_terrain():
    wall = make_terrain([(0.0, 1.0, 0.0), (1.0, 2.0, 0.45)])
    u = jnp.array([0.0, 30 * MG, 30 * MG])
    _, code, _ = jax.jit(slip_stride)(jnp.array([0.8, 1.4, 1.0]), u, wall, HOP)
    assert int(code) == COLLISION
    hole = make_terrain([(0.0, 1.0, 0.0), (2.0, 3.0, 0.0)])
    _, code, _ = jax.jit(slip_stride)(jnp.array([1.5, 1.3, 0.0]), u, hole, HOP)
    assert int(code) == HOLE
    # A leg planted far behind a fast body is never loaded.
    _, code, _ = jax.jit(slip_stride)(jnp.array([0.0, 1.3, 2.0]),
                                      jnp.array([-1.2, 30 * MG, 30 * MG]), FLAT, HOP)
    assert int(code) == COLLISION


# Strides (apex, (th_td, kc rho0 / (m g), kd / kc)) whose targets the first "bracket" solver
# (one bisection over [-pi/3, pi/3]) missed by 0.016-0.43 m: at their kc the liftoff speed
# rises with th_td up to a maximum before it falls, and the bisection ended left of it, on
# the failed stances of a leg far behind the body.
NON_MONOTONE = [
    ([-0.568, 1.267, 2.3], (-0.033, 28.18, 0.958)),
    ([-0.046, 1.484, 2.17], (-0.112, 52.66, 0.819)),
    ([0.339, 1.292, 1.937], (-0.008, 32.89, 0.785)),
    ([0.209, 1.271, 1.976], (-0.177, 36.22, 1.214)),
    ([-0.041, 1.491, 2.052], (-0.189, 41.24, 1.132)),
]


def reachable_targets(seed, n, extra=()):
    """Apex states reached by random admissible controls (then `extra` strides, as in
    `NON_MONOTONE`), with their start states."""
    apex, u = random_strides(seed, n)
    if extra:
        apex = np.concatenate([apex, [a for a, _ in extra]])
        u = np.concatenate([u, [[th, k * MG, k * MG * r] for _, (th, k, r) in extra]])
    goal, code = apex_map_batch(jnp.asarray(apex), jnp.asarray(u), 0.0, HOP)
    ok = np.asarray(code) == OK
    assert np.all(ok[len(ok) - len(extra):])
    return jnp.asarray(apex[ok]), goal[ok]


def deadbeat_errors(method, seed, n, extra=()):
    apex, goal = reachable_targets(seed, n, extra)
    if method == "gradient":  # the default search, on the program other files share
        u, _ = deadbeats(apex, goal, np.zeros(len(apex)))
    else:
        search = DeadbeatSearch(method=method)
        u, _ = jax.jit(jax.vmap(lambda a, g: deadbeat_slip(a, g, 0.0, HOP, search)))(apex, goal)
    nxt, code = apex_map_batch(apex, u, 0.0, HOP)
    err = np.abs(np.asarray(nxt - goal))
    pos = np.max(err[:, :2], axis=1)
    vel = err[:, 2]
    within = (np.asarray(code) == OK) & (pos < 1e-3) & (vel < 1e-3)
    return within, pos, vel, np.asarray(u)


# The bracket solver is an alternative no controller or plan uses (`deadbeat_slip`'s default
# is "gradient"): its check, a minute of compilation of its own, runs with the heavy tests.
@pytest.mark.slow
@pytest.mark.parametrize("method", [pytest.param("bracket", marks=pytest.mark.heavy),
                                    "gradient"])
def test_deadbeat_recovers_targets_small(method):
    # "bracket" also gets the targets on which a single bisection ended on the wrong branch.
    extra = NON_MONOTONE if method == "bracket" else ()
    within, *_ = deadbeat_errors(method, seed=10, n=6, extra=extra)
    assert len(within) >= 3 + len(extra) and np.all(within)


@pytest.mark.slow
def test_gradient_solver_never_tries_a_non_finite_point(monkeypatch):
    # A start whose stride fails has a constant residual, a zero Jacobian and a singular
    # normal matrix. The step used to be NaN; every later trial then ran a NaN stance to
    # diffrax's MAX_STEPS (~0.13 s each, 16 times), stalling a whole vmapped batch. The
    # case: a backward-moving apex over reference's goal block asked to reverse onto a
    # goal whose foothold lies behind the 0.35 m block's edge, from two starts: one whose
    # stride fails (`th_td` = 0) and one whose stride completes (`th_td` = -0.6).
    from jaxhop._core.terrain import builtin_terrain
    from jaxhop._models.slip import kernels as D

    seen = []
    residual = D._residual

    def recording(p, *args, **kwargs):
        jax.debug.callback(lambda q: seen.append(np.asarray(q)), p)
        return residual(p, *args, **kwargs)

    monkeypatch.setattr(D, "_residual", recording)
    apex = jnp.array([9.085155396247906, 1.2430493059720336, -1.9875529588897811])
    goal = jnp.array([8.725000000000001, 1.1175037200259623, 1.5992968749999998])
    terrain = builtin_terrain("reference")
    starts = jnp.array([[0.0, 0.5], [-0.6, 0.5]])
    th, kc, c2 = jax.jit(lambda a, g, t, p: D.deadbeat_gradient(
        a, g, 0.0, HOP, D.SEARCH_TOL, terrain=t, starts=p))(apex, goal, terrain, starts)
    jax.effects_barrier()
    seen = np.stack(seen).reshape(-1, 2)
    assert len(seen) > 20
    assert np.all(np.isfinite(seen))
    assert np.all(np.isfinite([float(th), float(kc), float(c2)]))
    # The failing start was priced, and its stride failed.
    assert np.any(np.all(seen == np.asarray(starts[0]), axis=1))
    r = residual(starts[0], apex, goal, 0.0, HOP, D.SEARCH_TOL, terrain)
    assert np.all(np.asarray(r) == 1e3)
    # A non-finite point itself counts as a failed stride, not as NaN.
    r = residual(jnp.array([jnp.nan, 0.5]), apex, goal, 0.0, HOP, D.SEARCH_TOL)
    assert np.all(np.asarray(r) == 1e3)


@pytest.mark.heavy
@pytest.mark.slow
@pytest.mark.parametrize("method", ["bracket", "gradient"])
def test_deadbeat_recovers_reachable_targets(method):
    within, pos, vel, u = deadbeat_errors(method, seed=11, n=640)
    assert len(within) >= 500
    print(f"\n{method}: n={len(within)} within={within.mean():.4f} "
          f"pos median={np.median(pos):.2e} p99={np.quantile(pos, 0.99):.2e} "
          f"vel median={np.median(vel):.2e} p99={np.quantile(vel, 0.99):.2e}")
    assert within.mean() >= 0.99
    kappa = u[:, 1] / MG
    assert np.all((kappa >= KAPPA_LO - 1e-9) & (kappa <= KAPPA_HI + 1e-9))
    ratio = u[:, 2] / u[:, 1]
    assert np.all((ratio >= RATIO_LO - 1e-9) & (ratio <= RATIO_HI + 1e-9))
