"""The SLIP deadbeat's table start with NumPy (twin of `jaxhop._models.slip.table`).

The table's values are data, read from the JAX table (`SlipTable.data()`): a `(values,
grid)` pair, `grid` the five `(lo, hi, n)` axes of `(zeta, nu, eps, th, s)`. The plane of a
query, its bilinear interpolant and the damped Gauss-Newton refinement on it, the starts,
and the Gauss-Newton polish one start at a time (`_slip.gauss_newton`, the multi-start
starts of `_slip.initial_guesses` last) are the JAX code's, step for step.

One sample per call, plain floats; no jax import.
"""

from __future__ import annotations

import math

import numpy as np

from ._model import INF, OK, Hopper, touchdown_one
from ._slip import W_POS, W_VEL, gauss_newton, initial_guesses

# Mirrors of jaxhop._models.slip.table constants.
TABLE_STARTS = 3
POLISH_ITER = 6
POLISH_MIN_TRUST = 1.0 / 64
POLISH_STALL = 1e-3
MULTI_ITER = 16
REFINE_STEPS = 12
REFINE_MAX = np.array([0.1, 0.3])


def polish_cost(tol):
    """C2 of an apex error of ten times the trial strides' tolerance (as JAX)."""
    return (10.0 * tol) ** 2


def _locate(x, lo, hi, n):
    f = min(max((x - lo) / (hi - lo) * (n - 1), 0.0), n - 1 - 1e-9)
    i = math.floor(f)
    return i, f - i


def table_slice(values, grid, apex, goal, h, hopper: Hopper):
    """The table's `(th, s)` plane for the stride, trilinear in `(zeta, nu, eps)`."""
    vs = math.sqrt(hopper.g * hopper.rho0)
    x = ((apex[1] - h) / hopper.rho0, apex[2] / vs,
         (goal[1] - h + 0.5 * goal[2] ** 2 / hopper.g) / hopper.rho0)
    (iz, wz), (iv, wv), (ie, we) = (_locate(v, *a) for v, a in zip(x, grid[:3]))
    cube = values[iz:iz + 2, iv:iv + 2, ie:ie + 2]
    w = (np.array([1 - wz, wz])[:, None, None] * np.array([1 - wv, wv])[None, :, None]
         * np.array([1 - we, we])[None, None, :])
    return np.einsum("abc,abcijk->ijk", w, cube)


def _bilinear(plane, p, grid):
    th_ax, s_ax = grid[3], grid[4]
    (i, wi), (j, wj) = _locate(p[0], *th_ax), _locate(p[1], *s_ax)
    c = plane[i:i + 2, j:j + 2]
    value = ((1 - wi) * (1 - wj) * c[0, 0] + wi * (1 - wj) * c[1, 0]
             + (1 - wi) * wj * c[0, 1] + wi * wj * c[1, 1])
    d_th = ((c[1, 0] - c[0, 0]) * (1 - wj) + (c[1, 1] - c[0, 1]) * wj) * (
        (th_ax[2] - 1) / (th_ax[1] - th_ax[0]))
    d_s = ((c[0, 1] - c[0, 0]) * (1 - wi) + (c[1, 1] - c[1, 0]) * wi) * (
        (s_ax[2] - 1) / (s_ax[1] - s_ax[0]))
    return value, np.stack([d_th, d_s], axis=1)


def _refine(plane, p0, target, grid, e0):
    """`jaxhop._models.slip.table._refine`: damped Gauss-Newton on the plane's interpolant, from
    `p0` with squared error `e0`."""
    lo = np.array([grid[3][0], grid[4][0]])
    hi = np.array([grid[3][1], grid[4][1]])

    def err2(p):
        r = _bilinear(plane, p, grid)[0] - target
        return float(r @ r) if np.all(np.isfinite(r)) else INF

    p, e, trust = np.asarray(p0, float), e0, 1.0
    for _ in range(REFINE_STEPS):
        value, jac = _bilinear(plane, p, grid)
        normal = jac.T @ jac
        try:
            d = np.linalg.solve(normal + 1e-12 * np.trace(normal) * np.eye(2),
                                jac.T @ (value - target))
        except np.linalg.LinAlgError:
            d = np.zeros(2)
        d = np.clip(trust * d if np.all(np.isfinite(d)) else np.zeros(2), -REFINE_MAX,
                    REFINE_MAX)
        q = np.clip(p - d, lo, hi)
        eq = err2(q)
        if eq < e:
            p, e, trust = q, eq, min(2.0 * trust, 1.0)
        else:
            trust = 0.25 * trust
    return p, e


def table_starts(values, grid, apex, goal, h, hopper: Hopper, n_starts=TABLE_STARTS,
                 terrain=None, flat_if_none=False):
    """`n_starts` refined table starts `(th, s)`, best first, and their squared errors
    (`jaxhop._models.slip.table`); with `flat_if_none`, those of flat ground where no
    touchdown angle lands on the foothold's block."""
    plane = table_slice(values, grid, apex, goal, h, hopper)
    target = np.array([(goal[0] - apex[0]) / hopper.rho0,
                       goal[2] / math.sqrt(hopper.g * hopper.rho0)])
    scale = np.array([hopper.rho0, math.sqrt(hopper.g * hopper.rho0)])
    err = (plane - target) * scale
    cost = W_POS * err[..., 0] ** 2 + W_VEL * err[..., 1] ** 2
    cost = np.where(np.isfinite(cost), cost, INF)
    th_axis = np.linspace(*grid[3])
    if terrain is not None:
        landing = np.zeros(len(th_axis), bool)
        for k, th in enumerate(th_axis):
            offset = (hopper.rho0 * math.sin(th), -hopper.rho0 * math.cos(th))
            code, block, *_ = touchdown_one(apex, terrain, hopper, 0.0, offset)
            landing[k] = code == OK and terrain.heights[block] == h
        flat = not np.any(landing[:, None] & (cost < INF))
        if flat_if_none and flat:
            landing[:] = True
        cost[~landing] = INF
        plane[~landing] = np.nan
    s_axis = np.linspace(*grid[4])
    col = cost.min(axis=0)
    cols = np.argsort(col, kind="stable")[:n_starts]  # as lax.top_k: ties to the lower
    rows = [int(np.argmin(cost[:, c])) for c in cols]
    cells = [(th_axis[r], s_axis[c]) for r, c in zip(rows, cols)]
    node = [float(np.sum((plane[r, c] - target) ** 2)) for r, c in zip(rows, cols)]
    refined = [_refine(plane, p, target, grid, e if np.isfinite(e) else INF)
               for p, e in zip(cells, node)]
    order = np.argsort([e for _, e in refined], kind="stable")
    errs = [refined[i][1] for i in order]
    if terrain is not None and flat_if_none and flat:
        errs = [INF] * len(errs)  # flat ground's starts: no start on the block
    return [refined[i][0] for i in order], errs


def staged(apex, goal, h, hopper: Hopper, sqrt_w, table, terrain, fallback, accept, tol):
    """`jaxhop._models.slip.table._deadbeat_table`: one start at a time until one ends with
    C2 <= `accept` (the table's starts, best first, then with `fallback` the multi-start
    solver's starts, all with the polish's stops; only the latter where the table has no
    start, and without `fallback` the starts over flat ground there, with the multi-start's
    polish); the best end wins. Returns `(p, C2, stage)`."""
    starts, errs = table_starts(*table, apex, goal, h, hopper, TABLE_STARTS, terrain,
                                flat_if_none=not fallback)
    none = not np.isfinite(errs[0])  # no table start
    n_all = TABLE_STARTS + 3 if fallback else TABLE_STARTS
    best, cost, guesses = np.asarray(starts[0], float), INF, None
    i = TABLE_STARTS if none and fallback else 0
    while i < n_all and cost > accept:
        if i < TABLE_STARTS:
            end, c = gauss_newton(starts[i], apex, goal, h, hopper, sqrt_w,
                                   MULTI_ITER if none else POLISH_ITER,
                                   polish_cost(tol), terrain, POLISH_MIN_TRUST, POLISH_STALL,
                                   tol)
        else:
            if guesses is None:
                guesses = initial_guesses(apex, goal, h, hopper, terrain, tol)
            end, c = gauss_newton(guesses[i - TABLE_STARTS], apex, goal, h, hopper, sqrt_w,
                                   MULTI_ITER, polish_cost(tol), terrain, POLISH_MIN_TRUST,
                                   POLISH_STALL, tol)
        if c < cost:
            best, cost = np.asarray(end, float), c
        i += 1
    stage = 1 if i <= 1 else (2 if i <= TABLE_STARTS else 3)
    return best, cost, stage
