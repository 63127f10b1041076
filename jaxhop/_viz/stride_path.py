"""One SLIP stride sampled for drawing: the descent, both stance phases (eq 10) and the rise.

`stride_path` returns `slip_stride`'s next apex, code and foothold together with the COM
path at a fixed number of samples, so that one compiled program serves every stride an
explorer draws (`jaxhop.explore_stride`). The stance is integrated again with dense output
(`sampled_stance`: the same phases and tolerances as `slip_stride`) and sampled evenly in
time in each phase; the flights are the ballistic parabolas. Windless.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._core.params import Hopper
from .._core.programs import jit
from .._core.terrain import Terrain
from .._models.flight import OK, touchdown
from .._models.slip.stride import cartesian, sampled_stance, slip_stride

#: Samples of each flight and of each stance phase.
N_FLIGHT = 24
N_STANCE = 32


class StridePath(NamedTuple):
    """`slip_stride`'s `(next_apex, code, foot)` and the sampled COM path.

    `path`: `(2 N_FLIGHT + 2 N_STANCE, 2)` COM positions `(y, z)`: descent, compression,
    decompression, rise; NaN where the stride has none (after a failed touchdown, or no
    rise). `touchdown`, `bottom`, `liftoff`: the COM at those instants (NaN if none).
    """

    next_apex: jnp.ndarray
    code: jnp.ndarray
    foot: jnp.ndarray
    path: jnp.ndarray
    touchdown: jnp.ndarray
    bottom: jnp.ndarray
    liftoff: jnp.ndarray


def _parabola(y, z, vy, vz, duration, g):
    t = jnp.linspace(0.0, 1.0, N_FLIGHT) * duration
    return jnp.stack([y + vy * t, z + vz * t - 0.5 * g * t**2], axis=1)


def stride_path(apex, u, terrain: Terrain, hopper: Hopper) -> StridePath:
    """One SLIP stride on `terrain` without wind (`slip_stride` at `STRIDE_TOL`) and its
    sampled COM path (`StridePath`). One sample; `u = (th_td, kc, kd)`."""
    nxt, code, foot = slip_stride(apex, u, terrain, hopper)
    th, kc, kd = u
    y, z, ydot = apex
    g = hopper.g
    offset = hopper.rho0 * jnp.stack([jnp.sin(th), -jnp.cos(th)])
    td_code, _, t_td, _, v_td = touchdown(apex, offset, terrain, hopper)
    t_down = jnp.where(jnp.isfinite(t_td), t_td, 0.0)
    descent = _parabola(y, z, ydot, 0.0, t_down, g)
    # A failed descent runs the benign dummy stance `slip_stride` runs; it is drawn as NaN.
    reached = td_code == OK
    states, loaded = sampled_stance(jnp.where(reached, th, 0.0),
                                    jnp.where(reached, v_td, jnp.array([0.0, -1.0])),
                                    kc, kd, hopper, N_STANCE)
    landed = reached & loaded
    stance = jax.vmap(lambda x: cartesian(x)[0])(states) + foot
    p_lo, v_lo = cartesian(states[-1])
    p_lo = p_lo + foot
    rises = landed & (v_lo[1] > 0)
    rise = _parabola(p_lo[0], p_lo[1], v_lo[0], v_lo[1], jnp.maximum(v_lo[1], 0.0) / g, g)
    nan = jnp.full(2, jnp.nan)
    path = jnp.concatenate([descent, jnp.where(landed, stance, jnp.nan),
                            jnp.where(rises, rise, jnp.nan)])
    return StridePath(nxt, code, foot, path, jnp.where(landed, descent[-1], nan),
                      jnp.where(landed, stance[N_STANCE - 1], nan),
                      jnp.where(landed, stance[-1], nan))


stride_path_jit = jit(stride_path)
