"""The receding-horizon run of MPPC on a course: replan, execute the first jump, repeat.

`Replanner` does the replans of one run (the environment in force at each replan, its
landing candidates computed once per environment, wall times); `run_course` executes every
planned first jump exactly and checks it (`check_jump`). Executing jumps under a
disturbance builds on the same `Replanner` (`jaxhop.parkour`; docs/parkour_reactive.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ._check import check_jump
from ._course import Course
from ._plan import MPPC, EnvData


class Replanner:
    """The replans of one receding-horizon run of `planner` on `course`.

    Replan `k` (0-based) sees the environment in force at `k` (`course.environment_at`);
    each environment's landing candidates and goal reachability are computed on its first
    replan (per room, `Settings.round_room`) and kept.
    """

    def __init__(self, planner: MPPC, course: Course):
        self.planner, self.course = planner, course
        self._data: dict[tuple, EnvData] = {}

    def warm_up(self, x: float, z: float, times: int, wind: float | None = None) -> None:
        """Plan the first horizon from `(x, z)` `times` times, untimed and not kept, so that
        compilation (once per set of padded sizes) is not counted in the replan times."""
        data = EnvData(self.planner, self.course, self.course.environment_at(0))
        for _ in range(times):
            self.planner.replan(self.course, data, x, z, wind)

    def __call__(self, k: int, x: float, z: float | None = None, wind: float | None = None,
                 room: float = 0.0):
        """Replan `k` from contact point `(x, z)`; `z=None`: the surface under `x`.

        `wind` (m/s^2) and `room` (m, rounded up by `Settings.round_room`): see
        `MPPC.replan` and `EnvData`.

        **Returns:** `(plan, env, ms)`: the `Plan` (`None` if no jump is possible), the
        environment it was planned on and the replan's wall time in milliseconds (a new
        environment's candidates and reachability included).
        """
        env = self.course.environment_at(k)
        t0 = time.perf_counter()
        room = self.planner.settings.round_room(room)
        data = self._data.get((id(env), room))
        if data is None:
            data = self._data[(id(env), room)] = EnvData(self.planner, self.course, env,
                                                          room)
        if z is None:
            z = float(env.surface(x))
        plan = self.planner.replan(self.course, data, x, z, wind)
        return plan, env, (time.perf_counter() - t0) * 1e3


@dataclass
class ParkourResult:
    """Outcome of a receding-horizon run (the `parkour` result keys in `to_json`)."""

    course: str
    planner: str
    finished: bool
    executed: list
    replan_ms: list
    violations: list
    plans: list = field(default_factory=list)
    failure: str | None = None
    fallbacks: int = 0
    notes: list = field(default_factory=list)

    @property
    def flight_time(self) -> float:
        return float(sum(j.t for j in self.executed))

    def to_json(self) -> dict:
        return {
            "course": self.course,
            "planner": self.planner,
            "finished": bool(self.finished),
            "jumps": len(self.executed),
            "flight_time": self.flight_time,
            "replan_ms": ms_stats(self.replan_ms),
            "violations": len(self.violations),
            "violation_details": self.violations,
            "failure": self.failure,
            "fallback_replans": self.fallbacks,
            "notes": self.notes,
            "executed": [j.to_dict() for j in self.executed],
        }


def ms_stats(replan_ms) -> dict:
    """`{"min", "median", "max"}` of per-replan wall times (`None`s without any)."""
    ms = np.asarray(replan_ms, float)
    if not ms.size:
        return {"min": None, "median": None, "max": None}
    return {"min": float(ms.min()), "median": float(np.median(ms)), "max": float(ms.max())}


def run_course(course: Course, planner: MPPC | None = None, max_jumps: int = 200,
               check: bool = True, warmup: bool = True, on_jump=None) -> ParkourResult:
    """Run the receding-horizon loop on a course, executing each planned first jump exactly.

    Replan `k` (0-based) sees the snapshot in force at `k`. Every executed jump goes
    through the independent checker (`check_jump`).

    **Arguments:**
    - `course`: the course (use `course.final()` for `--final-snapshot`).
    - `planner`: an `MPPC` (default settings if omitted).
    - `max_jumps`: give up after this many jumps.
    - `check`: run the checker on every executed jump.
    - `warmup`: plan the first horizon a few times, untimed, so that compilation (once
      per set of padded sizes) is not counted in the replan times.
    - `on_jump`: called with the robot's new position after every executed jump
      (progress display).

    **Returns:** a `ParkourResult`; per-replan wall times include everything a replan
    does (a changed environment's candidates and reachability included).
    """
    planner = planner or MPPC()
    x, z = course.start, float(course.environment_at(0).surface(course.start))
    replan = Replanner(planner, course)
    if warmup:  # compile, then a few more calls so that caches and allocators settle
        replan.warm_up(x, z, 5)
    result = ParkourResult(course.name, "mppc", False, [], [], [])
    for k in range(max_jumps):
        if abs(x - course.goal) < 1e-9:
            break
        plan, env, ms = replan(k, x, z)
        result.replan_ms.append(ms)
        if plan is None:
            result.failure = f"no solution at x={x:.3f}"
            break
        result.plans.append(plan)
        result.fallbacks += plan.fallback
        jump = plan.jumps[0]
        result.executed.append(jump)
        if check:
            moved = abs(float(env.surface(jump.xs)) - jump.zs) > 1e-9
            if moved:
                result.notes.append(f"replan {k}: the surface under the robot at "
                                    f"x={jump.xs:.3f} changed in this snapshot")
            for kind, msg in check_jump(planner.robot, course, env, jump, not moved):
                result.violations.append({"jump": k, "kind": kind, "message": msg})
        # The robot stands on the planned landing point; x1, z1 of eqs 8-9 agree with it
        # to rounding, and the checker verifies that.
        x = plan.nodes[1]
        z = float(env.surface(x))
        if on_jump is not None:
            on_jump(x)
    result.finished = abs(x - course.goal) < 1e-9
    if not result.finished and result.failure is None:
        result.failure = f"gave up after {max_jumps} jumps"
    return result

