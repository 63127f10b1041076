"""Ball-hopper (BHop) model: apex return map and deadbeat inverse (section IV-B).

Every function here handles one apex state; batching is added with `jax.vmap` by callers.
Controls are `u = (dy, th, k)`: horizontal shift in stance, touchdown angle, velocity gain.
"""

import jax.numpy as jnp

from .._core.params import Hopper
from .._core.programs import jit


def safe_sqrt(x):
    """sqrt with a finite gradient at and below 0 (the double-where pattern)."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def descent(apex, h, hopper: Hopper, wind=0.0):
    """Ballistic descent from apex to the virtual ground `h + rho0` (eq 23).

    Returns:
        `(y_td, v_td)`: COM horizontal position and velocity `(ydot, zdot)` at touchdown.
    """
    y, z, ydot = apex
    t_d = safe_sqrt(2.0 * (z - h - hopper.rho0) / hopper.g)
    y_td = y + ydot * t_d + 0.5 * wind * t_d**2
    return y_td, jnp.stack([ydot + wind * t_d, -hopper.g * t_d])


def stance(y_td, v_td, u):
    """Instantaneous stance transition (eqs 18-21): `v_lo = v_td - (1 + k)(v_td . n) n`."""
    dy, th, k = u
    n = jnp.stack([-jnp.sin(th), jnp.cos(th)])
    return y_td + dy, v_td - (1.0 + k) * jnp.dot(v_td, n) * n


def ascent(y_lo, v_lo, h, hopper: Hopper, wind=0.0):
    """Ballistic ascent from liftoff at height `h + rho0` to the next apex (eq 24)."""
    t_up = jnp.maximum(v_lo[1], 0.0) / hopper.g
    y = y_lo + v_lo[0] * t_up + 0.5 * wind * t_up**2
    z = h + hopper.rho0 + 0.5 * hopper.g * t_up**2
    return jnp.stack([y, z, v_lo[0] + wind * t_up])


def bhop_apex_map(apex, u, h, hopper: Hopper, wind=0.0):
    """Apex return map `Fa = Fu o Fs o Fd` (eq 22) over a flat foothold at height `h`."""
    y_td, v_td = descent(apex, h, hopper, wind)
    y_lo, v_lo = stance(y_td, v_td, u)
    return ascent(y_lo, v_lo, h, hopper, wind)


def liftoff_for_goal(goal, h, hopper: Hopper, wind=0.0):
    """Inverse ascent `Fu^-1`: liftoff position and velocity that reach `goal` (eqs 25-26).

    With a horizontal flight acceleration `wind` the rise of `t_up = zdot_lo / g` changes the
    horizontal velocity by `wind t_up` and the position by `wind t_up^2 / 2`; at `wind == 0`
    the windless expressions are used as they are (bit for bit eqs 25-26).
    """
    y_g, z_g, ydot_g = goal
    zdot_lo = safe_sqrt(2.0 * hopper.g * (z_g - h - hopper.rho0))
    t_up = zdot_lo / hopper.g
    calm = wind == 0
    y_lo = jnp.where(calm, y_g - ydot_g * zdot_lo / hopper.g,
                     y_g - ydot_g * t_up + 0.5 * wind * t_up**2)
    ydot_lo = jnp.where(calm, ydot_g, ydot_g - wind * t_up)
    return y_lo, jnp.stack([ydot_lo, zdot_lo])


def stance_controls(v_td, v_lo):
    """`(th, k)` of the stance map taking `v_td` to `v_lo` (eqs 28-29).

    The velocity change is parallel to `n(th)`, hence `tan th = -dvy / dvz`; `k` follows from
    `|dv|^2 = (1 + k) (-v_td . dv)`. A target with `-v_td . dv <= 0` is unreachable: `k` is
    then `inf`.
    """
    dv = v_lo - v_td
    th = jnp.arctan2(-dv[0], dv[1])
    th = jnp.where(th > jnp.pi / 2, th - jnp.pi, jnp.where(th < -jnp.pi / 2, th + jnp.pi, th))
    denom = -jnp.dot(v_td, dv)
    ok = denom > 0
    k = jnp.where(ok, jnp.dot(dv, dv) / jnp.where(ok, denom, 1.0) - 1.0, jnp.inf)
    return th, k


def deadbeat_bhop(apex, goal, h, hopper: Hopper, wind=0.0):
    """Deadbeat controls `u = (dy, th, k)` taking `apex` to `goal` over a foothold at `h`.

    Inverts eqs 25-29; with `wind` (a horizontal flight acceleration, e.g. the disturbance
    observer's estimate) the descent and the ascent are inverted with it, so that
    `bhop_apex_map(apex, u, h, hopper, wind) == goal`. `wind == 0` gives the nominal
    (windless) deadbeat bit for bit. The result is unclipped; callers clip it to the
    template's limits.
    """
    y_td, v_td = descent(apex, h, hopper, wind)
    y_lo, v_lo = liftoff_for_goal(goal, h, hopper, wind)
    th, k = stance_controls(v_td, v_lo)
    return jnp.stack([y_lo - y_td, th, k])


def clip_controls(u, lo, hi):
    return jnp.clip(u, lo, hi)


bhop_apex_map_jit = jit(bhop_apex_map)
deadbeat_bhop_jit = jit(deadbeat_bhop)
