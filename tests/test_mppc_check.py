"""The independent checker flags hand-made violating jumps of every kind."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop.mppc import Jump, Robot, check_jump, course_from_dict, min_time_jump
from jaxhop.mppc._check import KINDS, _paths

ROBOT = Robot()
MV = 0.05


def _course(obstacles=(), restricted=()):
    return course_from_dict({
        "start": 0.0, "goal": 3.0,
        "margins": {"horizontal": 0.03, "vertical": MV},
        "obstacles": [{"position": (a + b) / 2, "width": b - a, "height": h}
                      for a, b, h in obstacles],
        "restricted": [{"position": (a + b) / 2, "width": b - a} for a, b in restricted],
    })


def _flat_jump(x1=0.6, theta_deg=65.0):
    # An exact ballistic jump from (0, 0) to (x1, 0) at the given angle.
    th = math.radians(theta_deg)
    fx, fz = ROBOT.foot_from_hip
    xp, zp = x1 - fx, -fz
    t = math.sqrt(2 * (xp * math.tan(th) - zp) / ROBOT.g)
    v = (xp - ROBOT.r_takeoff * math.cos(th)) / (t * math.cos(th))
    return Jump(0.0, 0.0, v, th, t, x1, 0.0)


def _kinds(course, jump):
    return {k for k, _ in check_jump(ROBOT, course, course.environment, jump)}


def _height_at(px, pz, x):
    return float(np.interp(x, px, pz))


def test_clean_jump_passes():
    c = _course()
    assert _kinds(c, _flat_jump()) == set()


def test_bounds():
    j = _flat_jump()
    assert "bounds" in _kinds(_course(), Jump(0, 0, 3.0, j.theta, j.t, 0, 0))
    assert "bounds" in _kinds(_course(), Jump(0, 0, j.v, math.radians(60), j.t, 0, 0))
    assert "bounds" in _kinds(_course(), Jump(0, 0, j.v, j.theta, 0.1, 0, 0))


def test_takeoff_and_landing_height():
    j = _flat_jump()
    c = _course(obstacles=[(-0.2, 0.1, 0.1)])
    assert "takeoff_height" in _kinds(c, j)
    assert "takeoff_height" not in {
        k for k, _ in check_jump(ROBOT, c, c.environment, j, check_takeoff=False)}
    c = _course(obstacles=[(0.5, 0.9, 0.1)])
    assert "landing_height" in _kinds(c, j)


def test_edge_margin():
    j = _flat_jump(0.6)
    assert _kinds(_course(obstacles=[(0.61, 0.8, 0.1)]), j) == {"edge_margin"}


def test_restricted():
    j = _flat_jump(0.6)
    assert _kinds(_course(restricted=[(0.5, 0.7)]), j) == {"restricted"}
    # The boundary itself is allowed (eq 15 is <= 0).
    assert _kinds(_course(restricted=[(0.6, 0.7)]), j) == set()


def test_foot_clearance():
    j = _flat_jump(0.7, 75)
    (fx, fz), _ = _paths(ROBOT, j.xs, j.zs, j.v, j.theta, j.t)
    a = 0.3
    h = _height_at(fx, fz, a) - 0.02  # passes the front only 2 cm above the top
    kinds = _kinds(_course(obstacles=[(a, a + 0.02, h)]), j)
    assert "foot_clearance" in kinds and "collision" not in kinds


def test_knee_clearance():
    j = _flat_jump(0.75, 80)
    (fx, fz), (kx, kz) = _paths(ROBOT, j.xs, j.zs, j.v, j.theta, j.t)
    # A thin block whose back the knee passes 2 cm above the top while the foot passes
    # its front with room to spare.
    for b in np.linspace(0.2, 0.6, 81):
        a = b - 0.02
        h = _height_at(kx, kz, b) - 0.02
        if _height_at(fx, fz, a) > h + MV + 0.01 and kx[0] < a:
            break
    else:
        pytest.fail("no suitable block found")
    kinds = _kinds(_course(obstacles=[(a, b, h)]), j)
    assert "knee_clearance" in kinds and "foot_clearance" not in kinds


def test_collision():
    j = _flat_jump(0.6)
    kinds = _kinds(_course(obstacles=[(0.3, 0.35, 2.0)]), j)
    assert {"collision", "foot_clearance"} <= kinds
    # The knee at touchdown inside a block just behind the landing point.
    kinds = _kinds(_course(obstacles=[(0.4, 0.56, 0.3)]), j)
    assert "collision" in kinds


def test_every_kind_is_covered():
    # The tests above exercise every kind the checker knows.
    assert set(KINDS) == {"bounds", "takeoff_height", "landing_height", "edge_margin",
                          "restricted", "foot_clearance", "knee_clearance", "collision"}


def test_planner_jumps_pass_checker():
    # Whatever the planner's pair search calls feasible, the checker accepts.
    c = _course(obstacles=[(0.5, 0.7, 0.2), (1.2, 1.3, 0.3)])
    env = c.environment
    rng = np.random.default_rng(1)
    arrays = [jnp.asarray(a) for a in (env.front, env.back, env.height)]
    n_ok = 0
    pair = jax.jit(lambda a, b, c_, d: min_time_jump(ROBOT, (a, b), (c_, d), arrays, MV))
    for _ in range(150):
        x0 = float(rng.uniform(0.0, 1.6))
        x1 = x0 + float(rng.uniform(0.1, 1.0))
        z0, z1 = float(env.surface(x0)), float(env.surface(x1))
        ok, t, v, th = pair(x0, z0, x1, z1)
        if not ok:
            continue
        n_ok += 1
        kinds = _kinds(c, Jump(x0, z0, float(v), float(th), float(t), x1, z1))
        # landing legality (margins, knee at touchdown) is the caller's business
        assert not kinds & {"bounds", "takeoff_height", "landing_height", "foot_clearance",
                            "knee_clearance"}, (x0, x1, kinds)
        if "collision" in kinds:  # only the knee at touchdown may remain
            knee_x = x1 + ROBOT.knee_from_foot[0]
            assert np.any((knee_x > env.front) & (knee_x < env.back))
    assert n_ok > 30
