"""One call for the `parkour --planner reactive` command and the comparison."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .._core.params import Hopper
from .._core.result import COURSE_FAILURE_NAMES, Result, failure_counts, result_name
from ..mppc._course import Course
from ._map import leg_hopper, leg_templates
from ._run import (
    course_disturbance,
    course_plans,
    decision_ms,
    executed_strides,
    first_descent,
    initial_states,
    pad_plans,
    run_reactive,
    snapshot_flights,
)


def _stats(ms) -> dict:
    ms = np.asarray(ms, float)
    if not ms.size:
        return {"min": None, "median": None, "max": None}
    return {"min": float(ms.min()), "median": float(np.median(ms)), "max": float(ms.max())}


@dataclasses.dataclass(frozen=True)
class CourseRuns:
    """The seeded runs of the reactive planner on a course.

    Attributes:
        model: `"bhop"` or `"slip"`, the simulated model.
        controller: `"adaptive"` (the default, as on the command line) or `"paper"`.
        noise: `none`, `wind`, `sensor` or `landing`, or several joined by `+`
            (Froude-scaled to the leg; `docs/parkour_reactive.md`).
        seed: the seed of the initial states and of the noise.
        runs: how many seeded runs (run 0 is reported in full).
    """

    model: str = "bhop"
    controller: str = "adaptive"
    noise: str = "none"
    seed: int = 0
    runs: int = 1


def reactive_parkour(course: Course, runs: CourseRuns | None = None, *,
                     hopper: Hopper | None = None, templates=None, plans=None,
                     rebuild: int = 0, align: bool = True, log=None) -> dict:
    """Run the reactive planner on a course; the result has the MPPC result's keys.

    `finished`, `jumps`, `flight_time`, `violations`, `executed` describe run 0 (the first
    seeded initial apex); `success_rate` and `failures` cover all `runs`. `replan_ms` is the
    time per decision (a reactive planner decides at every apex instead of replanning);
    `update_ms` the incremental plan updates at snapshots (`rebuild_ms`: full rebuilds of
    the first `rebuild` snapshots). `runs` (`CourseRuns`): model, controller, noise, seed
    and number of runs. `hopper`, `templates` (default: the MPPC leg's, Froude-scaled) and
    `plans` (`course_plans`, built here when not given, with `rebuild`, `align`:
    `course_map`'s option, `False` centres every block's segments, and `log`).
    `recoveries` counts the strides taken from a recovered apex (total and mean per run).
    `snapshots`: for each snapshot, its update time against the flight in which it started
    (`snapshot_flights`).
    """
    runs = CourseRuns() if runs is None else runs
    model, noise, seed, controller = runs.model, runs.noise, runs.seed, runs.controller
    hopper = leg_hopper() if hopper is None else hopper
    templates = leg_templates(hopper, model=model) if templates is None else templates
    cps = plans if plans is not None else course_plans(course, hopper, templates,
                                                       rebuild=rebuild, log=log,
                                                       align=align)
    padded = pad_plans(cps, model)
    apex0, coverage = initial_states(cps, padded, runs.runs, seed, hopper)
    if apex0.shape[0] == 0:
        raise RuntimeError(f"{course.name}: the plan covers no initial state near the start")
    t0 = time.perf_counter()
    res = run_reactive(cps, padded, apex0, hopper=hopper, noise=noise, seed=seed, model=model,
                       controller=controller)
    run_s = time.perf_counter() - t0
    dec = decision_ms(cps, padded, apex0[: min(20, len(apex0))], hopper, model)
    code = res["code"]
    wind = course_disturbance(noise, hopper).wind
    executed = executed_strides(res, 0, hopper, wind)
    flight = first_descent(res, 0, hopper) + sum(j["t"] for j in executed)
    ok = code == Result.SUCCESS
    c0 = int(code[0])
    violations = []
    if result_name(c0) in ("restricted", "margin", "collision"):
        violations.append({"jump": int(res["steps"][0]) - 1, "kind": result_name(c0)})
    times = []
    for i in np.nonzero(ok)[0]:
        times.append(first_descent(res, i, hopper)
                     + sum(j["t"] for j in executed_strides(res, i, hopper, wind)))
    return {
        "course": course.name,
        "planner": "reactive",
        "model": model,
        "controller": controller,
        "noise": noise,
        "finished": bool(c0 == Result.SUCCESS),
        "jumps": len(executed),
        "flight_time": float(flight),
        "replan_ms": _stats(dec),
        "violations": len(violations),
        "violation_details": violations,
        "failure": None if c0 == Result.SUCCESS else result_name(c0),
        "executed": executed,
        "initial_apex": apex0[0].tolist(),
        "runs": int(len(code)),
        "seed": int(seed),
        "success_rate": float(ok.mean()),
        "failures": failure_counts(code, COURSE_FAILURE_NAMES),
        "recoveries": {"total": int(res["recoveries"].sum()),
                       "mean": float(res["recoveries"].mean())},
        "mean_jumps": float(res["steps"][ok].mean()) if ok.any() else None,
        "mean_flight_time": float(np.mean(times)) if times else None,
        "coverage": float(coverage),
        "build_s": float(cps.build_s),
        "update_ms": _stats(np.asarray(cps.update_s) * 1e3),
        "update_cpu_ms": _stats(np.asarray(cps.update_cpu_s) * 1e3),
        "rebuild_ms": _stats(np.asarray(cps.rebuild_s) * 1e3),
        "rebuild_cpu_ms": _stats(np.asarray(cps.rebuild_cpu_s) * 1e3),
        "rebuild_equal": [bool(x) for x in cps.rebuild_equal],
        "n_snapshots": len(cps.plans) - 1,
        "snapshots": snapshot_flights(cps, res, hopper),
        "n_policies": [int(cp.stats["n_instantiated"]) for cp in cps.plans],
        "run_s": float(run_s),
        "hopper": {"m": float(hopper.m), "g": float(hopper.g), "rho0": float(hopper.rho0)},
    }
