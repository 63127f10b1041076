"""jaxhop's MPPC under the disturbances of the comparison (docs/parkour_reactive.md).

`jaxhop.mppc.run_course` executes every planned first jump exactly. Here the same
receding-horizon replans (`jaxhop.mppc.Replanner`: same planner, same replans on the
snapshot in force) execute each jump under a disturbance, the reactive planner's
(`jaxhop._core.params.disturbance_for`), Froude-scaled to the leg (length `rt`, its gravity):

* `sensor`: the planner sees the robot's contact point `+-0.05 rt` off (uniform, fresh per
  replan) and plans from there; the jump (speed, angle) is executed from the true point,
  so it lands off by the same amount;
* `wind`: horizontal acceleration `-0.2 g / 9.81` during each flight: the landing moves
  by `a t^2 / 2`;
* `landing`: the landing point is off by uniform `+-0.05 rt`.

MPPC runs with an observer (`jaxhop.mppc.Observer`, docs/mppc.md, "Disturbances"): the
wind estimated from the measured landings and planned for, and room around edges,
restricted areas and blocks for the landing and sensing error seen so far.

Each executed jump is checked: the independent checker (`check_jump`) for the flight
from the true takeoff point in the true wind (foot and knee clearance, collisions), and
the disturbed landing point for the restricted areas (`restricted`), the edge margin
(`margin`) and a landing on a higher surface than planned (`collision`: the foot meets a
block top or side before its planned touchdown), with the checker's tolerance (`TOL`,
1e-6 m). A landing on a lower surface is a fall: the robot continues from there. Where
a replayed snapshot moves a block under the standing robot (the snapshots follow the
original planner's trajectory, not this one), the robot stands on the new surface (a
note is recorded). The run is finished when the robot stands within `0.05 rt` of the
goal (the reactive planner's goal tolerance in `y`).
"""

from __future__ import annotations

import math

import numpy as np

from .._core.params import Hopper, check_noise, disturbance_for
from .._models.flight import COLLISION, RESULT_NAMES
from ..mppc import (
    MPPC,
    Course,
    Jump,
    Observer,
    Replanner,
    Robot,
    Settings,
    check_jump,
    run_course,
)
from ..mppc._check import TOL
from ..mppc._run import ms_stats
from ._map import MARGIN, PARKOUR_FAILURES, RESTRICTED

#: The disturbances of a parkour run (`ground` has no meaning on a course).
PARKOUR_NOISE = ("none", "wind", "sensor", "landing")
_COLLISION = RESULT_NAMES[COLLISION]
_RESTRICTED = PARKOUR_FAILURES[RESTRICTED - 1]
_MARGIN = PARKOUR_FAILURES[MARGIN - 1]


def leg_disturbance(noise: str, robot: Robot):
    """`(sensor, wind, landing)` half-widths / acceleration of `noise` for the MPPC leg.

    `disturbance_for` with the leg as a hopper (`rho0 = r_takeoff`, its `g`): sensor noise
    on the contact point and landing noise `0.05 rt`, wind `-0.2 g / 9.81`.
    """
    d = disturbance_for(check_noise(noise, PARKOUR_NOISE),
                        Hopper(g=robot.g, rho0=robot.r_takeoff))
    return float(d.sensor[0]), float(d.wind), float(d.landing)


#: The room the disturbed runs' planner is sized for (`Settings.room_max`, m).
ROOM_MAX = 0.03


def run_mppc_noisy(course: Course, noise: str = "none", seed: int = 0,
                   planner: MPPC | None = None, max_jumps: int = 60,
                   observer: Observer | None = None) -> dict:
    """One MPPC run under a disturbance; the `parkour` result keys plus `success`.

    `planner`: default `MPPC(settings=Settings(room_max=ROOM_MAX))`; `observer`: default
    `Observer(room_max=planner.settings.room_max)` (a fresh one per run; the `none`
    disturbance runs `run_course`, without it). The result adds `wind_estimate` and
    `room` (the observer's last values).
    """
    planner = planner or MPPC(settings=Settings(room_max=ROOM_MAX))
    sensor, wind, land = leg_disturbance(noise, planner.robot)
    robot: Robot = planner.robot
    if noise == "none":
        out = run_course(course, planner).to_json()
        out["success"] = bool(out["finished"] and out["violations"] == 0)
        out["noise"] = "none"
        return out
    rng = np.random.default_rng(seed)
    leg = robot.r_takeoff
    tol = 0.05 * leg
    x = course.start
    z = float(course.environment_at(0).surface(x))
    obs = observer or Observer(room_max=planner.settings.room_max)
    replan = Replanner(planner, course)
    replan.warm_up(x, z, 3, wind=0.0)  # compile (the wind is a traced argument)
    executed, replan_ms, violations, notes = [], [], [], []
    failure = None
    finished = False
    last = None  # (planned landing, flight time, wind planned for) of the last jump
    for k in range(max_jumps):
        if abs(x - course.goal) <= tol:
            finished = True
            break
        x_meas = x + rng.uniform(-1.0, 1.0) * sensor
        z_here = float(course.environment_at(k).surface(x))
        if abs(z_here - z) > 1e-9:  # a snapshot moved a block under the standing robot
            notes.append(f"replan {k}: the surface under the robot at x={x:.3f} moved from "
                         f"z={z:.3f} to {z_here:.3f}; it stands on the new surface")
            z = z_here
        if last is not None:
            obs.update(last[0], x_meas, last[1], last[2])
        a_est = obs.wind
        # The height of the surface it stands on is known (the sensor errs in x only).
        plan, env, ms = replan(k, x_meas, z, wind=a_est, room=obs.room)
        if plan is None and obs.room > 0:  # no plan keeps the room: plan without it
            plan, env, ms2 = replan(k, x_meas, z, wind=a_est, room=0.0)
            ms += ms2
        replan_ms.append(ms)
        if plan is None:
            failure = f"no solution at x={x:.3f}"
            break
        j = plan.jumps[0]
        shift = x - x_meas
        flown = Jump(x, z, j.v, j.theta, j.t, j.x1 + shift, j.z1)
        for kind, msg in check_jump(robot, course, env, flown, check_takeoff=False,
                                    wind=wind):
            if kind in ("foot_clearance", "knee_clearance", _COLLISION):
                violations.append({"jump": k, "kind": kind, "message": msg})
        last = (plan.nodes[1], j.t, a_est)
        # Planned for a_est, flown in the true wind: the landing moves by the difference.
        x1 = (plan.nodes[1] + shift + 0.5 * (wind - a_est) * j.t**2
              + rng.uniform(-1.0, 1.0) * land)
        z1 = float(env.surface(x1))
        if z1 > j.z1 + 1e-9:
            violations.append({"jump": k, "kind": _COLLISION,
                               "message": f"lands at {x1:.4f} on a surface {z1:.3f} above the "
                                          f"planned {j.z1:.3f}"})
        if np.any((env.restricted_lo + TOL < x1) & (x1 < env.restricted_hi - TOL)):
            violations.append({"jump": k, "kind": _RESTRICTED,
                               "message": f"lands at {x1:.4f} in a restricted area"})
        edges = np.concatenate([env.front, env.back])
        if edges.size and np.min(np.abs(x1 - edges)) < course.margin_h - TOL:
            violations.append({"jump": k, "kind": _MARGIN,
                               "message": f"lands at {x1:.4f} within the edge margin"})
        # The fall to a lower surface adds flight time.
        t = j.t + (math.sqrt(2.0 * (j.z1 - z1) / robot.g) if z1 < j.z1 else 0.0)
        executed.append({"xs": float(x), "zs": float(z), "v": float(j.v),
                         "theta": float(j.theta), "t": float(t), "x1": float(x1),
                         "z1": float(z1)})
        x, z = x1, z1
    else:
        failure = f"gave up after {max_jumps} jumps"
    if not finished and failure is None:
        failure = "not at the goal"
    return {
        "course": course.name, "planner": "mppc", "noise": noise, "seed": int(seed),
        "finished": bool(finished), "jumps": len(executed),
        "flight_time": float(sum(e["t"] for e in executed)),
        "replan_ms": ms_stats(replan_ms),
        "violations": len(violations), "violation_details": violations, "failure": failure,
        "executed": executed, "success": bool(finished and not violations),
        "wind_estimate": obs.wind, "room": obs.room, "notes": notes,
    }
