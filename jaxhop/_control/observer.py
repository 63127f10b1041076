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

The same predictions give the controller a filtered apex to decide on (an extended
Kalman filter of the apex state; `docs/decisions.md`, "Apex filter"): the predicted apex
`pred` with the new wind estimate, its covariance `J P J^T + H H^T var_a + Q` (`Q`: the
landing error's variance on `y` plus a floor: model rounding for the BHop, the error of the
linearised stride for the SLIP), fused with the measurement of
variance `w^2 / 3` per axis. Without sensor noise the estimate is the measurement,
bit for bit; a run's first apex, and the one after a stride that did not complete, start
the filter again from the measurement.

State per run (`Observer`), reset per run, one sample at a time (vmapped by the drivers).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._core.params import Hopper
from .._core.terrain import Terrain
from .._models.bhop import bhop_apex_map
from .foothold import mapped_height

#: Prior variance of the wind (m/s^2)^2: a standard deviation of 1 m/s^2, five times the
#: paper's wind, so the first innovation is trusted almost fully.
PRIOR_VAR = 1.0
#: Process noise per stride (m/s^2)^2: a constant wind, allowed to drift by ~1e-3 m/s^2.
PROCESS_VAR = 1e-6
#: Floor of the measurement variance (m/s)^2 (model rounding when there is no sensor noise).
R_MIN = 1e-12
#: Floor of the apex prediction's variance, m^2 and (m/s)^2 (model rounding).
Q_MIN = 1e-10
#: The SLIP's floor, the same on every axis: its apex map, linearised about the estimate,
#: is off by 5-21 mm (mm/s) rms at estimate errors of up to 3 cm (cm/s) and a wind 0.2 m/s^2
#: off (`docs/decisions.md`, "Apex filter"); a filter that believed its prediction to 1e-5
#: took a noiseless axis for the truth and moved the wind by tens of m/s^2 to fit it.
Q_MIN_SLIP = 4e-4
#: Innovations below this (m/s) are rounding, not wind: the filter skips them, so an
#: undisturbed run keeps an estimate of exactly 0. The SLIP's floor is its integration
#: noise: the prediction is a second diffrax solve of the executed stride (rtol 1e-10),
#: from a touchdown computed in closed form rather than on the terrain.
NU_MIN = 1e-9
NU_MIN_SLIP = 1e-7
#: The SLIP's floor where its prediction is a fixed-shape stride (`slip_prediction`): ten
#: times the largest apex error of those strides against the 1e-10 stride (3.0e-6 on 2 000
#: random strides, docs/slip.md, "Fixed-shape trial strides").
NU_MIN_SLIP_FIXED = 3e-5


class Observer(NamedTuple):
    """The observer of one run: the estimate `wind` (m/s^2) and its variance `var`; the
    filtered apex `estimate` the controller decides on and its covariance `est_var`; the
    stride awaiting its measured apex (`pending`): the apex estimate it started from, its
    controls, the sensed foothold height and the stance's target energy (NaN: none)."""

    wind: jnp.ndarray
    var: jnp.ndarray
    apex: jnp.ndarray
    u: jnp.ndarray
    h: jnp.ndarray
    pending: jnp.ndarray
    energy: jnp.ndarray
    estimate: jnp.ndarray
    est_var: jnp.ndarray


def observer_init() -> Observer:
    """No wind known, nothing pending."""
    z = jnp.zeros(3)
    return Observer(jnp.asarray(0.0), jnp.asarray(PRIOR_VAR), z, z, jnp.asarray(0.0),
                    jnp.asarray(False), jnp.asarray(jnp.nan), z, jnp.zeros((3, 3)))


def bhop_terms(obs: Observer, hopper: Hopper):
    """`(pred, H, J)` of the pending BHop stride: the predicted apex, its derivatives in
    the wind `(3,)` and in the apex it started from `(3, 3)`."""
    f = lambda a, z: bhop_apex_map(z, obs.u, obs.h, hopper, a)  # noqa: E731
    pred, h_wind = jax.jvp(lambda a: f(a, obs.apex), (obs.wind,), (jnp.ones_like(obs.wind),))
    return pred, h_wind, jax.jacfwd(lambda z: f(obs.wind, z))(obs.apex)


def slip_prediction():
    """The strides of the SLIP's apex prediction and the floor of its innovations, as the
    decision's platform gives them (`jaxhop._models.slip.kernels.decision_tol`): on a CPU
    the executed stride's 1e-10 solve and `NU_MIN_SLIP`; elsewhere the decision's
    fixed-shape strides and `NU_MIN_SLIP_FIXED`, so that no turn of a data-dependent loop
    waits for the host there (docs/slip.md, "Fixed-shape trial strides")."""
    from .._models.slip.kernels import decision_tol
    from .._models.slip.stride import STRIDE_TOL

    tol = decision_tol()
    if tol.steps:
        return tol, NU_MIN_SLIP_FIXED
    return STRIDE_TOL.forward(), NU_MIN_SLIP


def slip_terms(obs: Observer, hopper: Hopper):
    """`bhop_terms` for the SLIP stride: its apex map (with the stance's target energy where
    the stride used one) on `slip_prediction`'s strides, both derivatives in one
    forward-mode pass through the stance."""
    from .._models.slip.stride import slip_apex_map

    tol = slip_prediction()[0]

    def f(x):
        nxt, _ = slip_apex_map(x[1:], obs.u, obs.h, hopper, tol, x[0], obs.energy)
        return nxt, nxt

    x = jnp.concatenate([obs.wind[None], obs.apex])
    # The prediction comes with its derivatives: one pass through the solves, not two.
    jac, pred = jax.jacfwd(f, has_aux=True)(x)
    return pred, jac[:, 0], jac[:, 1:]


def observe(obs: Observer, measured, sensor, hopper: Hopper, terms=bhop_terms,
            nu_min=NU_MIN, landing=0.0, stride_error=None, q_min=Q_MIN) -> Observer:
    """The Kalman update with the apex measured after the pending stride (none pending, or
    an innovation below `nu_min`: the estimate is kept), then the apex estimate (`fuse`).

    `sensor`: the half-widths of the uniform apex noise `(y, z, ydot)`. `terms`: the
    model's prediction, `bhop_terms` or `slip_terms`. `landing`: the half-width of the
    landing error on `y` (0: none). `stride_error`: half-widths `(y, z, ydot)` of a
    uniform error of the stride that the model's prediction does not describe (a hopper
    that is not the model, `jaxhop.mujoco`; `None`: none), process noise of the apex
    prediction and noise of the wind's innovation. `q_min`: the floor of the apex
    prediction's variance (`Q_MIN`, `Q_MIN_SLIP`).
    """
    pred, h_wind, jac = terms(obs, hopper)
    # The new apex carries w_v; the apex the prediction started from carries est_var.
    r = sensor[2] ** 2 / 3.0 + jac[2] @ obs.est_var @ jac[2] + R_MIN
    if stride_error is not None:
        r = r + jnp.asarray(stride_error, float)[2] ** 2 / 3.0
    p = obs.var + PROCESS_VAR
    nu = measured[2] - pred[2]
    gain = p * h_wind[2] / (h_wind[2] ** 2 * p + r)
    use = obs.pending & (jnp.abs(nu) >= nu_min) & jnp.isfinite(nu) & jnp.isfinite(gain)
    wind = jnp.where(use, obs.wind + gain * nu, obs.wind)
    var = jnp.where(use, (1.0 - gain * h_wind[2]) * p, obs.var)
    estimate, est_var = fuse(obs, measured, sensor, pred + h_wind * (wind - obs.wind),
                             h_wind, jac, var, landing, stride_error, q_min)
    return obs._replace(wind=wind, var=var, pending=jnp.asarray(False), estimate=estimate,
                        est_var=est_var)


def fuse(obs: Observer, measured, sensor, pred, h_wind, jac, wind_var, landing=0.0,
         stride_error=None, q_min=Q_MIN):
    """`(estimate, covariance)` of the apex: the prediction `pred` of the pending stride
    fused with the measurement (the Kalman gain of the linearised stride). No sensor noise,
    nothing pending or a non-finite prediction: the measurement itself. `landing`,
    `stride_error`, `q_min`: as `observe`'s."""
    r = jnp.asarray(sensor, float) ** 2 / 3.0
    q = jnp.zeros(3).at[0].set(jnp.asarray(landing, float) ** 2 / 3.0) + q_min
    if stride_error is not None:
        q = q + jnp.asarray(stride_error, float) ** 2 / 3.0
    p = jac @ obs.est_var @ jac.T + wind_var * jnp.outer(h_wind, h_wind) + jnp.diag(q)
    gain = jnp.linalg.solve(p + jnp.diag(r), p).T  # P S^-1, with P and S symmetric
    est = pred + gain @ (measured - pred)
    cov = (jnp.eye(3) - gain) @ p
    cov = 0.5 * (cov + cov.T)
    use = (obs.pending & jnp.any(r > 0) & jnp.all(jnp.isfinite(est))
           & jnp.all(jnp.isfinite(cov)))
    return jnp.where(use, est, measured), jnp.where(use, cov, jnp.diag(r))


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


def fuse_descent(obs: Observer, descent, t, sensor, g) -> Observer:
    """The Kalman update of the apex estimate and the wind together with the state
    `descent = (y, z, ydot)` measured `t` seconds into the descent (uniform noise of
    half-widths `sensor` on each), through the ballistic fall from the apex:
    `(y + ydot t + a t^2 / 2, z - g t^2 / 2, ydot + a t)`. The prior is the apex estimate
    with its covariance and the wind with its variance, independent. A second measurement
    of the same flight narrows the apex estimate before the leg is placed
    (`docs/decisions.md`, "Apex filter"). `t == 0`: the estimate is kept."""
    t_safe = jnp.where(t > 0, t, 1.0)
    x = jnp.concatenate([obs.estimate, obs.wind[None]])
    p = jnp.zeros((4, 4)).at[:3, :3].set(obs.est_var).at[3, 3].set(obs.var + PROCESS_VAR)
    h = jnp.array([[1.0, 0.0, t_safe, 0.5 * t_safe**2], [0.0, 1.0, 0.0, 0.0],
                   [0.0, 0.0, 1.0, t_safe]])
    offset = jnp.array([0.0, -0.5 * g * t_safe**2, 0.0])
    r = jnp.diag(jnp.asarray(sensor, float) ** 2 / 3.0 + R_MIN)
    s = h @ p @ h.T + r
    gain = jnp.linalg.solve(s, h @ p).T  # P H^T S^-1, with P and S symmetric
    x_new = x + gain @ (jnp.asarray(descent, float) - h @ x - offset)
    p_new = (jnp.eye(4) - gain @ h) @ p
    p_new = 0.5 * (p_new + p_new.T)
    use = (t > 0) & jnp.all(jnp.isfinite(x_new)) & jnp.all(jnp.isfinite(p_new))
    return obs._replace(estimate=jnp.where(use, x_new[:3], obs.estimate),
                        est_var=jnp.where(use, p_new[:3, :3], obs.est_var),
                        wind=jnp.where(use, x_new[3], obs.wind),
                        var=jnp.where(use, p_new[3, 3], obs.var))


def descent_time(measured, heights, terrain: Terrain, hopper: Hopper):
    """When the descent measurement is taken: `DESCENT_FRACTION` of the time of the fall
    from the measured apex until the foot (at rest length below the body) reaches the
    corrected map (block `heights`) under it; over a hole or off the map, the nearest
    block's top (the higher of two as near), where the foot will land."""
    ground = mapped_height(measured[:2], heights, terrain)
    gap = jnp.maximum(jnp.maximum(terrain.starts - measured[0], measured[0] - terrain.ends),
                      0.0)
    nearest = jnp.max(jnp.where(gap == jnp.min(gap), heights, -jnp.inf))
    ground = jnp.where(jnp.isfinite(ground), ground, nearest)
    fall = measured[1] - ground - hopper.rho0
    return DESCENT_FRACTION * jnp.sqrt(2.0 * jnp.maximum(fall, 0.0) / hopper.g)


def descent_key(run_key, k):
    """The key of the descent measurement after apex `k` of the run drawing from
    `run_key` (`descent_noise`): jaxhop's run loop and the MuJoCo runner draw the same."""
    return jax.random.fold_in(jax.random.fold_in(run_key, k), 1)


def descent_noise(key):
    """The uniforms in `[-1, 1)` of a descent measurement, ordered `(y, z, ydot)`: the
    velocity's from `key` (`descent_key`), the position's from `fold_in(key, 1)`."""
    velocity = jax.random.uniform(key, minval=-1.0, maxval=1.0)
    position = jax.random.uniform(jax.random.fold_in(key, 1), (2,), minval=-1.0, maxval=1.0)
    return jnp.stack([position[0], position[1], velocity])


def descent_update(obs: Observer, measured_ydot, descent, t, sensor, g) -> Observer:
    """The observer's update with the state `descent = (y, z, ydot)` measured `t` seconds
    into the descent. Without sensor noise the change of horizontal velocity since the
    apex measurement (`measured_ydot`) gives the wind (`observe_descent`); with it, the
    apex estimate and the wind are updated together (`fuse_descent`)."""
    scalar = observe_descent(obs, measured_ydot, descent[2], t, sensor)
    joint = fuse_descent(obs, descent, t, sensor, g)
    noisy = jnp.any(sensor > 0)
    return jax.tree.map(lambda a, b: jnp.where(noisy, a, b), joint, scalar)


def after_stride(obs: Observer, measured, u, h, completed, energy=None) -> Observer:
    """Record a stride for the next update (only a completed stride is compared).
    `measured`: the apex estimate the stride was decided on. `energy`: the target energy
    its stance used (`None`: none)."""
    energy = jnp.asarray(jnp.nan if energy is None else energy, float)
    return obs._replace(apex=measured, u=u, h=jnp.asarray(h, float),
                        pending=jnp.asarray(completed), energy=energy)
