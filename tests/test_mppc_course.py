"""MPPC courses: the shipped data, the loader's validation, the robot offsets, the CLI."""

import json
import math

import numpy as np
import pytest

from jaxhop import InputError
from jaxhop._cli.main import main
from jaxhop.mppc import (
    Robot,
    course_from_dict,
    foot_offset,
    knee_offset,
    list_courses,
    load_course,
    random_course,
    reference_results,
)

SHIPPED = [
    "mppc-hw-disturbances", "mppc-hw-dynamic-1", "mppc-hw-dynamic-2", "mppc-hw-dynamic-3",
    "mppc-hw-dynamic-4", "mppc-hw-static", "mppc-hw-two-rounds", "mppc-sim-1", "mppc-sim-2",
]

GOOD = {
    "name": "tiny", "start": 0.0, "goal": 2.0,
    "margins": {"horizontal": 0.03, "vertical": 0.05},
    "obstacles": [{"position": 1.0, "width": 0.2, "height": 0.2}],
    "restricted": [{"position": 1.5, "width": 0.2}],
}


def test_shipped_courses_load():
    assert list_courses() == SHIPPED
    for name in SHIPPED:
        c = load_course(name)
        assert c.name == name and c.start == 0.0
        assert c.goal == (14.4 if name == "mppc-hw-two-rounds" else 7.2)
        assert (c.margin_h, c.margin_v) == (0.03, 0.05)
        assert np.all(c.environment.back > c.environment.front)
    names = {r["course"] for r in reference_results()["results"]}
    assert names == set(SHIPPED)


def test_sim1_matches_spec_example():
    env = load_course("mppc-sim-1").environment
    np.testing.assert_allclose((env.front + env.back) / 2, [1.3, 1.9, 2.8, 4.8, 6.5])
    np.testing.assert_allclose(env.height, [0.2, 0.2, 0.2, 0.2, 0.3])
    np.testing.assert_allclose(env.back - env.front, [0.2, 0.2, 0.1, 0.2, 0.2])
    np.testing.assert_allclose((env.restricted_lo + env.restricted_hi) / 2, [1.6, 4.5, 5.1])


def test_snapshots_in_force():
    c = load_course("mppc-hw-dynamic-1")
    first = c.snapshots[0][0]
    assert c.environment_at(first - 1) is c.environment
    assert c.environment_at(first) is c.snapshots[0][1]
    assert c.environment_at(10_000) is c.snapshots[-1][1]
    final = c.final()
    assert final.snapshots == () and final.environment is c.snapshots[-1][1]


def test_surface():
    c = course_from_dict(GOOD)
    np.testing.assert_allclose(c.environment.surface([0.5, 0.95, 1.05, 1.2]), [0, 0.2, 0.2, 0])


def test_robot_offsets_match_spec():
    r = Robot()
    np.testing.assert_allclose(r.foot_from_hip, (0.0118586, -0.1695859), atol=1e-7)
    np.testing.assert_allclose(r.knee_from_foot, (-0.1292203, 0.0761716), atol=1e-6)
    th = math.radians(70)
    cxe, cze = foot_offset(r, th)
    cxk, czk = knee_offset(r, th)
    # eqs 1-4
    assert cxe == pytest.approx(0.19 * math.cos(th) - 0.17 * math.cos(math.radians(94)))
    assert cze == pytest.approx(0.19 * math.sin(th) - 0.17 * math.sin(math.radians(94)))
    assert cxk == pytest.approx(cxe - 0.15 * math.cos(math.radians(30.518)))
    assert czk == pytest.approx(cze + 0.15 * math.sin(math.radians(30.518)))


def _bad(**changes):
    data = json.loads(json.dumps(GOOD))
    for key, value in changes.items():
        if value is None:
            data.pop(key)
        else:
            data[key] = value
    return data


@pytest.mark.parametrize(
    "data, field",
    [
        (_bad(goal=None), "goal"),
        (_bad(goal="far"), "goal"),
        (_bad(goal=-1.0), "goal"),
        (_bad(start=float("nan")), "start"),
        (_bad(obstacles={"position": 1}), "obstacles"),
        (_bad(obstacles=[{"position": 1.0, "width": -0.2, "height": 0.2}]), "width"),
        (_bad(obstacles=[{"position": 1.0, "width": 0.2}]), "height"),
        (_bad(obstacles=[{"position": 1.0, "width": 0.2, "height": 0.2, "depth": 1}]), "depth"),
        (_bad(obstacles=[{"position": 1.0, "width": 0.2, "height": 0.2},
                         {"position": 1.1, "width": 0.2, "height": 0.1}]), "overlap"),
        (_bad(restricted=[{"position": 2.0, "width": 0.4}]), "goal"),
        (_bad(margins={"horizontal": -0.01, "vertical": 0.05}), "margins.horizontal"),
        (_bad(snapshots=[{"from_jump": -1, "obstacles": []}]), "from_jump"),
        (_bad(snapshots=[{"from_jump": 2, "obstacles": []},
                         {"from_jump": 2, "obstacles": []}]), "from_jump"),
        (_bad(snapshots=[{"from_jump": 1, "obstacles": [{"position": 1}]}]), "snapshots[0]"),
        (_bad(colour="red"), "colour"),
        ([1, 2, 3], "course"),
    ],
)
def test_malformed_courses(data, field):
    with pytest.raises(InputError, match=field.replace("[", r"\[").replace("]", r"\]")):
        course_from_dict(data)


def test_load_errors(tmp_path):
    with pytest.raises(InputError, match="neither a shipped course"):
        load_course("no-such-course")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        load_course(str(bad))
    good = tmp_path / "good.json"
    good.write_text(json.dumps(GOOD))
    assert load_course(str(good)).name == "tiny"


def _cli(argv):
    """`jaxhop ARGV` through the command line's entry point, in this process."""
    return main(argv)


def test_cli_bad_input_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(_bad(obstacles=[{"position": 1.0, "width": 0, "height": 1}])))
    for argv, needle in ((["parkour", "--course", str(bad)], "width"),
                         (["parkour", "--course", "nope"], "neither a shipped course"),
                         (["parkour", "--course", "mppc-sim-1", "--grid", "-1"], "--grid"),
                         (["parkour", "--course", "mppc-sim-1", "--planner", "astar"],
                          "invalid choice")):
        assert _cli(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], (argv, err)


def test_cli_writes_json(tmp_path):
    out = tmp_path / "out.json"
    assert _cli(["parkour", "--course", "mppc-sim-1", "--json", str(out),
                 "--plot", str(tmp_path / "run.png")]) == 0
    result = json.loads(out.read_text())
    for key in ("course", "planner", "finished", "jumps", "flight_time", "replan_ms",
                "violations", "executed"):
        assert key in result
    assert set(result["replan_ms"]) == {"min", "median", "max"}
    assert result["finished"] and result["violations"] == 0
    assert set(result["executed"][0]) == {"xs", "zs", "v", "theta", "t", "x1", "z1"}
    assert (tmp_path / "run.png").stat().st_size > 0


def test_random_course_is_seeded():
    a, b = random_course(3), random_course(3)
    assert a.to_dict() == b.to_dict()
    assert a.to_dict() != random_course(4).to_dict()
    assert course_from_dict(a.to_dict()).to_dict() == a.to_dict()
