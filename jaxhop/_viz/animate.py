"""Animations of a run: the body, its leg, the terrain and the footholds, rebuilt from the
apexes and footholds."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from .._control.decisions import model_for
from .._core.result import RESULT_NAMES
from .._core.terrain import Terrain
from .draw import RunStyle, ballistic, draw_terrain, stride_paths

ANIMATION_FORMATS = (".gif", ".mp4")


def animation_writer(path: str, fps: int):
    """A matplotlib writer for `path`: Pillow for `.gif`, ffmpeg for `.mp4`.

    Raises:
        InputError: another extension, or `.mp4` without an ffmpeg encoder.
    """
    import os

    from matplotlib.animation import FFMpegWriter, PillowWriter, writers

    from .._core.errors import InputError

    ext = os.path.splitext(path)[1].lower()
    if ext == ".gif":
        return PillowWriter(fps=fps)
    if ext == ".mp4":
        if not writers.is_available("ffmpeg"):
            raise InputError(f"cannot write {path}: MP4 needs ffmpeg, which is not installed "
                             "(write a .gif instead)")
        return FFMpegWriter(fps=fps)
    raise InputError(f"{path}: the file name must end with .gif or .mp4")


def animation_frames(run: dict, rho0: float = 1.0, g: float = 9.81, fps: int = 25,
                     model: str = "bhop", wind: float = 0.0) -> list[tuple]:
    """Frames `(com_y, com_z, foot_y, foot_z, in_contact)` of a run at `fps`.

    Flight follows `stride_paths` in time steps of `1 / fps`; the BHop stance
    (instantaneous) and the SLIP stance (not recorded) take four frames each, the COM moving
    along the chord from touchdown to liftoff with the foot planted. The leg hangs below the
    COM while descending and is half retracted while rising.
    """
    apexes = np.asarray(run["apexes"])
    apexes = apexes[np.all(np.isfinite(apexes), axis=1)]
    frames = []
    dt = 1.0 / fps
    for p in stride_paths(apexes, run["footholds"], rho0, g, model, wind, n=2):
        (yf, h), td, lo = p["foot"], p["td"], p["lo"]
        y0, z0, vy0 = p["apex"]
        for t in np.arange(0.0, p["t_down"], dt):
            cy, cz = ballistic(y0, z0, vy0, 0.0, t, g, wind)
            frames.append((cy, cz, cy + yf - td[0], cz + h - td[1], False))
        if p["liftoff"] is None:
            frames.append((td[0], td[1], yf, h, True))
            continue
        for s in np.linspace(0.0, 1.0, 4):
            frames.append((td[0] + s * (lo[0] - td[0]), td[1] + s * (lo[1] - td[1]), yf, h,
                           True))
        y1, z1, vy1, vz1, t_up = p["liftoff"]
        for t in np.arange(dt, t_up, dt):
            cy, cz = ballistic(y1, z1, vy1, vz1, t, g, wind)
            frames.append((cy, cz, cy, cz - 0.6 * rho0, False))
    if not frames:
        frames.append((apexes[0, 0], apexes[0, 1], apexes[0, 0], apexes[0, 1] - rho0, False))
    return frames


def animate_run(terrain: Terrain, run: dict, path: str, fps: int = 25, goal=None,
                style: RunStyle | None = None, dpi: int = 80) -> str:
    """Write an animation of a run: the body, its leg, the terrain and the footholds.

    The motion is rebuilt from the apexes and footholds (`animation_frames`). `path` ending
    in `.gif` is written with Pillow, `.mp4` with ffmpeg (`animation_writer`). Returns the
    path written. `style` (`RunStyle`): the model, hopper and wind of the run.
    """
    style = RunStyle() if style is None else style
    model = style.model
    writer = animation_writer(path, fps)
    apexes = np.asarray(run["apexes"])
    apexes = apexes[np.all(np.isfinite(apexes), axis=1)]
    frames = animation_frames(run, style.rho0, style.g, fps, model, style.wind)
    title = (f"{model_for(model).name.upper()}: {RESULT_NAMES[int(run['code'])]} in "
             f"{int(run['steps'])} strides")
    return write_animation(terrain, frames, path, writer, title, float(np.max(apexes[:, 1])),
                           goal, dpi)


def write_animation(terrain: Terrain, frames, path: str, writer, title: str, top: float,
                    goal=None, dpi: int = 80, distinct=lambda a, b: a != b) -> str:
    """Write frames `(com_y, com_z, foot_y, foot_z, in_contact)` over the terrain with
    `writer` (`animation_writer`): the body, its leg to the foot, and a mark at every
    foothold, a new one where `distinct(last_mark, foot)`. `top`: the highest body height
    drawn. Returns `path`."""
    from matplotlib.animation import FuncAnimation

    fig, ax = plt.subplots(figsize=(9, 3.4))
    draw_terrain(ax, terrain)
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=6, label="global goal")
    ax.set_ylim(float(np.min(terrain.heights)) - 0.6, top + 0.3)
    (leg,) = ax.plot([], [], color="0.2", lw=2, zorder=6)
    (body,) = ax.plot([], [], "o", color="tab:orange", ms=12, zorder=7)
    (marks,) = ax.plot([], [], "v", color="tab:blue", ms=6, zorder=5, label="footholds")
    ax.set_title(title)
    if goal is not None:
        ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    contacts: list[tuple[float, float]] = []

    def draw(i):
        cy, cz, fy, fz, contact = frames[i]
        if contact and (not contacts or distinct(contacts[-1], (fy, fz))):
            contacts.append((fy, fz))
        leg.set_data([cy, fy], [cz, fz])
        body.set_data([cy], [cz])
        if contacts:
            marks.set_data(*zip(*contacts))
        return leg, body, marks

    anim = FuncAnimation(fig, draw, frames=len(frames), blit=True)
    try:
        anim.save(path, writer=writer, dpi=dpi)
    finally:
        plt.close(fig)
    return path
