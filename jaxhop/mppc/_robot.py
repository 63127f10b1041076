"""The hopping leg of the MPPC paper (seed 004): bounds and the eqs 1-4 offsets."""

import math

import equinox as eqx
import jax.numpy as jnp


class Robot(eqx.Module):
    """Point-mass hopping leg with a fixed flight configuration (docs/mppc.md, "Model").

    All fields are static Python floats: they are the paper's constants, not swept values.
    Angles are in radians from the horizontal; lengths in metres; times in seconds.
    """

    v_min: float = eqx.field(static=True, default=1.5)
    v_max: float = eqx.field(static=True, default=2.7)
    theta_min: float = eqx.field(static=True, default=math.radians(65.0))
    theta_max: float = eqx.field(static=True, default=math.radians(85.0))
    t_min: float = eqx.field(static=True, default=0.2)
    t_max: float = eqx.field(static=True, default=3.0)
    r_takeoff: float = eqx.field(static=True, default=0.19)
    r_flight: float = eqx.field(static=True, default=0.17)
    theta_flight: float = eqx.field(static=True, default=math.radians(94.0))
    l2: float = eqx.field(static=True, default=0.15)
    alpha_flight: float = eqx.field(static=True, default=math.radians(30.518))
    g: float = eqx.field(static=True, default=8.0665)

    def __check_init__(self):
        if not (0 < self.v_min <= self.v_max):
            raise ValueError("Robot: need 0 < v_min <= v_max")
        if not (0 < self.theta_min <= self.theta_max < math.pi / 2):
            raise ValueError("Robot: need 0 < theta_min <= theta_max < pi/2")
        if not (0 < self.t_min <= self.t_max):
            raise ValueError("Robot: need 0 < t_min <= t_max")

    @property
    def foot_from_hip(self) -> tuple[float, float]:
        """Foot relative to the hip in the flight configuration: `-rf (cos, sin) theta_f`."""
        return (
            -self.r_flight * math.cos(self.theta_flight),
            -self.r_flight * math.sin(self.theta_flight),
        )

    @property
    def knee_from_foot(self) -> tuple[float, float]:
        """Knee relative to the foot in flight: `l2 (-cos, sin) alpha_f` (eqs 3-4)."""
        return (-self.l2 * math.cos(self.alpha_flight), self.l2 * math.sin(self.alpha_flight))

    @property
    def knee_from_hip(self) -> tuple[float, float]:
        fx, fz = self.foot_from_hip
        kx, kz = self.knee_from_foot
        return (fx + kx, fz + kz)


def foot_offset(robot: Robot, theta):
    """Eqs 1-2: foot in flight relative to the takeoff contact point, `(c_xe, c_ze)`.

    **Arguments:**
    - `robot`: the leg.
    - `theta`: takeoff angle(s) in radians (NumPy or JAX array, or float).

    **Returns:** the pair `(c_xe, c_ze)`, broadcast like `theta`.
    """
    fx, fz = robot.foot_from_hip
    return robot.r_takeoff * jnp.cos(theta) + fx, robot.r_takeoff * jnp.sin(theta) + fz


def knee_offset(robot: Robot, theta):
    """Eqs 3-4: knee in flight relative to the takeoff contact point, `(c_xk, c_zk)`.

    **Arguments:**
    - `robot`: the leg.
    - `theta`: takeoff angle(s) in radians.

    **Returns:** the pair `(c_xk, c_zk)`, broadcast like `theta`.
    """
    kx, kz = robot.knee_from_hip
    return robot.r_takeoff * jnp.cos(theta) + kx, robot.r_takeoff * jnp.sin(theta) + kz
