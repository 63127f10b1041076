"""MPPC planning: per-pair minimum time, DP optimality, the receding-horizon loop."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop.mppc import (
    MPPC,
    Jump,
    Robot,
    Settings,
    _jump,
    _plan,
    check_jump,
    course_from_dict,
    load_course,
    min_time_jump,
    random_course,
    run_course,
)

ROBOT = Robot()


def _brute_min_times(x0, z0, x1, z1, arrays, mv, n=2001):
    # Dense scan of the takeoff angle (0.01 deg steps); each angle fixes the jump (eqs
    # 6-9) and the exact verification decides feasibility.
    fx, fz = ROBOT.foot_from_hip
    xh, zh = _jump._queries(ROBOT, *arrays, mv)
    tans = jnp.tan(jnp.linspace(ROBOT.theta_min, ROBOT.theta_max, n))

    def one(a, b, c, d):
        ok, t, _, _ = jax.vmap(
            lambda T: _jump._verify(ROBOT, a, b, c - fx - a, d - fz - b, xh, zh, arrays, T)
        )(tans)
        return jnp.min(jnp.where(ok, t, jnp.inf))

    return np.asarray(jax.jit(jax.vmap(one))(x0, z0, x1, z1))


def test_min_time_jump_against_angle_scan():
    course = load_course("mppc-sim-1")
    env = course.environment
    arrays = tuple(jnp.asarray(a) for a in (env.front, env.back, env.height))
    rng = np.random.default_rng(0)
    x0 = rng.uniform(0.5, 6.0, 600)
    x1 = x0 + rng.uniform(0.05, 1.1, 600)
    z0, z1 = env.surface(x0), env.surface(x1)
    mine = jax.jit(jax.vmap(lambda a, b, c, d: min_time_jump(ROBOT, (a, b), (c, d), arrays, 0.05)))
    ok, t, _, _ = (np.asarray(q) for q in mine(x0, z0, x1, z1))
    brute = _brute_min_times(x0, z0, x1, z1, arrays, 0.05)
    found = np.isfinite(brute)
    assert found.sum() > 250
    # Never feasible where the scan finds nothing; almost never the other way round.
    assert not np.any(ok & ~found)
    assert np.sum(found & ~ok) <= 0.01 * found.sum()
    # Minimal to the scan's resolution almost always; a rare Newton overshoot costs
    # at most a few milliseconds.
    both = ok & found
    excess = t[both] - brute[both]
    assert np.all(excess <= 0.02)
    assert np.quantile(excess, 0.98) < 2e-4


def test_min_time_is_minimal_by_checker():
    # Just below the returned angle (same landing point), the independent checker
    # finds a violated constraint: the returned jump is the fastest.
    course = course_from_dict({"start": 0, "goal": 3, "obstacles": [
        {"position": 0.5, "width": 0.1, "height": 0.2}]})
    env = course.environment
    arrays = tuple(jnp.asarray(a) for a in (env.front, env.back, env.height))
    fx, fz = ROBOT.foot_from_hip
    xs = np.arange(0.3, 0.9, 0.01)
    legal = _plan.landing_ok(ROBOT, env, course.margin_h, xs)
    tested = 0
    for x1 in xs[legal]:
        z1 = float(env.surface(x1))
        ok, t, v, th = (float(q) for q in min_time_jump(ROBOT, (0.0, 0.0), (x1, z1),
                                                        arrays, 0.05))
        if not ok or th < ROBOT.theta_min + 1e-3:
            continue
        tested += 1
        assert check_jump(ROBOT, course, env, Jump(0, 0, v, th, t, x1, z1)) == []
        th2 = th - math.radians(0.05)
        xp, zp = x1 - fx, z1 - fz
        t2 = math.sqrt(2 * (xp * math.tan(th2) - zp) / ROBOT.g)
        v2 = (xp - ROBOT.r_takeoff * math.cos(th2)) / (t2 * math.cos(th2))
        assert t2 < t
        assert check_jump(ROBOT, course, env, Jump(0, 0, v2, th2, t2, x1, z1)) != []
    assert tested >= 3


def _tiny_window(course, grid):
    planner = MPPC(settings=Settings(grid=grid, dead_ends="never"))
    data = _plan.EnvData(planner, course, course.environment)
    size, band, ksize, local = planner._sizes(course)
    sel = data.legal & (data.x > course.start)
    x = np.concatenate([[course.start], data.x[sel]])
    z = np.concatenate([[0.0], data.z[sel]])
    m = len(x)
    x = np.concatenate([x, x[-1] + 10 + np.arange(size - m)])
    z = np.concatenate([z, np.zeros(size - m)])
    valid = np.arange(size) < m
    env = course.environment
    obs = planner._pad_obstacles(env.front, env.back, env.height, ksize)
    cost, _, _, best = _plan._horizon_solve(ROBOT, x, z, valid, *obs, course.margin_v, band,
                                            local)
    cost = np.asarray(cost)
    return m, np.isfinite(cost), cost, np.asarray(best)


@pytest.mark.parametrize("seed", [0, 1])
def test_dp_against_brute_force(seed):
    rng = np.random.default_rng(seed)
    h = float(rng.uniform(0.1, 0.2))
    a = float(rng.uniform(0.5, 0.8))
    course = course_from_dict({
        "start": 0.0, "goal": 1.6,
        "obstacles": [{"position": a + 0.05, "width": 0.1, "height": h}],
        "restricted": [{"position": 1.2, "width": 0.1}],
    })
    m, ok, t, best = _tiny_window(course, 0.1)
    assert m <= 30
    cost = np.full((m, m), np.inf)
    for i in range(m):
        for w in range(ok.shape[1]):
            if i + 1 + w < m and ok[i, w]:
                cost[i, i + 1 + w] = t[i, w]
    target = m - 1
    for n in range(1, 5):
        brute = math.inf
        for mid in itertools.combinations(range(1, target), n - 1):
            path = (0, *mid, target)
            brute = min(brute, sum(cost[p, q] for p, q in zip(path, path[1:])))
        assert best[n - 1, target] == pytest.approx(brute, abs=1e-12) or (
            math.isinf(brute) and math.isinf(best[n - 1, target]))
        if math.isfinite(brute):  # the backtracked path has n jumps and that cost
            nodes = _plan._backtrack(best, np.where(ok, t, np.inf), target, n)
            assert nodes[0] == 0 and nodes[-1] == target and len(nodes) == n + 1
            total = sum(cost[p, q] for p, q in zip(nodes, nodes[1:]))
            assert total == pytest.approx(brute)


@pytest.mark.slow
def test_horizon_rule_smallest_n():
    course = load_course("mppc-sim-1")
    planner = MPPC()
    data = _plan.EnvData(planner, course, course.environment)
    plan = planner.replan(course, data, 0.0, 0.0)
    # 2 m of floor and blocks: the original's rule gives N from ceil(2 / 0.784) = 3.
    assert plan.n_jumps == 3 and len(plan.jumps) == 3
    # x_t = 2.0 is the back edge of the block at 1.9: the horizon ends at the last legal
    # landing point before it, on the block top, Mh before the edge.
    assert plan.target == pytest.approx(2.0 - 0.03)
    assert plan.nodes[0] == 0.0 and plan.nodes[-1] == plan.target


def test_sim1_end_to_end_and_no_recompilation():
    course = load_course("mppc-sim-1")
    planner = MPPC()
    result = run_course(course, planner)  # includes its own warm-up
    before = dict(_plan.TRACES)
    result = run_course(course, planner)
    assert _plan.TRACES == before  # same padded shapes: nothing traced again
    out = result.to_json()
    assert out["finished"] and out["violations"] == 0
    assert out["jumps"] <= 12
    assert out["flight_time"] <= 6.0914 * 1.01  # the original's total, +1 %
    assert out["executed"][-1]["x1"] == pytest.approx(7.2)
    for a, b in zip(out["executed"], out["executed"][1:]):
        assert b["xs"] == pytest.approx(a["x1"], abs=1e-9)


@pytest.mark.slow
def test_random_course_finishes_when_reachable():
    course = random_course(7)
    planner = MPPC()
    result = run_course(course, planner)
    env = course.environment
    data = _plan.EnvData(planner, course, env)
    assert result.finished == bool(data.reach[0])
    assert not result.violations


@pytest.mark.slow
def test_all_courses_finish():
    planner = MPPC()
    for name in ["mppc-hw-dynamic-1", "mppc-hw-two-rounds", "mppc-sim-2"]:
        for course in (load_course(name), load_course(name).final()):
            out = run_course(course, planner).to_json()
            assert out["finished"] and out["violations"] == 0, (name, out["failure"])
