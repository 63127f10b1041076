"""Figures carry the data they are given (counts of plotted items), not only 'no crash'."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from jaxhop._plot import doa_figure, runs_figure  # noqa: E402
from jaxhop._terrain import builtin_terrain  # noqa: E402


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
