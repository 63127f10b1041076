"""MPPC under disturbances (wind, room) and the continuous polish, against closed forms."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop.mppc import (
    MPPC,
    Jump,
    Observer,
    Robot,
    Settings,
    _plan,
    check_jump,
    course_from_dict,
    load_course,
    min_time_jump,
    random_course,
)
from jaxhop.parkour._mppc_noise import leg_disturbance, run_mppc_noisy

ROBOT = Robot()
CLEARANCE = {"foot_clearance", "knee_clearance", "collision"}


def _course(obstacles=(), restricted=()):
    return course_from_dict({
        "start": 0.0, "goal": 3.0,
        "margins": {"horizontal": 0.03, "vertical": 0.05},
        "obstacles": [{"position": (a + b) / 2, "width": b - a, "height": h}
                      for a, b, h in obstacles],
        "restricted": [{"position": (a + b) / 2, "width": b - a} for a, b in restricted],
    })


def _landing(x0, z0, v, th, t, wind):
    # Closed-form ballistic landing of the contact point: the hip starts at the contact
    # point plus rt (cos, sin) theta, flies with (v cos, v sin) theta, gravity and the
    # horizontal acceleration; the foot hangs at -rf (cos, sin) theta_f from the hip.
    hx = x0 + ROBOT.r_takeoff * math.cos(th) + v * math.cos(th) * t + 0.5 * wind * t**2
    hz = z0 + ROBOT.r_takeoff * math.sin(th) + v * math.sin(th) * t - 0.5 * ROBOT.g * t**2
    return (hx - ROBOT.r_flight * math.cos(ROBOT.theta_flight),
            hz - ROBOT.r_flight * math.sin(ROBOT.theta_flight))


def test_wind_estimate_recovers_the_acceleration_from_short_landings():
    a = -0.37
    obs = Observer()
    assert obs.wind == 0.0 and obs.room == pytest.approx(obs.room_first)
    # Three flights of known time, planned for no wind, then for a wrong wind: each lands
    # a t^2 / 2 (less the wind planned for) away from its planned point.
    for t, used in ((0.55, 0.0), (0.41, 0.0), (0.62, -0.1)):
        x_plan = 1.234
        obs.update(x_plan, x_plan + 0.5 * (a - used) * t**2, t, used)
    assert obs.wind == pytest.approx(a, abs=1e-12)
    assert np.max(np.abs(obs.residuals())) < 1e-12
    assert obs.n == 3 and obs.room == pytest.approx(0.0, abs=1e-12)


def test_wind_estimate_is_not_used_when_it_is_noise():
    # Landings scattered +-1 cm around the plan, no wind: the mean does not stand out.
    rng = np.random.default_rng(3)
    obs = Observer()
    errors = rng.uniform(-0.01, 0.01, 8)
    for e in errors:
        obs.update(2.0, 2.0 + e, 0.5, 0.0)
    assert obs.wind == 0.0
    # The room: (n + 1) / n times the largest error seen.
    assert obs.room == pytest.approx(min(9 / 8 * np.max(np.abs(errors)), obs.room_max))
    with pytest.raises(ValueError):
        obs.update(2.0, 2.0, 0.0, 0.0)


@pytest.mark.parametrize("wind", [-0.1645, 0.25])
def test_jump_planned_in_wind_lands_on_the_planned_point(wind):
    c = _course(obstacles=[(0.5, 0.7, 0.2)])
    env = c.environment
    arrays = [jnp.asarray(q) for q in (env.front, env.back, env.height)]
    pair = jax.jit(lambda x0, x1, z1, a: min_time_jump(ROBOT, (x0, 0.0), (x1, z1), arrays,
                                                       0.05, a))
    n_ok = 0
    for x0, x1 in ((0.0, 0.6), (0.1, 0.62), (0.2, 0.85), (0.0, 0.4)):
        z1 = float(env.surface(x1))
        ok, t, v, th = (float(q) for q in pair(x0, x1, z1, wind))
        if not ok:
            continue
        n_ok += 1
        lx, lz = _landing(x0, 0.0, v, th, t, wind)
        assert lx == pytest.approx(x1, abs=1e-9) and lz == pytest.approx(z1, abs=1e-9)
        # In still air the same jump lands wind t^2 / 2 away.
        sx, _ = _landing(x0, 0.0, v, th, t, 0.0)
        assert sx - x1 == pytest.approx(-0.5 * wind * t**2, abs=1e-9)
        jump = Jump(x0, 0.0, v, th, t, x1, z1)
        kinds = {k for k, _ in check_jump(ROBOT, c, env, jump, wind=wind)}
        assert not kinds & (CLEARANCE | {"bounds", "landing_height"}), kinds
        # The checker flies the path it is told: without the wind it lands elsewhere.
        still = {k for k, _ in check_jump(ROBOT, c, env, jump)}
        assert still != kinds or lx != pytest.approx(sx, abs=1e-6)
    assert n_ok >= 3


@pytest.mark.slow
def test_still_air_path_and_zero_wind_agree():
    env = load_course("mppc-sim-1").environment
    arrays = [jnp.asarray(q) for q in (env.front, env.back, env.height)]
    rng = np.random.default_rng(0)
    x0 = rng.uniform(0.5, 6.0, 200)
    x1 = x0 + rng.uniform(0.1, 1.0, 200)
    z0, z1 = env.surface(x0), env.surface(x1)

    def batch(wind):
        f = jax.vmap(lambda a, b, c, d: min_time_jump(ROBOT, (a, b), (c, d), arrays, 0.05, wind))
        return [np.asarray(q) for q in jax.jit(f)(x0, z0, x1, z1)]

    ok0, t0, _, _ = batch(None)
    ok1, t1, _, _ = batch(0.0)
    assert ok0.sum() > 50
    np.testing.assert_array_equal(ok0, ok1)
    np.testing.assert_allclose(t1[ok0], t0[ok0], atol=1e-12)


def test_room_keeps_a_shifted_flight_clear():
    # A jump planned with room r, flown from takeoff points up to r off (the same speed
    # and angle), still keeps every clearance by the independent checker.
    room = 0.01
    c = _course(obstacles=[(0.45, 0.65, 0.15), (1.2, 1.3, 0.25)])
    env = c.environment
    arrays = [jnp.asarray(q) for q in (env.front, env.back, env.height)]
    pair = jax.jit(lambda x0, x1, z0, z1: min_time_jump(ROBOT, (x0, z0), (x1, z1), arrays,
                                                        0.05, room=room))
    plain = jax.jit(lambda x0, x1, z0, z1: min_time_jump(ROBOT, (x0, z0), (x1, z1), arrays, 0.05))
    tested = flagged = 0
    for x0, x1 in ((0.0, 0.6), (0.1, 0.55), (0.61, 1.0), (0.9, 1.25), (0.3, 0.8)):
        z0, z1 = float(env.surface(x0)), float(env.surface(x1))
        # Landing legality with the room (margins, knee at touchdown) is the caller's.
        assert _plan.landing_ok(ROBOT, env, c.margin_h, [x1], room)[0]
        for solve, shifts in ((pair, (-room, -room / 2, room / 2, room)), (plain, (-room, room))):
            ok, t, v, th = (float(q) for q in solve(x0, x1, z0, z1))
            if not ok:
                continue
            for d in shifts:
                jump = Jump(x0 + d, z0, v, th, t, x1 + d, z1)
                kinds = {k for k, _ in check_jump(ROBOT, c, env, jump, check_takeoff=False)}
                if solve is pair:
                    tested += 1
                    assert not kinds & CLEARANCE, (x0, x1, d, kinds)
                else:
                    flagged += bool(kinds & CLEARANCE)
    assert tested >= 8
    assert flagged >= 1  # without room, the tight minimum-time jump does not keep it


def test_round_room():
    s = Settings(room_max=0.03)
    assert s.round_room(0.0) == 0.0 and s.round_room(0.001) == pytest.approx(0.0025)
    assert s.round_room(0.0025) == pytest.approx(0.0025)
    assert s.round_room(0.5) == pytest.approx(0.03)
    assert Settings().round_room(0.01) == 0.0


# Each course compiles the polish for its own blocks and wind; two run in CI, the third with
# the heavy tests.
@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param("mppc-sim-1", marks=pytest.mark.heavy),
                                  "random-3", "mppc-hw-dynamic-2"])
def test_polish_never_slower_and_passes_the_checker(name):
    course = random_course(3) if name == "random-3" else load_course(name)
    grid, polished = MPPC(), MPPC(settings=Settings(polish=True))
    env = course.environment
    data_g = _plan.EnvData(grid, course, env)
    data_p = _plan.EnvData(polished, course, env)
    starts = [x for x in data_g.x[data_g.legal] if x < course.goal - 0.5][::9][:8]
    helped = 0
    for x in starts:
        z = float(env.surface(x))
        a, b = grid.replan(course, data_g, x, z), polished.replan(course, data_p, x, z)
        if a is None:
            assert b is None
            continue
        ta, tb = sum(j.t for j in a.jumps), sum(j.t for j in b.jumps)
        assert tb <= ta
        helped += tb < ta - 1e-9
        assert b.nodes[0] == a.nodes[0] and b.nodes[-1] == a.nodes[-1]
        assert len(b.jumps) == len(a.jumps)
        for j in b.jumps:
            assert check_jump(ROBOT, course, env, j) == [], (x, j)
    assert helped >= 1


@pytest.mark.slow
def test_disturbed_run_under_wind_finishes_a_shipped_course():
    course = load_course("mppc-hw-static")
    out = run_mppc_noisy(course, "wind", seed=0)
    assert out["success"] and out["finished"] and out["violations"] == 0
    _, wind, _ = leg_disturbance("wind", ROBOT)
    assert out["wind_estimate"] == pytest.approx(wind, rel=1e-9)
    assert abs(out["executed"][-1]["x1"] - course.goal) <= 0.05 * ROBOT.r_takeoff
