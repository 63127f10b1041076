"""`deadbeat_slip` of the twin: the multi-start solver or the staged table-start solve
(twin of `jaxhop.slip.deadbeat_slip`)."""

import dataclasses
import math

import numpy as np

from ._model import OK, Hopper, Terrain
from ._slip import (
    RATIO_HI,
    RATIO_LO,
    SEARCH_TOL,
    W_POS,
    W_VEL,
    clip_p,
    kc_limits,
    multi_start,
    trial,
)
from ._slip_table import staged


@dataclasses.dataclass(frozen=True)
class DeadbeatSearch:
    """How the twin's `deadbeat_slip` searches (twin of `jaxhop.slip.DeadbeatSearch`).

    Attributes:
        method: `"gauss-newton"` (the JAX gradient solver's iteration, finite-difference
            Jacobian; the default, used by the execution path) or `"lm"`
            (`scipy.optimize.least_squares`, MINPACK Levenberg-Marquardt).
        tol: rtol = atol of the table-start solve's trial strides (a decision's: 1e-5).
        table: `(values, grid)` of the SLIP table: the staged table-start solve
            (Gauss-Newton only), `fallback` and `accept` as in JAX.
    """

    method: str = "gauss-newton"
    tol: float = SEARCH_TOL
    table: tuple | None = None
    fallback: bool = True
    accept: float = 1e-8


def deadbeat_slip(apex, goal, h, hopper: Hopper, search: DeadbeatSearch | None = None,
                  terrain: Terrain | None = None, full=False):
    """Position-aware SLIP deadbeat `(u, ok)` from `apex` to `goal` over a foothold at `h`.

    `u = (th_td, kc, kd)` clipped to the limits; `ok` when no clipping was needed and the
    trial stride with `u` completes (as `jaxhop.slip.deadbeat_slip`, "gradient").
    `search`: the solver (`DeadbeatSearch`); `terrain`: plan each trial on the block the
    foot lands on in this map (as JAX). `full`: also the stage.
    """
    search = DeadbeatSearch() if search is None else search
    method, table, tol = search.method, search.table, search.tol
    apex, goal, h = np.asarray(apex, float), np.asarray(goal, float), float(h)
    sqrt_w = np.sqrt(np.array([W_POS, W_POS, W_VEL]))
    stage = 3
    if table is None:
        best, _ = multi_start(apex, goal, h, hopper, sqrt_w, method, terrain)
    else:
        best, _, stage = staged(apex, goal, h, hopper, sqrt_w, table, terrain,
                                search.fallback, search.accept, tol)
    th, s = clip_p(best)
    kc_lo, kc_hi = kc_limits(hopper)
    kc = kc_lo + s * (kc_hi - kc_lo)
    _, code, kd = trial(apex, goal, h, th, kc, hopper, tol, terrain)
    kc_c = min(max(kc, kc_lo), kc_hi)
    # As jnp.clip: +-inf clips to the limits, NaN stays NaN (then kc is used).
    kd_c = kd if math.isnan(kd) else min(max(kd, RATIO_LO * kc_c), RATIO_HI * kc_c)
    ok = code == OK and kd_c == kd and kc_c == kc and math.isfinite(kd)
    u = np.array([th, kc_c, kd_c if math.isfinite(kd_c) else kc_c])
    return (u, ok, stage) if full else (u, ok)
