"""Disturbance observer of the adaptive controller: a constant wind learnt from apexes.

The controller predicts the apex each stride should reach; the next measured apex tells it
how far reality differs. A constant horizontal flight acceleration `a_w` (wind) is
estimated online from those prediction errors with a scalar Kalman filter
(`docs/decisions.md`, "Adaptive controller"):

- prediction: the model's apex map from the measured apex the stride started from, with
  the controls it applied, over the foothold height sensed at touchdown, flown with the
  current estimate `a`: `pred = Fa(z_meas, u, h; a)` (BHop: eq 22; SLIP: its apex map,
  with the stance's target energy where the stride used one);
- measurement: the innovation in horizontal velocity `nu = ydot_meas - pred_ydot`, with
  `H = d pred_ydot / d a` (about the flight time: the wind acts for the descent and the
  rise, the descent part passing through the stance; through diffrax for the SLIP);
- measurement noise `R = (w_v^2 + sum_i (J_i w_i)^2) / 3 + R_MIN`: uniform noise of
  half-width `w` has variance `w^2 / 3`; the new apex carries `w_v`, the apex the
  prediction started from carries `w` through `J = d pred_ydot / d z_meas`;
- process noise `Q` per stride: small, the wind is modelled as constant (a slow drift is
  still followed).

State per run (`Observer`), reset per run, one sample at a time (vmapped by the drivers).
"""

from __future__ import annotations

from typing import NamedTuple

import diffrax
import jax
import jax.numpy as jnp

from ._bhop import bhop_apex_map
from ._params import Hopper

#: Prior variance of the wind (m/s^2)^2: a standard deviation of 1 m/s^2, five times the
#: paper's wind, so the first innovation is trusted almost fully.
PRIOR_VAR = 1.0
#: Process noise per stride (m/s^2)^2: a constant wind, allowed to drift by ~1e-3 m/s^2.
PROCESS_VAR = 1e-6
#: Floor of the measurement variance (m/s)^2 (model rounding when there is no sensor noise).
R_MIN = 1e-12
#: Innovations below this (m/s) are rounding, not wind: the filter skips them, so an
#: undisturbed run keeps an estimate of exactly 0. The SLIP's floor is its integration
#: noise: the prediction is a second diffrax solve of the executed stride (rtol 1e-10),
#: from a touchdown computed in closed form rather than on the terrain.
NU_MIN = 1e-9
NU_MIN_SLIP = 1e-7


class Observer(NamedTuple):
    """The observer of one run: the estimate `wind` (m/s^2) and its variance `var`, and the
    stride awaiting its measured apex (`pending`): the measured apex it started from, its
    controls, the sensed foothold height and the stance's target energy (NaN: none)."""

    wind: jnp.ndarray
    var: jnp.ndarray
    apex: jnp.ndarray
    u: jnp.ndarray
    h: jnp.ndarray
    pending: jnp.ndarray
    energy: jnp.ndarray


def observer_init() -> Observer:
    """No wind known, nothing pending."""
    z = jnp.zeros(3)
    return Observer(jnp.asarray(0.0), jnp.asarray(PRIOR_VAR), z, z, jnp.asarray(0.0),
                    jnp.asarray(False), jnp.asarray(jnp.nan))


def predicted_ydot(apex, u, h, hopper: Hopper, wind):
    """The horizontal apex velocity the BHop stride from `apex` with `u` reaches."""
    return bhop_apex_map(apex, u, h, hopper, wind)[2]


def bhop_terms(obs: Observer, hopper: Hopper):
    """`(pred, H, J)` of the pending BHop stride: the predicted horizontal apex velocity,
    its derivatives in the wind and in the measured apex it started from."""
    f = lambda a, z: predicted_ydot(z, obs.u, obs.h, hopper, a)  # noqa: E731
    pred, h_wind = jax.jvp(lambda a: f(a, obs.apex), (obs.wind,), (jnp.ones_like(obs.wind),))
    return pred, h_wind, jax.grad(lambda z: f(obs.wind, z))(obs.apex)


def slip_terms(obs: Observer, hopper: Hopper):
    """`bhop_terms` for the SLIP stride: its apex map (with the stance's target energy where
    the stride used one), both derivatives in one forward-mode pass through diffrax."""
    from ._slip import STRIDE_TOL, Tolerances, slip_apex_map

    tol = Tolerances(STRIDE_TOL.rtol, STRIDE_TOL.atol, diffrax.ForwardMode())

    def f(x):
        nxt, _ = slip_apex_map(x[1:], obs.u, obs.h, hopper, tol, x[0], obs.energy)
        return nxt[2]

    x = jnp.concatenate([obs.wind[None], obs.apex])
    jac = jax.jacfwd(f)(x)
    return f(x), jac[0], jac[1:]


def observe(obs: Observer, measured, sensor, hopper: Hopper, terms=bhop_terms,
            nu_min=NU_MIN) -> Observer:
    """The Kalman update with the apex measured after the pending stride (none pending, or
    an innovation below `nu_min`: the estimate is kept).

    `sensor`: the half-widths of the uniform apex noise `(y, z, ydot)`. `terms`: the
    model's prediction, `bhop_terms` or `slip_terms`.
    """
    pred, h_wind, jac = terms(obs, hopper)
    r = (sensor[2] ** 2 + jnp.sum((jac * sensor) ** 2)) / 3.0 + R_MIN
    p = obs.var + PROCESS_VAR
    nu = measured[2] - pred
    gain = p * h_wind / (h_wind**2 * p + r)
    use = obs.pending & (jnp.abs(nu) >= nu_min) & jnp.isfinite(nu) & jnp.isfinite(gain)
    wind = jnp.where(use, obs.wind + gain * nu, obs.wind)
    var = jnp.where(use, (1.0 - gain * h_wind) * p, obs.var)
    return obs._replace(wind=wind, var=var, pending=jnp.asarray(False))


#: The leg of a spring-leg (SLIP) hopper is placed in flight: its controller measures the
#: horizontal velocity again after this fraction of the fall from the apex to the map under
#: it, before it sets the touchdown angle.
DESCENT_FRACTION = 0.5


def observe_descent(obs: Observer, measured_ydot, ydot_descent, t, sensor) -> Observer:
    """The Kalman update with the horizontal velocity measured `t` seconds into the
    descent: `(ydot_descent - measured_ydot) / t` measures the wind directly (`H = 1`),
    with the variance `2 w_v^2 / (3 t^2)` of two uniform velocity errors. `t == 0` (no
    descent to measure in): the estimate is kept."""
    t_safe = jnp.where(t > 0, t, 1.0)
    nu = (ydot_descent - measured_ydot) / t_safe - obs.wind
    r = 2.0 * sensor[2] ** 2 / (3.0 * t_safe**2) + R_MIN
    p = obs.var + PROCESS_VAR
    gain = p / (p + r)
    use = (t > 0) & jnp.isfinite(nu)
    return obs._replace(wind=jnp.where(use, obs.wind + gain * nu, obs.wind),
                        var=jnp.where(use, (1.0 - gain) * p, obs.var))


def after_stride(obs: Observer, measured, u, h, completed, energy=None) -> Observer:
    """Record a stride for the next update (only a completed stride is compared).
    `energy`: the target energy its stance used (`None`: none)."""
    energy = jnp.asarray(jnp.nan if energy is None else energy, float)
    return obs._replace(apex=measured, u=u, h=jnp.asarray(h, float),
                        pending=jnp.asarray(completed), energy=energy)
