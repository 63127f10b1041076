"""One stride of the MuJoCo hopper at a time: servoes, the leg spring and the phase events.

A stride runs from an apex to the next apex in four phases (`docs/mujoco.md`):

- descent: the hip servo turns the leg to the touchdown angle, the leg servo extends it to
  its rest length;
- compression, from the first foot contact: no hip torque (a free pivot, as the SLIP's
  massless leg), the leg force `kc (rho0 - rho)` on the prismatic joint;
- decompression, from the bottom (the rate of the body's distance from the foothold
  crossing zero: the SLIP's `rho'`; the leg joint's own rate also carries the foot's
  vibration on the contact): `kd (rho0 - rho)`;
- ascent, from the foot's liftoff: the hip servo holds the leg at its liftoff angle (a
  leg swung forward low catches the side of a step up), the leg servo retracts it; the
  stride ends where the body's vertical velocity crosses zero.

The forces are computed in Python each step and applied through two motors. A wind (a
horizontal acceleration `wind` in flight, jaxhop's `Disturbance.wind`) is a horizontal
force of its mass times `wind` on every moving body in descent and ascent, none in stance
(`data.xfrc_applied`): in flight the whole hopper accelerates at `wind`, as jaxhop's point
mass. `descent_state` looks ahead in a descent on a copy of the state (the adaptive
controller's descent measurement). Failures are
`Result` codes, as jaxhop's stride: `COLLISION` (the body touching a block, the foot
hitting a block's side or touching one in ascent, a leg collapsed below
`COLLAPSED rho0`, a liftoff that does not rise, a phase that never ends), `HOLE` (the
foot more than `rho0` below the lowest block top), `OFF_MAP` (the foot outside the map's
`y` range) and `SLIP` (the foot slid more than `SLIDE_LIMIT rho0` in one stance).
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from .._core.params import Hopper
from .._core.result import Result
from .._core.terrain import Terrain
from .._models.slip.stride import COLLAPSED
from ._model import DEFAULT, IDEAL, Mechanics, hopper_xml

DESCENT, COMPRESSION, DECOMPRESSION, ASCENT = range(4)
PHASES = ("descent", "compression", "decompression", "ascent")
#: Sliding of the foot in one stance (times rho0) beyond which the stride fails with `SLIP`.
SLIDE_LIMIT = 0.01
#: A foot contact whose normal is less steep than this (its z component) is a wall hit.
WALL_NORMAL = 0.7
#: The foot has lifted off once its bottom is this far (times rho0) above the touchdown
#: point: MuJoCo drives a held contact's penetration to zero, so the contact itself comes
#: and goes between steps of a loaded stance.
LIFTED = 5e-4
PHASE_T_MAX = 5.0  # s


class Stride(NamedTuple):
    """What one stride did: `code` (`Result`), the next apex `(y, z, ydot)` of the body
    (NaN on a failure), the foothold `(y, h)` (NaN before a touchdown), the state at the
    bottom of the stance `(rho, th, rho', th')` relative to the foot (SLIP's polar
    coordinates), how far the foot slid (m) and, for a failure, what happened."""

    code: int
    apex: np.ndarray
    foothold: np.ndarray
    bottom: np.ndarray
    slide: float
    why: str = ""


class Simulator:
    """The MuJoCo hopper over one terrain: `reset` to an apex, then `stride` after stride.

    Arguments:
        hopper: the SLIP's `m`, `g`, `rho0`.
        terrain: the true terrain (its blocks become boxes).
        mech: the `Mechanics` (masses, foot, friction, servoes, contact, timestep).
    """

    def __init__(self, hopper: Hopper, terrain: Terrain, mech: Mechanics = DEFAULT):
        self.hopper, self.terrain, self.mech = hopper, terrain, mech
        self.model = mujoco.MjModel.from_xml_string(hopper_xml(hopper, terrain, mech))
        self.data = mujoco.MjData(self.model)
        m = self.model
        joint = {n: m.joint(n) for n in ("y", "z", "hip", "leg")}
        self.qi = {n: int(j.qposadr[0]) for n, j in joint.items()}
        self.vi = {n: int(j.dofadr[0]) for n, j in joint.items()}
        self.foot = m.geom("foot").id
        self.body = m.geom("body").id
        rho0, mass = float(hopper.rho0), float(hopper.m)
        self.rho0, self.g = rho0, float(hopper.g)
        self.r = mech.foot_radius * rho0
        self.rest = rho0 - self.r  # hip to foot centre at rest
        m_leg, m_foot = mech.leg_mass * mass, mech.foot_mass * mass
        i_hip = m_leg * rho0**2 / 3.0 + m_foot * self.rest**2
        self.hip_gains = (i_hip * mech.hip_omega**2, 2.0 * i_hip * mech.hip_omega)
        self.leg_gains = (m_foot * mech.leg_omega**2, 2.0 * m_foot * mech.leg_omega)
        self.h_min = float(np.min(terrain.heights))
        self.y_range = terrain.y_range
        self._vel = np.zeros(6)
        self._ahead = mujoco.MjData(self.model)  # the copy `descent_state` steps
        # every moving body's mass: the wind force per unit acceleration (world body 0 none)
        self._masses = np.array(self.model.body_mass)
        self._masses[0] = 0.0

    def _wind(self, data, wind: float):
        """Set the wind force of a flight phase (`wind = 0`: none) on every moving body."""
        data.xfrc_applied[:, 0] = self._masses * wind

    # --- state ---------------------------------------------------------------------------

    def reset(self, apex, th: float = 0.0, length: float | None = None):
        """Put the body at rest vertically at `apex = (y, z, ydot)` with the leg at angle
        `th` and foot-bottom length `length` (default `rho0`), moving with the body."""
        d = self.data
        mujoco.mj_resetData(self.model, d)
        length = self.rho0 if length is None else length
        d.qpos[self.qi["y"]], d.qpos[self.qi["z"]] = apex[0], apex[1]
        d.qpos[self.qi["hip"]] = th
        d.qpos[self.qi["leg"]] = length - self.rho0
        d.qvel[self.vi["y"]] = apex[2]
        mujoco.mj_forward(self.model, d)

    def body_state(self) -> np.ndarray:
        """`(y, z, ydot, zdot)` of the body."""
        q, v = self.data.qpos, self.data.qvel
        return np.array([q[self.qi["y"]], q[self.qi["z"]], v[self.vi["y"]], v[self.vi["z"]]])

    def foot_point(self) -> np.ndarray:
        """The bottom of the foot sphere `(y, z)` when the leg is upright; its centre
        shifted by `r` down (the point a touchdown or a hole is judged by)."""
        c = self.data.geom_xpos[self.foot]
        return np.array([c[0], c[2] - self.r])

    def _contacts(self):
        """`(dist, normal_z, point, body_hit)` of the foot's nearest listed contact (dist
        `inf` when none; `point` on the block's surface) and whether the body touches a
        block."""
        d = self.data
        dist, nz, point, body = np.inf, 0.0, None, False
        for i in range(d.ncon):
            c = d.contact[i]
            g1, g2 = int(c.geom1), int(c.geom2)
            if self.body in (g1, g2):
                body = True
            elif self.foot in (g1, g2) and c.dist < dist:
                # the point on the block's surface (c.pos lies half way into the penetration)
                n = np.array(c.frame[:3]) * (1.0 if g2 == self.foot else -1.0)
                dist, nz, point = float(c.dist), abs(float(n[2])), c.pos - 0.5 * c.dist * n
        return dist, nz, point, body

    def _slip_speed(self, point) -> float:
        """Horizontal speed of the foot's material point at the contact `point`."""
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_GEOM, self.foot,
                                 self._vel, 0)
        w, v = self._vel[:3], self._vel[3:]
        arm = point - self.data.geom_xpos[self.foot]
        return abs(v[0] + w[1] * arm[2] - w[2] * arm[1])

    def descent_state(self, t: float, wind: float = 0.0) -> np.ndarray:
        """The body's `(y, z, ydot)` `t` seconds after the apex the simulator stands at, on
        a copy of its state flown in descent: the hip and leg servos (the descent's gains)
        hold the leg at its present angle and length, the wind force on. The leg held, the
        body flies as the whole hopper (a leg extending would push the body back and
        forth). The state a stride ends at lies up to one step past its apex (`stride`): the
        copy flies the rest of `t` from there, its last fraction of a step (or back to `t`
        when that lies before) on the ballistic flight. The simulator's own state is left
        as it is."""
        m, d = self.model, self._ahead
        mujoco.mj_copyData(d, m, self.data)
        iy, iz, ih, il = (self.qi[n] for n in ("y", "z", "hip", "leg"))
        jy, jz, jh, jl = (self.vi[n] for n in ("y", "z", "hip", "leg"))
        (hp, hv), (lp, lv) = self.hip_gains, self.leg_gains
        q, v, ctrl = d.qpos, d.qvel, d.ctrl
        hold, length = float(q[ih]), float(q[il])
        self._wind(d, wind)
        left = float(t) + min(float(v[jz]), 0.0) / self.g  # the apex was this long ago
        dt = m.opt.timestep
        for _ in range(max(int(np.floor(left / dt + 1e-9)), 0)):
            ctrl[0] = hp * (hold - q[ih]) - hv * v[jh]
            ctrl[1] = lp * (length - q[il]) - lv * v[jl]
            mujoco.mj_step(m, d)
            left -= dt
        return np.array([q[iy] + v[jy] * left + 0.5 * wind * left**2,
                         q[iz] + v[jz] * left - 0.5 * self.g * left**2, v[jy] + wind * left])

    # --- one stride ------------------------------------------------------------------------

    def stride(self, u, kd_at_bottom=None, record: list | None = None,
               every: float = 0.01, wind: float = 0.0) -> Stride:
        """From the current apex to the next: touchdown angle `th`, stiffnesses `kc`, `kd`.

        Arguments:
            u: `(th_td, kc, kd)`.
            kd_at_bottom: optional `f(bottom, foothold) -> kd` called at the bottom of the
                stance (the adaptive controller's energy feedback); its result replaces `kd`.
            record: a list that receives `(t, y, z, foot_y, foot_z, in_stance)` rows every
                `every` seconds.
            wind: horizontal acceleration (m/s^2) of the hopper in descent and ascent.
        """
        m, d = self.model, self.data
        th_td, kc, kd = (float(x) for x in u)
        iy, iz, ih, il = (self.qi[n] for n in ("y", "z", "hip", "leg"))
        jy, jz, jh, jl = (self.vi[n] for n in ("y", "z", "hip", "leg"))
        (hp, hv), (lp, lv) = self.hip_gains, self.leg_gains
        retract = (self.mech.retract - 1.0) * self.rho0
        collapsed = COLLAPSED * self.rho0 - self.rest
        lifted = LIFTED * self.rho0
        hole = self.h_min - self.rho0
        y_lo, y_hi = self.y_range
        q, v, ctrl, xpos = d.qpos, d.qvel, d.ctrl, d.geom_xpos
        foot_id, r, g = self.foot, self.r, self.g
        dt = m.opt.timestep
        phase, t_phase, k = DESCENT, 0.0, kc
        foothold = np.full(2, np.nan)
        bottom = np.full(4, np.nan)
        slide = 0.0
        next_rec = d.time
        nan3 = np.full(3, np.nan)
        fy = fh = th_lo = 0.0

        def out(code, why="", apex=nan3):
            self._wind(d, 0.0)
            return Stride(int(code), apex, foothold, bottom, slide, why)

        wind = float(wind)
        self._wind(d, wind)

        while True:
            if phase == DESCENT:
                ctrl[0] = hp * (th_td - q[ih]) - hv * v[jh]
                ctrl[1] = -lp * q[il] - lv * v[jl]
            elif phase == ASCENT:
                ctrl[0] = hp * (th_lo - q[ih]) - hv * v[jh]
                ctrl[1] = lp * (retract - q[il]) - lv * v[jl]
            else:
                ctrl[0] = 0.0
                ctrl[1] = -k * q[il]
            mujoco.mj_step(m, d)
            t_phase += dt
            if record is not None and d.time >= next_rec:
                record.append((d.time, q[iy], q[iz], xpos[foot_id, 0], xpos[foot_id, 2] - r,
                               phase in (COMPRESSION, DECOMPRESSION)))
                next_rec += every
            dist, nz, point, body_hit = self._contacts() if d.ncon else (np.inf, 0.0, None,
                                                                           False)
            if body_hit or t_phase > PHASE_T_MAX or q[il] < collapsed:
                why = ("body on a block" if body_hit else "leg collapsed"
                       if q[il] < collapsed else "phase never ended")
                return out(Result.COLLISION, f"{why} ({PHASES[phase]})")
            if phase == DESCENT:
                if dist <= 0.0:
                    if nz < WALL_NORMAL:
                        return out(Result.COLLISION, "foot hit a block's side")
                    phase, t_phase = COMPRESSION, 0.0
                    self._wind(d, 0.0)
                    foothold = np.array([point[0], point[2]])
                    fy, fh = point[0], point[2]
                elif xpos[foot_id, 2] - r < hole:
                    return out(Result.HOLE, "foot fell into a hole")
                elif not y_lo <= xpos[foot_id, 0] <= y_hi:
                    return out(Result.OFF_MAP, "foot left the map")
            elif phase == ASCENT:
                if dist <= 0.0:
                    return out(Result.COLLISION, "foot touched a block in ascent")
                if v[jz] <= 0.0:
                    # the apex lies within one step before: go back along the parabola
                    back = v[jz] / g
                    return out(Result.SUCCESS, "", np.array([
                        q[iy] + v[jy] * back + 0.5 * wind * back**2,
                        q[iz] + 0.5 * v[jz] * back, v[jy] + wind * back]))
            else:
                if dist <= 0.0:
                    slide += self._slip_speed(point) * dt
                    if slide > SLIDE_LIMIT * self.rho0:
                        return out(Result.SLIP, f"foot slid {slide:.3f} m")
                if phase == COMPRESSION:
                    # the SLIP's rho' >= 0: the body's velocity along the leg
                    if (q[iy] - fy) * v[jy] + (q[iz] - fh) * v[jz] >= 0.0:
                        phase, t_phase, bottom = DECOMPRESSION, 0.0, self._polar(foothold)
                        if kd_at_bottom is not None:
                            k = float(kd_at_bottom(bottom, foothold))
                        else:
                            k = kd
                elif xpos[foot_id, 2] - r - fh > lifted:
                    if v[jz] <= 0.0:
                        return out(Result.COLLISION, "liftoff without rising")
                    phase, t_phase = ASCENT, 0.0
                    self._wind(d, wind)
                    th_lo = q[ih] - np.copysign(self.mech.swing, v[jy])

    def _polar(self, foothold) -> np.ndarray:
        """The body's state about the foothold in the SLIP's polar coordinates."""
        y, z, ydot, zdot = self.body_state()
        dy, dz = y - foothold[0], z - foothold[1]
        rho = np.hypot(dy, dz)
        th = np.arctan2(-dy, dz)
        e_r = np.array([-np.sin(th), np.cos(th)])
        e_th = np.array([-np.cos(th), -np.sin(th)])
        vel = np.array([ydot, zdot])
        return np.array([rho, th, vel @ e_r, (vel @ e_th) / rho])


def ideal_simulator(hopper: Hopper, terrain: Terrain) -> Simulator:
    """A simulator with the SLIP's idealisation (`IDEAL`): the cross-check's."""
    return Simulator(hopper, terrain, IDEAL)
