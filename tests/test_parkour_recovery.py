"""The adaptive controller on a changing parkour course (docs/parkour_reactive.md,
"Snapshots under the runs"): a snapshot drops an obstacle in front of the runs; the
paper's controller loses the runs the updated plan no longer holds, recovery and holding
carry them to the goal."""

import numpy as np
import pytest

from jaxhop._core.result import Result
from jaxhop._planning.policies import PairGrid
from jaxhop.mppc import course_from_dict
from jaxhop.parkour import leg_hopper, leg_templates
from jaxhop.parkour._run import (
    course_plans,
    goal_tolerance,
    hold_tables,
    initial_states,
    pad_plans,
    run_reactive,
)

# A clear 1 m floor; from stride 2 on a 0.1 m block stands at 0.45-0.55 m, where the runs
# are about to land.
DROP = {
    "name": "drop", "start": 0.0, "goal": 1.0,
    "margins": {"horizontal": 0.03, "vertical": 0.05},
    "obstacles": [], "restricted": [],
    "snapshots": [{"from_jump": 2, "restricted": [],
                   "obstacles": [{"position": 0.5, "width": 0.1, "height": 0.1}]}],
}
OBSTACLE = (0.45, 0.55)


@pytest.fixture(scope="module")
def drop_runs():
    course = course_from_dict(DROP)
    hop = leg_hopper()
    cps = course_plans(course, hop, leg_templates(hop), grid=PairGrid(4, 4))
    padded = pad_plans(cps)
    apex0, _ = initial_states(cps, padded, 16, 0, hop)
    runs = {c: run_reactive(cps, padded, apex0, hopper=hop, controller=c)
            for c in ("paper", "adaptive")}
    return course, hop, cps, apex0, runs


@pytest.mark.slow
def test_recovery_carries_runs_past_a_dropped_obstacle(drop_runs):
    course, hop, cps, apex0, runs = drop_runs
    paper, adaptive = runs["paper"], runs["adaptive"]
    # The scenario is real: the paper's controller loses some runs at the snapshot.
    lost = paper["code"] == Result.OUTSIDE_DOMAIN
    assert lost.sum() >= 4 and np.all(paper["steps"][lost] == DROP["snapshots"][0]["from_jump"])
    assert np.all((paper["code"] == Result.SUCCESS) | lost)
    # The adaptive controller finishes every run, recovering exactly the lost ones.
    assert np.all(adaptive["code"] == Result.SUCCESS)
    assert np.all((adaptive["recoveries"] > 0) == lost)
    # Checked against the course itself, not the plan: the last apex is within the
    # tolerance of the goal apex over the floor, and no touchdown is on the obstacle or in
    # a margin band beside it, nor in front of the start or past the goal's floor.
    tol = goal_tolerance(hop)
    goal = np.array([DROP["goal"], hop.rho0 * 1.3, 0.0])
    mh = DROP["margins"]["horizontal"]
    for i in range(len(apex0)):
        n = int(adaptive["steps"][i])
        assert np.all(np.abs(adaptive["apexes"][i, n] - goal) <= tol + 1e-12)
        feet = adaptive["footholds"][i, :n]
        assert np.all(feet[:, 1] == 0.0)
        after = np.arange(n) >= DROP["snapshots"][0]["from_jump"]
        near = (feet[:, 0] > OBSTACLE[0] - mh) & (feet[:, 0] < OBSTACLE[1] + mh)
        assert not np.any(near & after)
    # Without the snapshot both controllers give the same runs (nothing to recover).
    static = type(cps)(**{**cps.__dict__, "starts": [0], "maps": cps.maps[:1],
                          "plans": cps.plans[:1]})
    a = run_reactive(static, pad_plans(static), apex0, hopper=hop, controller="paper")
    b = run_reactive(static, pad_plans(static), apex0, hopper=hop, controller="adaptive")
    assert np.all(a["code"] == Result.SUCCESS)
    assert np.array_equal(a["apexes"], b["apexes"], equal_nan=True)
    assert np.array_equal(a["policies"], b["policies"])


@pytest.mark.slow
def test_hold_tables_pick_the_best_undeployed_policy(drop_runs):
    _, _, cps, _, _ = drop_runs
    big = np.iinfo(np.int32).max
    for cp in cps.plans:
        plan = cp.plan
        hold_pos, best_inst = hold_tables(plan)
        deployed = set(plan.situated[plan.order].tolist())
        ranked = []
        for s in range(plan.n_situated):
            mine = np.nonzero(plan.situated == s)[0]
            if s in deployed or mine.size == 0:
                assert hold_pos[s] == big
                continue
            # One policy at a time: the most robust, then the safest, then the lowest id.
            best = min(mine, key=lambda a: (-plan.robustness[a], -plan.safety[a], a))
            assert best_inst[s] == best
            ranked.append((-plan.robustness[best], -plan.safety[best], best, s))
        assert [s for *_, s in sorted(ranked)] == list(np.argsort(hold_pos)[:len(ranked)])
        held = hold_pos < big
        # Deployed situated policies keep the plan's own first deployed policy.
        assert np.array_equal(best_inst[~held], plan.best_per_situated()[1][~held])
