"""`deadbeat_slip`: the SLIP deadbeat controls of one apex, by either solver.

`"gradient"` (Gauss-Newton through diffrax, `kernels.deadbeat_gradient`, or started from
the apex table, `table.deadbeat_table`) or `"bracket"` (nested bracketing searches,
`bracket.deadbeat_bracket`); `docs/slip.md`, "Deadbeat".
"""

import equinox as eqx
import jax.numpy as jnp

from ..._core.params import Hopper
from .bracket import deadbeat_bracket
from .kernels import SEARCH_TOL, clipped_controls, deadbeat_gradient
from .stride import Tolerances
from .table import SlipTable, deadbeat_table


class DeadbeatSearch(eqx.Module):
    """How `deadbeat_slip` searches for the controls.

    Attributes:
        method: `"gradient"` (Gauss-Newton through diffrax, optax steps; the default) or
            `"bracket"` (nested bisection / golden section; windless).
        tol: the trial strides' integration tolerances (`SEARCH_TOL`; a reactive
            decision's: `DECISION_TOL`).
        table: `"gradient"` only: a `SlipTable` to start from (`table.deadbeat_table`);
            `None`: the multi-start solver's three starts.
        fallback: with `table`, the multi-start solver's starts where the table's best
            miss has C2 above `accept`, or where the table has no start; `False` (a
            decision): none, and the table's starts over flat ground with a longer polish
            where the table has no start.
        accept: the C2 below which a table start is accepted.
    """

    method: str = eqx.field(static=True, default="gradient")
    tol: Tolerances = SEARCH_TOL
    table: SlipTable | None = None
    fallback: bool = eqx.field(static=True, default=True)
    accept: float | jnp.ndarray = 1e-8


def deadbeat_slip(apex, goal, h, hopper: Hopper, search: DeadbeatSearch | None = None, *,
                  terrain=None, wind=None, predict=False):
    """Position-aware SLIP deadbeat controls taking `apex` to `goal` over a foothold at `h`.

    Arguments:
        apex, goal: `(y, z, ydot)` in the world frame.
        h: the foothold's height.
        search: the solver and its settings (`DeadbeatSearch`; default: Gauss-Newton from
            three starts, trial strides at `SEARCH_TOL`).
        terrain: `"gradient"` only: plan each trial stride on the block its foot lands on
            in this map (the execution controller passes the planner's map), not on `h`.
        wind: `"gradient"` only: the horizontal flight acceleration the strides are
            inverted with (`None`: none); `kd` balances its work in flight (`energy_kd`).
        predict: with `terrain`, also return the stride `u` gives (`slip_stride` at the
            search's `tol` over `terrain` with `wind`) as `(next_apex, code)`, without a
            stride of its own where `u` needed no clipping.

    Returns:
        `(u, ok)` (with `predict`: `(u, ok, next_apex, code)`): `u = (th_td, kc, kd)`
        clipped to the control limits; `ok` when no clipping was needed and the trial
        stride with `u` completes. `ValueError`: an unknown `method`, or `predict` without
        `terrain`.
    """
    search = DeadbeatSearch() if search is None else search
    method, tol, table = search.method, search.tol, search.table
    if predict and terrain is None:
        raise ValueError("predict needs the terrain the stride is predicted on")
    if method == "bracket":
        if wind is not None:
            raise ValueError("the bracket solver is windless; use method='gradient'")
        th, kc = deadbeat_bracket(apex, goal, h, hopper, tol)
    elif method == "gradient" and table is not None:
        th, kc, _, _ = deadbeat_table(apex, goal, h, hopper, tol, table, terrain, wind,
                                      search.fallback, search.accept)
    elif method == "gradient":
        th, kc, _ = deadbeat_gradient(apex, goal, h, hopper, tol, terrain=terrain, wind=wind)
    else:
        raise ValueError(f"method must be 'bracket' or 'gradient', got {method!r}")
    return clipped_controls(apex, goal, h, th, kc, hopper, tol, terrain, wind, predict)
