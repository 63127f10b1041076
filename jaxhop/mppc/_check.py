"""Independent checker of an executed jump: dense samples of the foot and knee paths.

Written apart from the planner's closed forms: it integrates nothing analytically, but
samples the ballistic flight of the hip (eqs 6-9) at many instants, places the foot and
knee with the flight-configuration offsets, and tests every rule on the samples (faces
are located by linear interpolation between samples). A flight in wind (a constant
horizontal acceleration `a`) adds `a tau^2 / 2` to the hip's horizontal position at time
`tau`.
"""

import math

import numpy as np

from ._course import Course, Environment
from ._robot import Robot

TOL = 1e-6  # metres / relative, far above the planner's rounding, far below any margin
N_SAMPLES = 4001

KINDS = ("bounds", "takeoff_height", "landing_height", "edge_margin", "restricted",
         "foot_clearance", "knee_clearance", "collision")


def _paths(robot: Robot, xs, zs, v, theta, t, wind=0.0):
    tau = np.linspace(0.0, t, N_SAMPLES)
    hip_x = xs + robot.r_takeoff * math.cos(theta) + v * math.cos(theta) * tau
    if wind:
        hip_x = hip_x + 0.5 * wind * tau**2
    hip_z = (zs + robot.r_takeoff * math.sin(theta) + v * math.sin(theta) * tau
             - 0.5 * robot.g * tau**2)
    foot_dx = -robot.r_flight * math.cos(robot.theta_flight)
    foot_dz = -robot.r_flight * math.sin(robot.theta_flight)
    knee_dx = foot_dx - robot.l2 * math.cos(robot.alpha_flight)
    knee_dz = foot_dz + robot.l2 * math.sin(robot.alpha_flight)
    return (hip_x + foot_dx, hip_z + foot_dz), (hip_x + knee_dx, hip_z + knee_dz)


def _heights_at_face(px, pz, face):
    # Lowest height where a sampled path passes x = face (by interpolation; in strong wind
    # the path need not move forward all the way, so every crossing counts).
    d = px - face
    k = np.nonzero(((d[:-1] < 0) & (d[1:] >= 0)) | ((d[:-1] > 0) & (d[1:] <= 0)))[0]
    if not (px.min() < face < px.max()) or not k.size:
        return None
    w = (face - px[k]) / (px[k + 1] - px[k])
    return float(np.min(pz[k] + w * (pz[k + 1] - pz[k])))


def check_jump(robot: Robot, course: Course, env: Environment, jump,
               check_takeoff: bool = True, wind: float = 0.0) -> list:
    """All constraint violations of one executed jump.

    Rules: eq 5 bounds on `v`, `theta`, `t`; takeoff on the surface; the landing contact
    (eqs 8-9) on the surface under it, at least `Mh` from every block edge and outside
    every restricted area; the foot passing a block front and the knee passing a block
    back at least `Mv` above its top; neither foot nor knee inside a block during the
    flight, or the knee at touchdown.

    **Arguments:**
    - `robot`, `course`, `env`: the leg, the course (margins) and the environment in force.
    - `jump`: anything with `xs, zs, v, theta, t` (the landing is recomputed here).
    - `check_takeoff`: also require the takeoff on the surface of `env` (a run turns this
      off when a snapshot moved a block under the standing robot).
    - `wind`: the horizontal acceleration the jump is flown in (m/s^2; the hip's path
      and the landing point include it; 0: still air).

    **Returns:** a list of `(kind, message)` pairs, empty for a clean jump; `kind` is one
    of `KINDS`.
    """
    out = []
    xs, zs, v, th, t = (float(jump.xs), float(jump.zs), float(jump.v), float(jump.theta),
                        float(jump.t))
    if not (robot.v_min * (1 - TOL) <= v <= robot.v_max * (1 + TOL)):
        out.append(("bounds", f"takeoff speed {v:.4f} outside [{robot.v_min}, {robot.v_max}]"))
    if not (robot.theta_min - TOL <= th <= robot.theta_max + TOL):
        out.append(("bounds", f"takeoff angle {math.degrees(th):.3f} deg out of bounds"))
    if not (robot.t_min * (1 - TOL) <= t <= robot.t_max * (1 + TOL)):
        out.append(("bounds", f"flight time {t:.4f} outside [{robot.t_min}, {robot.t_max}]"))
    if t <= 0:
        return out
    surf0 = float(env.surface(xs))
    if check_takeoff and abs(zs - surf0) > TOL:
        out.append(("takeoff_height", f"takeoff at z={zs:.4f}, surface there is {surf0:.4f}"))
    (fx, fz), (kx, kz) = _paths(robot, xs, zs, v, th, t, float(wind))
    x1, z1 = fx[-1], fz[-1]
    surf1 = float(env.surface(x1))
    if abs(z1 - surf1) > TOL:
        out.append(("landing_height", f"lands at ({x1:.4f}, {z1:.4f}), surface is {surf1:.4f}"))
    for a, b in zip(env.front, env.back):
        for edge in (a, b):
            if abs(x1 - edge) < course.margin_h - TOL:
                out.append(("edge_margin", f"lands at {x1:.4f}, {abs(x1 - edge):.4f} from an "
                                           f"edge at {edge:.4f}"))
    for a, b in zip(env.restricted_lo, env.restricted_hi):
        if a + TOL < x1 < b - TOL:
            out.append(("restricted", f"lands at {x1:.4f} in restricted area [{a:.3f}, {b:.3f}]"))
    for a, b, h in zip(env.front, env.back, env.height):
        z_face = _heights_at_face(fx, fz, a)
        if z_face is not None and z_face < h + course.margin_v - TOL:
            out.append(("foot_clearance", f"foot passes block front {a:.3f} at z={z_face:.4f} "
                                          f"< {h:.3f} + Mv"))
        z_face = _heights_at_face(kx, kz, b)
        if z_face is not None and z_face < h + course.margin_v - TOL:
            out.append(("knee_clearance", f"knee passes block back {b:.3f} at z={z_face:.4f} "
                                          f"< {h:.3f} + Mv"))
        for name, px, pz in (("foot", fx, fz), ("knee", kx, kz)):
            inside = (px > a + TOL) & (px < b - TOL) & (pz < h - TOL)
            faces = [_heights_at_face(px, pz, e) for e in (a, b)]
            if inside.any() or any(f is not None and f < h - TOL for f in faces):
                where = float(px[np.argmax(inside)]) if inside.any() else a
                out.append(("collision", f"{name} enters block [{a:.3f}, {b:.3f}] near "
                                         f"x={where:.3f}"))
    return out
