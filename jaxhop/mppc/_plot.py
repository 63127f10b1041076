"""Figure of a parkour run: course, executed jumps and the plans behind them.

matplotlib is imported when a figure is drawn, not with `jaxhop.mppc`: the command line
imports the MPPC modules for its `parkour` options, and matplotlib took half a second of
every `jaxhop` command's start.
"""

import math

import numpy as np

from ._course import Course
from ._robot import Robot


def _foot_path(robot: Robot, jump, n=60):
    tau = np.linspace(0.0, jump.t, n)
    c, s = math.cos(jump.theta), math.sin(jump.theta)
    fx, fz = robot.foot_from_hip
    x = jump.xs + robot.r_takeoff * c + fx + jump.v * c * tau
    z = jump.zs + robot.r_takeoff * s + fz + jump.v * s * tau - 0.5 * robot.g * tau**2
    return x, z


def plot_run(course: Course, result, robot: Robot | None = None, replan: int | None = None):
    """Draw the course and a run on it; a pure function returning a new `Figure`.

    Blocks and restricted areas are those of the last environment the run saw (earlier
    snapshots are drawn faintly). Executed jumps are solid foot paths; the plan made at
    replan `replan` (default: the first) is dashed.

    **Arguments:**
    - `course`: the course.
    - `result`: a `ParkourResult` from `run_course`.
    - `robot`: the leg (default parameters if omitted).
    - `replan`: index of the replan whose whole plan is drawn.

    **Returns:** a `matplotlib.figure.Figure`.
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    robot = robot or Robot()
    fig = Figure(figsize=(12, 3.6))
    ax = fig.add_subplot()
    n_env = max(len(result.executed) - 1, 0)
    last = course.environment_at(n_env)
    envs = [course.environment] + [e for _, e in course.snapshots]
    for env in envs:
        alpha, face = (0.9, "0.55") if env is last else (0.15, "0.7")
        for a, b, h in zip(env.front, env.back, env.height):
            ax.add_patch(Rectangle((a, 0), b - a, h, facecolor=face, edgecolor="0.3",
                                   alpha=alpha, lw=0.8))
    for a, b in zip(last.restricted_lo, last.restricted_hi):
        ax.axvspan(a, b, ymax=0.06, color="tab:red", alpha=0.5, lw=0)
    ax.axhline(0, color="0.2", lw=1)
    for k, jump in enumerate(result.executed):
        x, z = _foot_path(robot, jump)
        ax.plot(x, z, color="tab:blue", lw=1.5, label="executed (foot)" if k == 0 else None)
        ax.plot([jump.x1], [jump.z1], "o", color="tab:blue", ms=3)
    plans = getattr(result, "plans", [])
    if plans:
        i = 0 if replan is None else replan
        for k, jump in enumerate(plans[i].jumps):
            x, z = _foot_path(robot, jump)
            ax.plot(x, z, "--", color="tab:orange", lw=1,
                    label=f"plan at replan {i}" if k == 0 else None)
    ax.axvline(course.start, color="tab:green", lw=1, ls=":")
    ax.axvline(course.goal, color="tab:green", lw=1, ls=":")
    status = "finished" if result.finished else "not finished"
    ax.set_title(f"{course.name}: {status}, {len(result.executed)} jumps, "
                 f"{result.flight_time:.2f} s flight, {len(result.violations)} violations")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_xlim(course.start - 0.2, course.goal + 0.2)
    ax.set_ylim(-0.05, 1.0)
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    return fig
