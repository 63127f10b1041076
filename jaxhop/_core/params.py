"""Physical parameters of the hopper: a small frozen pytree, never module constants."""

import math

import equinox as eqx
import jax.numpy as jnp

from .errors import InputError


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


#: The hopper the paper's templates (eq 33) and disturbances (section VI-C) were written for:
#: `m` (kg), `g` (m/s^2), `rho0` (m).
REFERENCE_HOPPER = (80.0, 9.81, 1.0)


def froude_scales(hopper) -> dict:
    """Froude scale factors of `hopper` against `REFERENCE_HOPPER`.

    Lengths scale with `rho0`, speeds with `sqrt(g rho0)`, energies with `m g rho0`; angles
    and the velocity gain `k` are dimensionless. Each factor is a ratio of the two hoppers'
    scales, computed so that it is exactly `1.0` for the reference hopper.

    Returns:
        `{"length", "velocity", "energy"}` as Python floats.
    """
    m0, g0, l0 = REFERENCE_HOPPER
    m, g, l = float(hopper.m), float(hopper.g), float(hopper.rho0)
    length = l / l0
    return {"length": length, "velocity": math.sqrt((g / g0) * length),
            "energy": (m / m0) * (g / g0) * length}


def float_array(x):
    """`x` as a float array, one type whatever the caller passes (a Python float is weakly
    typed, a NumPy or JAX scalar is not): a compiled run program is chosen by its arguments'
    types, so `wind=0.2` and `wind=np.float64(0.2)` would each compile one of their own. The
    converter of the run settings' float fields."""
    return jnp.asarray(x, dtype=jnp.result_type(float))


class Disturbance(eqx.Module):
    """Per-run disturbance settings (`docs/decisions.md`, "Disturbances"), float arrays
    whatever their type as given.

    Attributes:
        wind: constant horizontal acceleration in every flight phase (m/s^2).
        sensor: half-widths of the uniform apex measurement noise on (y, z, ydot).
        landing: half-width of the uniform horizontal error of each landing (m).
    """

    wind: jnp.ndarray = eqx.field(default=0.0, converter=float_array)
    sensor: jnp.ndarray = eqx.field(default_factory=lambda: jnp.zeros(3),
                                    converter=float_array)
    landing: jnp.ndarray = eqx.field(default=0.0, converter=float_array)


#: Named disturbances. `ground` perturbs the perceived map (`perceived_terrain`), not the
#: flight; `landing` shifts every landing point. Terrains and parkour courses share them.
NOISE_KINDS = ("none", "wind", "sensor", "ground", "landing")
WIND_ACCEL = -0.2
SENSOR_HALF_WIDTH = (0.05, 0.05, 0.05)
GROUND_HALF_WIDTH = 0.15
LANDING_HALF_WIDTH = 0.05


def noise_parts(noise: str, kinds=NOISE_KINDS, field: str = "noise") -> tuple[str, ...]:
    """The kinds of a noise name: one of `kinds`, or several joined by `+` (`wind+sensor`).

    Raises:
        InputError: one line naming `field`: an unknown or empty kind, a kind given twice, or
            `none` joined with others.
    """
    choices = f"choose from {', '.join(kinds)}, or several joined by '+', e.g. wind+sensor"
    if not isinstance(noise, str):
        raise InputError(f"{field}: invalid choice {noise!r} ({choices})")
    parts = tuple(noise.split("+"))
    for part in parts:
        if part == "":
            raise InputError(f"{field}: invalid choice {noise!r}, an empty kind ({choices})")
        if part not in kinds:
            where = f" in {noise!r}" if len(parts) > 1 else ""
            raise InputError(f"{field}: invalid choice {part!r}{where} ({choices})")
    if len(parts) > 1 and "none" in parts:
        raise InputError(f"{field}: 'none' cannot be joined with other kinds, got {noise!r}")
    twice = sorted({p for p in parts if parts.count(p) > 1})
    if twice:
        raise InputError(f"{field}: {twice[0]!r} is given twice in {noise!r}")
    return parts


def check_noise(noise: str, kinds=NOISE_KINDS, field: str = "noise") -> str:
    """`noise` if it names one of `kinds` or several joined by `+` (`noise_parts`)."""
    noise_parts(noise, kinds, field)
    return noise


def has_ground(noise: str) -> bool:
    """Whether `ground` noise (a perceived map, `perceived_terrain`) is among the kinds."""
    return "ground" in noise_parts(noise)


def disturbance_for(noise: str, hopper=None) -> Disturbance:
    """The in-flight disturbance of a noise name (`ground` acts on the map instead).

    Several kinds joined by `+` (`wind+sensor`) act together: each sets its own field of the
    `Disturbance`. With `hopper`, the paper's values (written for the 80 kg, 1 m hopper) are
    Froude-scaled to it: wind with `g`, sensor noise on positions and landings with `rho0`,
    on speed with `sqrt(g rho0)`. Without, they are used as they are.
    """
    parts = noise_parts(noise)
    if hopper is None:
        length = velocity = 1.0
        wind = WIND_ACCEL
    else:
        f = froude_scales(hopper)
        length, velocity = f["length"], f["velocity"]
        wind = WIND_ACCEL * float(hopper.g) / REFERENCE_HOPPER[1]
    fields = {}
    if "wind" in parts:
        fields["wind"] = wind
    if "sensor" in parts:
        y, z, v = SENSOR_HALF_WIDTH
        fields["sensor"] = jnp.array([y * length, z * length, v * velocity])
    if "landing" in parts:
        fields["landing"] = LANDING_HALF_WIDTH * length
    return Disturbance(**fields)
