"""The MuJoCo hopper: an MJCF model generated from a `Hopper` and a terrain.

A planar spring-leg hopper (`docs/mujoco.md`). The body (mass `m`) moves on two slide
joints (`y` horizontal, `z` vertical; MuJoCo's `x` is jaxhop's `y`), so its rotation is
locked like the SLIP's point mass. The leg hangs from a hip hinge (angle `th`, the SLIP's
convention: `th > 0` puts the foot ahead of the body) and carries its mass half way down;
a prismatic joint sets the leg length `rho` from the hip to the centre of the foot sphere.
The joint's rest length is `rho0 - r` (foot radius `r`), so the foot's bottom is `rho0`
below a hip whose leg hangs vertically at rest, as the SLIP's foot is. The leg spring is
no MuJoCo element: the runner applies its force on the prismatic joint each step
(`jaxhop.mujoco._sim`).

Terrain blocks are boxes from their top height down to `DEPTH` below the lowest block;
holes are the gaps between them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._core.errors import InputError
from .._core.params import Hopper
from .._core.terrain import Terrain

# Blocks reach this far below the lowest block top (m, times rho0): below the hole depth.
DEPTH = 1.5
BODY_RADIUS = 0.05  # times rho0: the body's collision sphere


@dataclass(frozen=True)
class Mechanics:
    """What the MuJoCo hopper has beyond the SLIP, and how it is simulated.

    Attributes:
        leg_mass, foot_mass: masses as fractions of `m` (the leg's at `rho0 / 2` below the
            hip, the foot's at the foot); the default total is 5 % of `m`.
        foot_radius: radius of the foot sphere, times `rho0`.
        friction: sliding friction coefficient of foot and ground.
        hip_omega, leg_omega: natural frequencies (rad/s) of the critically damped hip
            and leg-length servos in flight; their gains scale with the leg's inertia.
        retract: leg length after liftoff, times `rho0` (until the next apex).
        swing: angle (rad) the hip turns the leg further back after liftoff, against the
            direction of motion, so that the retracting foot moves away from a step up
            just ahead of its foothold rather than into it.
        timestep: MuJoCo's step (s); `integrator`: MuJoCo's integrator name.
        contact_time: contact time constant (s) of `solref` (damping ratio 1).
        solimp: the first two numbers of MuJoCo's `solimp` (constraint impedance).
        noslip: MuJoCo's `noslip_iterations` (0: off): hard friction, no creep of a foot
            that sticks.
    """

    leg_mass: float = 0.03
    foot_mass: float = 0.02
    foot_radius: float = 0.002
    friction: float = 1.0
    hip_omega: float = 40.0
    leg_omega: float = 60.0
    retract: float = 0.5
    swing: float = 0.2
    timestep: float = 1e-3
    integrator: str = "implicitfast"
    contact_time: float = 2e-3
    solimp: tuple = (0.99, 0.999)
    noslip: int = 0

    def __post_init__(self):
        for name in ("leg_mass", "foot_mass", "foot_radius", "friction", "hip_omega",
                     "leg_omega", "retract", "timestep", "contact_time"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 < value < float("inf")):
                raise InputError(f"mechanics.{name} must be a positive finite number, "
                                 f"got {value!r}")
        if not (isinstance(self.swing, (int, float)) and 0 <= self.swing < 1.5):
            raise InputError(f"mechanics.swing must be in [0, 1.5) rad, got {self.swing!r}")
        if self.retract > 1 or self.foot_radius >= 0.5:
            raise InputError("mechanics: retract must be at most 1 and foot_radius below 0.5")
        if self.contact_time < 2 * self.timestep:
            raise InputError(f"mechanics.contact_time must be at least twice the timestep "
                             f"({2 * self.timestep:g} s), got {self.contact_time:g}")
        if self.integrator not in ("Euler", "RK4", "implicit", "implicitfast"):
            raise InputError(f"mechanics.integrator: unknown {self.integrator!r}")

    def replace(self, **changes) -> Mechanics:
        return dataclasses.replace(self, **changes)


#: The default mechanics.
DEFAULT = Mechanics()
#: Near-massless leg, stiff servos, hard contact, small steps: the SLIP's idealisation,
#: for the cross-check of the two simulators.
IDEAL = Mechanics(leg_mass=1e-5, foot_mass=1e-5, foot_radius=1e-3, friction=3.0,
                  timestep=1e-4, integrator="RK4", contact_time=5e-4, noslip=10)


def _f(x) -> str:
    return " ".join(f"{float(v):.12g}" for v in np.atleast_1d(x))


def hopper_xml(hopper: Hopper, terrain: Terrain, mech: Mechanics = DEFAULT) -> str:
    """The MJCF text of the hopper over `terrain`."""
    m, g, rho0 = float(hopper.m), float(hopper.g), float(hopper.rho0)
    r = mech.foot_radius * rho0
    m_leg, m_foot = mech.leg_mass * m, mech.foot_mass * m
    bottom = float(np.min(terrain.heights)) - DEPTH * rho0
    boxes = []
    for i, (s, e, h) in enumerate(terrain.blocks()):
        centre, half = [(s + e) / 2, 0, (h + bottom) / 2], [(e - s) / 2, rho0, (h - bottom) / 2]
        boxes.append(f'    <geom name="block{i}" type="box" pos="{_f(centre)}" size="{_f(half)}"/>')
    # Thin-rod inertia of the leg about its centre; a tiny floor keeps MuJoCo's inertia valid.
    i_leg = max(m_leg * rho0**2 / 12.0, 1e-9)
    i_foot = max(0.4 * m_foot * r**2, 1e-12)
    return f"""<mujoco model="jaxhop-hopper">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{_f(mech.timestep)}" integrator="{mech.integrator}" gravity="0 0 {-g:.12g}"
          cone="elliptic" impratio="10" noslip_iterations="{mech.noslip}"/>
  <default>
    <geom contype="1" conaffinity="1" condim="3" friction="{_f([mech.friction, 0, 0])}"
          solref="{_f([mech.contact_time, 1.0])}" solimp="{_f(mech.solimp)} 0.001 0.5 2"/>
  </default>
  <worldbody>
{chr(10).join(boxes)}
    <body name="body">
      <joint name="y" type="slide" axis="1 0 0"/>
      <joint name="z" type="slide" axis="0 0 1"/>
      <geom name="body" type="sphere" size="{_f(BODY_RADIUS * rho0)}" mass="{_f(m)}"
            contype="2" conaffinity="1"/>
      <body name="leg">
        <joint name="hip" type="hinge" axis="0 -1 0"/>
        <inertial pos="0 0 {_f(-rho0 / 2)}" mass="{_f(max(m_leg, 1e-9))}"
                  diaginertia="{_f([i_leg, i_leg, 1e-9])}"/>
        <body name="foot" pos="0 0 {_f(-(rho0 - r))}">
          <joint name="leg" type="slide" axis="0 0 -1"/>
          <geom name="foot" type="sphere" size="{_f(r)}" contype="2" conaffinity="1"/>
          <inertial pos="0 0 0" mass="{_f(max(m_foot, 1e-9))}" diaginertia="{_f([i_foot] * 3)}"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="hip" joint="hip"/>
    <motor name="leg" joint="leg"/>
  </actuator>
</mujoco>
"""
