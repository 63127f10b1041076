import json
import math

import pytest

from jaxhop._cli.main import main


@pytest.mark.parametrize("content, needle", [
    ("{not json", "invalid JSON"),
    ('{"blocks": [{"start": 0, "end": 1, "height": 0}, {"start": 0.5, "end": 2, "height": 0}]}',
     "blocks[1]: overlaps blocks[0]"),
    ('{"blocks": [{"start": 0, "end": -1, "height": 0}]}', "blocks[0]: start 0.0 must be less"),
    ('{"blocks": [{"start": 0, "end": 1, "height": NaN}]}', "blocks[0].height: must be finite"),
    ('{"blocks": []}', "blocks: the list is empty"),
    ('{"blocks": [{"start": 0, "end": 1, "height": 0}]}', "has no default goal"),
    ('[]', "expected a JSON object"),
])
def test_malformed_terrain_file_exits_2(tmp_path, capsys, content, needle):
    path = tmp_path / "bad.json"
    path.write_text(content)
    assert main(["plan", "--terrain", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("argv, needle", [
    (["plan", "--terrain", "nowhere"], "neither a built-in"),
    (["sweep", "--terrain", "flat", "--goal", "1,2"], "--goal: expected 3"),
    (["sweep", "--terrain", "flat", "--goal", "1,2,inf"], "finite"),
    (["sweep", "--terrain", "flat", "--seed", "-3"], "--seed"),
    (["sweep", "--terrain", "flat", "--dy", "0"], "--dy: must be positive"),
    (["run", "--terrain", "flat", "--apex", "a,b,c"], "--apex: expected numbers"),
    (["sweep", "--noise", "storm"], "invalid choice"),
    (["frobnicate"], "invalid choice"),
])
def test_bad_arguments_exit_2(capsys, argv, needle):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


@pytest.mark.slow
def test_plan_and_run_json(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("JAXHOP_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "p.json"
    assert main(["plan", "--terrain", "flat", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert set(data) == {"n_segments", "n_situated", "n_candidate_pairs", "n_instantiated",
                         "n_goal_policies", "n_deployed", "n_edges", "seconds"}
    assert data["n_segments"] == 20 and data["n_situated"] == 400
    run = tmp_path / "r.json"
    assert main(["run", "--terrain", "flat", "--apex", "0.5,1.6,0.5", "--json", str(run),
                 "--plot", str(tmp_path / "r.png")]) == 0
    r = json.loads(run.read_text())
    assert r["result"] == "success" and len(r["footholds"]) == r["steps"]
    assert (tmp_path / "r.png").stat().st_size > 10_000


def test_step_bhop_matches_closed_form(tmp_path):
    import jax.numpy as jnp
    import numpy as np

    from jaxhop._core.params import Hopper
    from jaxhop._models.bhop import bhop_apex_map

    out = tmp_path / "s.json"
    assert main(["step", "--model", "bhop", "--apex", "0.2,1.4,0.8", "--controls",
                 "0.1,0.05,1.2", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    expect = bhop_apex_map(jnp.array([0.2, 1.4, 0.8]), jnp.array([0.1, 0.05, 1.2]), 0.0,
                           Hopper())
    assert data["result"] == "ok"
    np.testing.assert_allclose(data["apex_next"], np.asarray(expect), atol=1e-12)


def test_step_slip_equal_stiffness_conserves_energy(tmp_path):
    out = tmp_path / "s.json"
    assert main(["step", "--model", "slip", "--apex", "0,1.3,1.0", "--controls",
                 "0.15,20000,20000", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    (y0, z0, v0), (y1, z1, v1) = data["apex"], data["apex_next"]
    e0, e1 = 0.5 * v0**2 + 9.81 * z0, 0.5 * v1**2 + 9.81 * z1
    assert data["result"] == "ok" and y1 > y0
    assert abs(e1 - e0) / e0 < 1e-8


@pytest.mark.slow
def test_run_animate_writes_a_gif(tmp_path, monkeypatch, capsys):
    from PIL import Image

    monkeypatch.setenv("JAXHOP_CACHE", str(tmp_path / "cache"))
    gif = tmp_path / "run.gif"
    assert main(["run", "--terrain", "flat", "--apex", "0.5,1.6,0.5", "--animate",
                 str(gif)]) == 0
    with Image.open(gif) as im:
        assert im.n_frames > 10 and im.size[0] > 100
    capsys.readouterr()
    # A format other than GIF / MP4 is refused before any work, in one line.
    assert main(["run", "--terrain", "flat", "--animate", str(tmp_path / "run.avi")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxhop: error: --animate:") and ".gif or .mp4" in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "run.avi").exists()


# --- the foot's height in `jaxhop step` ------------------------------------------------------


def _step_args(model, apex, controls, terrain=None):
    import argparse

    return argparse.Namespace(model=model, apex=list(apex), controls=list(controls),
                              terrain=terrain)


def test_step_accepts_a_slip_apex_whose_foot_is_above_the_ground(tmp_path):
    """0.38 rad at z = 1.0: the leg reaches down only 1 cos(0.38) = 0.929 m."""
    from jaxhop._cli.args import check_step_args

    assert check_step_args(_step_args("slip", (0, 1.0, 5.0), (0.38, 20000, 20000))) is not None
    out = tmp_path / "s.json"
    assert main(["step", "--model", "slip", "--apex", "0,1.0,5.0", "--controls",
                 "0.38,20000,20000", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["apex"] == [0.0, 1.0, 5.0]


@pytest.mark.parametrize("th", [0.0, 0.2, -0.38, 0.7])
def test_step_apex_check_is_the_slip_descent_reaching_the_ground(th):
    """Accepted iff the SLIP descent starts with the foot above the ground (its own test,
    `flat_touchdown`), on either side of the threshold."""
    import jax.numpy as jnp

    from jaxhop._cli.args import check_step_args
    from jaxhop._core.errors import InputError
    from jaxhop._core.params import Hopper
    from jaxhop._models.slip.stride import flat_touchdown

    for dz in (-1e-3, 1e-3):
        z = math.cos(th) + dz
        reached = bool(flat_touchdown(jnp.array([0.0, z, 1.0]), th, 0.0, Hopper())[2])
        args = _step_args("slip", (0.0, z, 1.0), (th, 20000, 20000))
        if reached:
            check_step_args(args)
        else:
            with pytest.raises(InputError, match="puts the foot"):
                check_step_args(args)
        assert reached == (dz > 0)


def test_step_foot_under_a_block_edge_is_checked_where_the_foot_is(tmp_path):
    """A SLIP foot swung over a higher block is checked against that block's top."""
    from jaxhop._cli.args import check_step_args
    from jaxhop._core.errors import InputError

    path = tmp_path / "t.json"
    path.write_text('{"blocks": [{"start": -2, "end": 0.2, "height": 0}, '
                    '{"start": 0.2, "end": 2, "height": 0.3}]}')
    th = 0.38  # foot at y = sin(0.38) = 0.371, over the 0.3 m block
    with pytest.raises(InputError, match="ground under it \\(0.3"):
        check_step_args(_step_args("slip", (0.0, 1.2, 1.0), (th, 2e4, 2e4), str(path)))
    check_step_args(_step_args("slip", (0.0, 1.3, 1.0), (th, 2e4, 2e4), str(path)))
    check_step_args(_step_args("slip", (0.0, 1.2, 1.0), (-th, 2e4, 2e4), str(path)))
    # BHop: the foot hangs straight down at the apex.
    with pytest.raises(InputError, match="puts the foot"):
        check_step_args(_step_args("bhop", (0.0, 1.0, 1.0), (0.1, 0.05, 1.2)))
    check_step_args(_step_args("bhop", (0.0, 1.001, 1.0), (0.1, 0.05, 1.2)))


# --- combined disturbances -------------------------------------------------------------------


def test_combined_noise_is_the_fieldwise_combination():
    import numpy as np

    from jaxhop._core.params import Hopper, disturbance_for, has_ground

    for hopper in (None, Hopper(m=30.0, g=5.0, rho0=0.5)):
        wind, sensor = disturbance_for("wind", hopper), disturbance_for("sensor", hopper)
        landing = disturbance_for("landing", hopper)
        both = disturbance_for("wind+sensor", hopper)
        assert both.wind == wind.wind != 0 and both.landing == 0
        np.testing.assert_array_equal(both.sensor, sensor.sensor)
        three = disturbance_for("landing+sensor+wind", hopper)
        assert three.wind == wind.wind and three.landing == landing.landing != 0
        np.testing.assert_array_equal(three.sensor, sensor.sensor)
        ground = disturbance_for("wind+sensor+ground", hopper)
        assert ground.wind == wind.wind and ground.landing == 0
        np.testing.assert_array_equal(ground.sensor, sensor.sensor)
    assert has_ground("wind+sensor+ground") and has_ground("ground")
    assert not has_ground("wind+sensor") and not has_ground("none")


@pytest.mark.parametrize("noise, needle", [
    ("none+wind", "'none' cannot be joined"), ("wind+sensor+wind", "'wind' is given twice"),
    ("wind+", "an empty kind"), ("+sensor", "an empty kind"), ("wind++sensor", "an empty kind"),
    ("wind+storm", "invalid choice 'storm' in 'wind+storm'"), ("", "an empty kind"),
    ("Wind", "invalid choice 'Wind'"),
])
def test_bad_noise_combinations_are_refused(capsys, noise, needle):
    from jaxhop._core.errors import InputError
    from jaxhop._core.params import disturbance_for

    with pytest.raises(InputError, match="noise: "):
        disturbance_for(noise)
    for argv in (["sweep", "--terrain", "flat"], ["run", "--terrain", "flat"],
                 ["parkour", "--course", "mppc-sim-1", "--planner", "reactive"]):
        assert main(argv + ["--noise", noise]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("jaxhop: error: --noise: ")
        assert needle in err


def test_noise_lists_parse_on_every_command():
    from jaxhop._cli.main import build_parser

    parser = build_parser()
    for cmd in (["sweep"], ["run"]):
        for noise in ("wind+sensor", "wind+sensor+ground", "ground+wind", "none"):
            assert parser.parse_args(cmd + ["--noise", noise]).noise == noise
    pk = ["parkour", "--course", "mppc-sim-1", "--noise"]
    assert parser.parse_args(pk + ["wind+sensor+landing"]).noise == "wind+sensor+landing"
    with pytest.raises(Exception, match="invalid choice 'ground'"):
        parser.parse_args(pk + ["wind+ground"])
    with pytest.raises(Exception, match="invalid choice 'landing'"):
        parser.parse_args(["sweep", "--noise", "landing+wind"])
