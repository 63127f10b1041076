import json

import pytest

from jaxhop._cli import main


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

    from jaxhop._bhop import bhop_apex_map
    from jaxhop._params import Hopper

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
