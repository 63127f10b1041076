"""Figures and animations of a MuJoCo run, drawn with matplotlib from its recorded
trajectory (no display or OpenGL needed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .._core.result import result_name  # noqa: E402
from .._core.terrain import Terrain  # noqa: E402
from .._viz.draw import draw_terrain  # noqa: E402


def _title(run: dict) -> str:
    why = f" ({run['why']})" if run.get("why") else ""
    return f"MuJoCo hopper: {result_name(run['code'])}{why} in {int(run['steps'])} strides"


def trajectory_figure(terrain: Terrain, run: dict, trajectory: np.ndarray, goal=None,
                      perceived: Terrain | None = None):
    """The body's path, the foot's path, the apexes and the footholds of one run.

    `trajectory`: rows `(t, y, z, foot_y, foot_z, in_stance)` (`run_recorded`).
    """
    tr = np.asarray(trajectory, float)
    fig, ax = plt.subplots(figsize=(11, 3.8))
    draw_terrain(ax, terrain, perceived)
    ax.plot(tr[:, 1], tr[:, 2], color="tab:orange", lw=1.4, label="body", zorder=4)
    ax.plot(tr[:, 3], tr[:, 4], color="0.3", lw=0.7, label="foot", zorder=3)
    apexes = np.asarray(run["apexes"])
    apexes = apexes[np.all(np.isfinite(apexes), axis=1)]
    ax.plot(apexes[:, 0], apexes[:, 1], "o", color="tab:orange", ms=3.5, zorder=5,
            label="apexes")
    feet = np.asarray(run["footholds"])
    feet = feet[np.all(np.isfinite(feet), axis=1)]
    ax.plot(feet[:, 0], feet[:, 1], "v", color="tab:blue", ms=5, zorder=5, label="footholds")
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=7, label="global goal", zorder=6)
    top = max(float(np.max(tr[:, 2])) if tr.size else 0.0, float(np.max(terrain.heights)))
    ax.set_ylim(float(np.min(terrain.heights)) - 0.65, top + 0.9)
    ax.legend(loc="upper left", fontsize=8, ncol=5)
    ax.set_title(_title(run))
    fig.tight_layout()
    return fig


def animate_trajectory(terrain: Terrain, run: dict, trajectory: np.ndarray, path: str,
                       goal=None, fps: int = 25, dpi: int = 80) -> str:
    """Write an animation of one run (`.gif` with Pillow, `.mp4` with ffmpeg): the body, its
    leg to the foot and the footholds, sampled from the trajectory at `fps`."""
    from .._viz.animate import animation_writer, write_animation

    writer = animation_writer(path, fps)
    tr = np.asarray(trajectory, float)
    if tr.shape[0] == 0:
        raise ValueError("the trajectory is empty")
    times = np.arange(tr[0, 0], tr[-1, 0] + 1e-9, 1.0 / fps)
    rows = tr[np.minimum(np.searchsorted(tr[:, 0], times), tr.shape[0] - 1)]
    # A planted foot still moves a little in contact: one mark per foothold 5 cm apart.
    frames = [(y, z, fy, fz, bool(stance)) for _, y, z, fy, fz, stance in rows]
    return write_animation(terrain, frames, path, writer, _title(run), float(np.max(tr[:, 2])),
                           goal, dpi, distinct=lambda a, b: abs(a[0] - b[0]) > 0.05)
