"""Figures and animations of a MuJoCo run, drawn with matplotlib from its recorded
trajectory (no display or OpenGL needed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .._draw import draw_terrain  # noqa: E402
from .._result import result_name  # noqa: E402
from .._terrain import Terrain  # noqa: E402


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
    from matplotlib.animation import FuncAnimation

    from .._animate import animation_writer

    writer = animation_writer(path, fps)
    tr = np.asarray(trajectory, float)
    if tr.shape[0] == 0:
        raise ValueError("the trajectory is empty")
    times = np.arange(tr[0, 0], tr[-1, 0] + 1e-9, 1.0 / fps)
    rows = tr[np.minimum(np.searchsorted(tr[:, 0], times), tr.shape[0] - 1)]
    fig, ax = plt.subplots(figsize=(9, 3.4))
    draw_terrain(ax, terrain)
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=6, label="global goal")
        ax.legend(loc="upper left", fontsize=8)
    ax.set_ylim(float(np.min(terrain.heights)) - 0.6, float(np.max(tr[:, 2])) + 0.3)
    (leg,) = ax.plot([], [], color="0.2", lw=2, zorder=6)
    (body,) = ax.plot([], [], "o", color="tab:orange", ms=12, zorder=7)
    (marks,) = ax.plot([], [], "v", color="tab:blue", ms=6, zorder=5)
    ax.set_title(_title(run))
    fig.tight_layout()
    contacts: list[tuple[float, float]] = []

    def draw(i):
        _, y, z, fy, fz, stance = rows[i]
        if stance and (not contacts or abs(contacts[-1][0] - fy) > 0.05):
            contacts.append((fy, fz))
        leg.set_data([y, fy], [z, fz])
        body.set_data([y], [z])
        if contacts:
            marks.set_data(*zip(*contacts))
        return leg, body, marks

    anim = FuncAnimation(fig, draw, frames=len(rows), blit=True)
    try:
        anim.save(path, writer=writer, dpi=dpi)
    finally:
        plt.close(fig)
    return path
