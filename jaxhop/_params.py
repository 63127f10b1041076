"""Physical parameters of the hopper: a small frozen pytree, never module constants."""

import equinox as eqx
import jax.numpy as jnp

from ._errors import InputError


class Hopper(eqx.Module):
    """Mass, gravity and leg rest length of the hopper (SI units).

    All three are traced leaves, so sweeping them does not recompile.
    """

    m: float = 80.0
    g: float = 9.81
    rho0: float = 1.0

    def __check_init__(self):
        for name in ("m", "g", "rho0"):
            value = getattr(self, name)
            if isinstance(value, (int, float)) and not (value > 0 and value < float("inf")):
                raise InputError(f"hopper.{name} must be a positive finite number, got {value}")


class Disturbance(eqx.Module):
    """Per-run disturbance settings (SPEC section 11).

    Attributes:
        wind: constant horizontal acceleration in every flight phase (m/s^2).
        sensor: half-widths of the uniform apex measurement noise on (y, z, ydot).
    """

    wind: float = 0.0
    sensor: jnp.ndarray = eqx.field(default_factory=lambda: jnp.zeros(3))


NOISE_KINDS = ("none", "wind", "sensor", "ground")
WIND_ACCEL = -0.2
SENSOR_HALF_WIDTH = (0.05, 0.05, 0.05)
GROUND_HALF_WIDTH = 0.15


def disturbance_for(noise: str) -> Disturbance:
    """The in-flight disturbance of a named noise kind (`ground` acts on the map instead)."""
    if noise not in NOISE_KINDS:
        raise InputError(f"noise must be one of {', '.join(NOISE_KINDS)}, got {noise!r}")
    if noise == "wind":
        return Disturbance(wind=WIND_ACCEL)
    if noise == "sensor":
        return Disturbance(sensor=jnp.asarray(SENSOR_HALF_WIDTH))
    return Disturbance()
