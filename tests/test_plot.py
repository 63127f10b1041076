"""Figures carry the data they are given (counts of plotted items), not only 'no crash'."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxhop
from jaxhop._core.terrain import builtin_terrain  # noqa: E402
from jaxhop._viz.plot import doa_figure, runs_figure  # noqa: E402


def _fake_run(steps):
    apexes = np.full((61, 3), np.nan)
    feet = np.full((60, 2), np.nan)
    for k in range(steps + 1):
        apexes[k] = (0.3 + 0.5 * k, 1.5, 0.5)
    for k in range(steps):
        feet[k] = (0.55 + 0.5 * k, 0.0)
    return {"apexes": apexes, "footholds": feet, "code": 0, "steps": steps}


def test_runs_figure_plots_one_foothold_per_stride():
    terrain = builtin_terrain("flat")
    runs = [_fake_run(4), _fake_run(2)]
    fig = runs_figure(terrain, runs, goal=(2.5, 1.3, 0.0))
    ax = fig.axes[0]
    feet = [ln for ln in ax.lines if ln.get_marker() == "v"]
    assert [len(ln.get_xdata()) for ln in feet] == [4, 2]
    apex_marks = [ln for ln in ax.lines if ln.get_marker() == "."]
    assert [len(ln.get_xdata()) for ln in apex_marks] == [5, 3]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "run 1: success in 4 strides" in labels and "global goal" in labels
    plt.close(fig)


def test_doa_figure_counts_successes_and_failures():
    terrain = builtin_terrain("flat")
    initial = np.stack([np.linspace(0.2, 2.8, 30), np.full(30, 1.6), np.full(30, 0.5)], 1)
    code = np.where(np.arange(30) % 7 == 0, 4, 0)
    steps = np.arange(30) % 5
    fig = doa_figure(terrain, initial, code, steps)
    ax = fig.axes[0]
    sizes = sorted(c.get_offsets().shape[0] for c in ax.collections
                   if c.get_offsets().shape[0] in (int((code == 0).sum()), int((code != 0).sum())))
    assert sizes == sorted([int((code == 0).sum()), int((code != 0).sum())])
    assert f"{100 * (code == 0).mean():.1f}%" in ax.get_title()
    plt.close(fig)


# --- run geometry, region cross-sections, open-loop replay, animation --------------------

import pytest  # noqa: E402

from jaxhop._execution.replay import nominal_controls, open_loop_replay  # noqa: E402
from jaxhop._viz.animate import animate_run, animation_frames, animation_writer  # noqa: E402
from jaxhop._viz.draw import RunStyle, policy_cross_sections, stride_paths  # noqa: E402
from jaxhop._viz.plot import disturbance_figure, long_run_figure  # noqa: E402

G, RHO0 = 9.81, 1.0


def _slip_like_run(th=0.2, v=1.0, z0=1.5):
    """One SLIP-like stride built by hand: touchdown and liftoff with the leg at `rho0`."""
    t_d = np.sqrt(2 * (z0 - RHO0 * np.cos(th)) / G)
    td = np.array([v * t_d, z0 - 0.5 * G * t_d**2])
    foot = td + RHO0 * np.array([np.sin(th), -np.cos(th)])
    lo = foot + RHO0 * np.array([np.sin(th), np.cos(th)])
    vz = G * t_d
    nxt = (lo[0] + v * vz / G, lo[1] + vz**2 / (2 * G), v)
    apexes = np.full((4, 3), np.nan)
    apexes[0], apexes[1] = (0.0, z0, v), nxt
    feet = np.full((3, 2), np.nan)
    feet[0] = foot
    return apexes, feet, td, lo


def test_stride_paths_slip_touchdown_and_liftoff_at_leg_length():
    apexes, feet, td, lo = _slip_like_run()
    (p,) = stride_paths(apexes, feet, RHO0, G, model="slip")
    np.testing.assert_allclose(p["td"], td, atol=2e-3)
    np.testing.assert_allclose(p["lo"], lo, atol=2e-3)
    # The BHop geometry (foot straight below the COM) touches down at z = h + rho0 instead.
    (q,) = stride_paths(apexes, feet, RHO0, G, model="bhop")
    assert abs(q["td"][1] - (feet[0, 1] + RHO0)) < 1e-12 and abs(q["td"][1] - td[1]) > 0.01
    # Path ends: the descent starts at the apex, the ascent ends at the next apex.
    assert np.allclose([p["descent"][0][0], p["descent"][1][0]], apexes[0, :2])
    assert np.allclose([p["ascent"][0][-1], p["ascent"][1][-1]], apexes[1, :2])


def test_animation_frames_follow_the_run_and_plant_each_foot():
    run = _fake_run(3)
    frames = np.array(animation_frames(run, fps=25), float)
    assert len(frames) > 20
    contact = frames[:, 4] > 0
    planted = {tuple(np.round(f[2:4], 9)) for f in frames[contact]}
    assert planted == {tuple(np.round(f, 9)) for f in run["footholds"][:3]}
    assert np.all(frames[contact, 3] == 0.0)  # the feet touch the flat ground
    assert np.all(frames[~contact, 1] > 1.0)  # the body flies above the leg length


def test_animation_writer_rejects_unknown_formats(monkeypatch):
    from matplotlib.animation import writers

    from jaxhop._core.errors import InputError

    with pytest.raises(InputError, match=r"\.gif or \.mp4"):
        animation_writer("run.avi", 25)
    monkeypatch.setattr(writers, "is_available", lambda name: False)
    with pytest.raises(InputError, match="ffmpeg"):
        animation_writer("run.mp4", 25)


def test_animate_run_writes_a_multi_frame_gif(tmp_path):
    from PIL import Image

    run = _fake_run(3)
    path = animate_run(builtin_terrain("flat"), run, str(tmp_path / "r.gif"), fps=8, dpi=30)
    with Image.open(path) as im:
        assert im.n_frames == len(animation_frames(run, fps=8)) > 10


def test_doa_figure_names_failure_kinds():
    terrain = builtin_terrain("flat")
    initial = np.stack([np.linspace(0.2, 2.8, 10), np.full(10, 1.6), np.full(10, 0.5)], 1)
    code = np.array([0, 0, 6, 6, 6, 1, 0, 0, 0, 0])
    fig = doa_figure(terrain, initial, code, np.ones(10, int), title="SLIP")
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "failure (4: collision 1, solver 3)" in labels
    plt.close(fig)


@pytest.fixture(scope="module")
def flat():
    """The plan on `flat` and one nominal BHop run on it (built once, not cached)."""
    import jax

    from jaxhop._execution.batches import run_batch
    from jaxhop._planning.plan import build_plan

    plan = build_plan(builtin_terrain("flat"))
    runs = run_batch(plan, [[0.4, 1.6, 0.5]], jaxhop.RunSettings(controller="paper"),
                     key=jax.random.key(0))
    return plan, {k: v[0] for k, v in runs.items()}


def test_cross_sections_contain_the_apex_and_the_goal(flat):
    from matplotlib.path import Path

    plan, run = flat
    steps = int(run["steps"])
    assert run["code"] == 0 and steps >= 2
    sections = policy_cross_sections(plan, run["policies"][:steps], run["apexes"])
    assert len(sections) == steps
    for k, (dom, goal) in enumerate(sections):
        # The apex lies in its policy's domain, the policy's goal in its feasible goal.
        assert Path(dom).contains_point(run["apexes"][k, :2], radius=1e-9)
        assert Path(goal).contains_point(plan.goals[run["policies"][k], :2], radius=1e-9)
    fig = runs_figure(plan.terrain, [run], plan.goal, plan=plan)
    assert len(fig.axes[0].patches) == 2 * steps
    feet = [ln for ln in fig.axes[0].lines if ln.get_marker() == "v"]
    assert [len(ln.get_xdata()) for ln in feet] == [steps]
    plt.close(fig)


def test_open_loop_replay_reproduces_nominal_and_drifts_under_wind(flat):
    import jax

    from jaxhop._core.params import disturbance_for
    from jaxhop._execution.batches import run_batch

    plan, nominal = flat
    steps = int(nominal["steps"])
    for mode in ("controls", "goals"):
        same = open_loop_replay(plan, nominal, mode=mode)
        assert same["code"] == 0 and same["steps"] == steps
        np.testing.assert_allclose(same["apexes"][: steps + 1],
                                   nominal["apexes"][: steps + 1], atol=1e-10)
    assert nominal_controls(plan, nominal).shape == (steps, 3)
    wind = disturbance_for("wind")
    key = jax.random.key(3)
    replay = open_loop_replay(plan, nominal, disturbance=wind, key=key)
    reactive = {k: v[0] for k, v in run_batch(plan, nominal["apexes"][:1],
                                              jaxhop.RunSettings(controller="paper"), key=key,
                                              disturbance=wind).items()}
    n = min(int(replay["steps"]), int(reactive["steps"]))
    gap = np.abs(replay["apexes"][1 : n + 1] - reactive["apexes"][1 : n + 1])
    assert np.nanmax(gap) > 1e-3  # re-selection changes the controls under wind
    # Open loop, the wind slows every flight and nothing corrects it: the end falls short.
    assert replay["code"] != 0
    last = replay["apexes"][int(replay["steps"])]
    assert np.isnan(last).all() or abs(last[0] - plan.goal[0]) > 0.05
    fig = disturbance_figure(plan.terrain, nominal, replay, reactive, plan.goal, "wind",
                             RunStyle(wind=float(wind.wind)))
    top, bottom = fig.axes
    for ax, other in ((top, replay), (bottom, reactive)):
        feet = [len(ln.get_xdata()) for ln in ax.lines if ln.get_marker() == "v"]
        expect = [int(nominal["steps"]),
                  int(np.isfinite(other["footholds"][:, 0]).sum())]
        assert feet == expect
    circles = [ln for ln in bottom.lines if ln.get_marker() == "o" and ln.get_markersize() == 11]
    used = set(nominal["policies"][:steps].tolist())
    fresh = [p for p in reactive["policies"][: int(reactive["steps"])] if p not in used]
    assert len(circles[0].get_xdata()) == len(fresh)
    plt.close(fig)


def test_long_run_figure_marks_one_goal_per_stride(flat):
    plan, run = flat
    fig = long_run_figure(plan, run, model="bhop")
    ax = fig.axes[0]
    goals = [ln for ln in ax.lines if ln.get_marker() == "o" and ln.get_mfc() == "none"]
    assert len(goals[0].get_xdata()) == int(run["steps"])
    np.testing.assert_allclose(goals[0].get_xdata(), plan.goals[run["policies"][:run["steps"]], 0])
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(lbl.startswith("BHOP COM path: success") for lbl in labels)
    plt.close(fig)
