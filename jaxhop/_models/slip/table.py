"""A forward table of the SLIP apex map: the starting points of the SLIP deadbeat.

With `kd` from the energy balance (eq 12), one SLIP stride over flat ground is fixed by five
dimensionless numbers (Froude scaling: lengths over `rho0`, speeds over `sqrt(g rho0)`):

- `zeta = (z - h) / rho0`, the apex height over the foothold;
- `nu = ydot / sqrt(g rho0)`, the apex speed;
- `eps = (z* - h + ydot*^2 / (2 g)) / rho0`, the target apex energy over `m g rho0`
  relative to the foothold (eq 12 gives the stride exactly this energy);
- `th`, the touchdown angle;
- `s = (kappa - KAPPA_LO) / (KAPPA_HI - KAPPA_LO)` with `kappa = kc rho0 / (m g)`.

Its outputs are the horizontal advance `(y' - y) / rho0` and the next apex speed `nu'` (the
height follows from the energy). The table holds them on a grid over all five (`TableGrid`),
built once with batched diffrax strides of a unit hopper and valid for every hopper size.
A deadbeat query interpolates the table multilinearly in `(zeta, nu, eps)` and takes the
best `(th, s)` cells as starts of a Gauss-Newton polish (`jaxhop._models.slip.kernels`).

The table is cached on disk next to the plans (`cache_dir()/slip-table-<key>.npz`), keyed
by its grid, the search tolerances and the package version (`docs/slip.md`, "Deadbeat").
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._core.batching import bounded_while, run_once
from ..._core.params import Hopper
from ..._core.paths import atomic_write, cache_dir, file_lock
from ..._core.programs import jit
from ..._core.version import VERSION
from ..bhop import safe_sqrt
from .kernels import (
    KAPPA_HI,
    KAPPA_LO,
    SEARCH_TOL,
    W_POS,
    W_VEL,
    clipped_controls,
    deadbeat_gradient,
    initial_guesses,
    kc_limits,
    trial_stride,
)

_FORMAT = 2


class TableGrid(eqx.Module):
    """The table's grid: `(lo, hi, n)` per input (all static)."""

    zeta: tuple = eqx.field(static=True, default=(1.0, 3.0, 11))
    nu: tuple = eqx.field(static=True, default=(-1.0, 1.0, 41))
    eps: tuple = eqx.field(static=True, default=(1.0, 3.2, 9))
    th: tuple = eqx.field(static=True, default=(-0.6, 0.6, 25))
    s: tuple = eqx.field(static=True, default=(0.0, 1.0, 7))

    def axes(self):
        return [np.linspace(*a) for a in (self.zeta, self.nu, self.eps, self.th, self.s)]

    def to_list(self):
        return [list(a) for a in (self.zeta, self.nu, self.eps, self.th, self.s)]


DEFAULT_GRID = TableGrid()


class SlipTable(eqx.Module):
    """The tabulated map: `values[iz, iv, ie, ith, is] = (dy / rho0, nu')`, NaN where the
    stride fails; `grid` gives the axes."""

    values: jnp.ndarray
    grid: TableGrid = eqx.field(static=True, default=DEFAULT_GRID)

    def data(self):
        """`(values, grid)` as NumPy values and the five `(lo, hi, n)` axes: what the twin
        (`jaxhop.reference._slip_table`) reads."""
        return np.asarray(self.values), self.grid.to_list()


_UNIT = Hopper(m=1.0, g=1.0, rho0=1.0)


def _entry(zeta, nu, eps, th, s, tol):
    kc = KAPPA_LO + s * (KAPPA_HI - KAPPA_LO)
    apex = jnp.stack([0.0, zeta, nu])
    goal = jnp.stack([0.0, eps, 0.0])  # only its energy enters eq 12
    nxt, code, *_ = trial_stride(apex, goal, 0.0, th, kc, _UNIT, tol)
    ok = (code == 0) & jnp.all(jnp.isfinite(nxt))
    return jnp.where(ok, jnp.stack([nxt[0], nxt[2]]), jnp.nan)


def build_table(grid: TableGrid = DEFAULT_GRID, chunk: int | None = None,
                progress: bool = True) -> np.ndarray:
    """The table's values on `grid` (`(nz, nv, ne, nth, ns, 2)`), computed with batched
    diffrax strides of a unit hopper at the deadbeat's search tolerances, on every device.

    `chunk`: strides per batch (default 256 on a CPU, 4 096 on an accelerator). A vmapped
    stride runs until the slowest of its batch ends; on a 2-core CPU batches of 256 build
    the table about 3x faster than batches of 4 096 (0.4-0.6 s against 1.5-1.6 s per
    16 384 strides, jax 0.10.2)."""
    from ..._core.batching import chunked_map
    from ..._core.progress import Progress

    axes = grid.axes()
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 5)
    if chunk is None:
        chunk = 256 if jax.default_backend() == "cpu" else 4096
    fn = jit(jax.vmap(lambda x: _entry(*x, SEARCH_TOL)))
    with Progress(mesh.shape[0], "SLIP table", "strides", enabled=progress) as bar:
        out = chunked_map(fn, mesh.shape[0], chunk, (mesh,), bar=bar)
    return np.asarray(out).reshape(*(a.size for a in axes), 2)


def table_key(grid: TableGrid = DEFAULT_GRID) -> str:

    payload = {"version": VERSION, "format": _FORMAT, "grid": grid.to_list(),
               "tol": [SEARCH_TOL.rtol, SEARCH_TOL.atol]}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


_LOADED: dict = {}
_LOCK = threading.Lock()


def _read(path: str, key: str, shape: tuple):
    """The cached values at `path`, or `None` (missing, corrupt, stale or another grid)."""
    try:
        with np.load(path) as z:
            if str(z["key"]) == key and z["values"].shape == shape:
                return z["values"]
    except (OSError, ValueError, KeyError):
        pass
    return None


def slip_table(grid: TableGrid = DEFAULT_GRID, cache: bool = True,
               progress: bool = True) -> SlipTable:
    """The SLIP table on `grid`: from memory, from the disk cache, or built (and cached).

    A corrupt or stale cache file is rebuilt; processes that share the cache directory
    build it once (a lock file beside it). `cache=False` builds it without the disk.
    `progress`: a bar while it is built.
    """
    key = table_key(grid)
    shape = tuple(a.size for a in grid.axes()) + (2,)
    with _LOCK:
        if key in _LOADED:
            return _LOADED[key]
        if not cache:
            values = build_table(grid, progress=progress)
        else:
            os.makedirs(cache_dir(), exist_ok=True)
            path = os.path.join(cache_dir(), f"slip-table-{key}.npz")
            values = _read(path, key, shape)
            if values is None:
                with file_lock(path + ".lock"):
                    values = _read(path, key, shape)  # another process may have built it
                    if values is None:
                        values = build_table(grid, progress=progress)
                        atomic_write(path, lambda f: np.savez(f, key=np.asarray(key),
                                                              values=values))
        table = SlipTable(jnp.asarray(values), grid)
        _LOADED[key] = table
        return table


# Newton steps on the interpolated plane per start, and their largest step (th, s).
REFINE_STEPS = 12
REFINE_MAX = (0.1, 0.3)


def _locate(x, lo, hi, n):
    """Cell index and weight of `x` on the axis `linspace(lo, hi, n)`, clipped to it."""
    f = jnp.clip((x - lo) / (hi - lo) * (n - 1), 0.0, n - 1 - 1e-9)
    i = jnp.floor(f).astype(jnp.int32)
    return i, f - i


def table_slice(table: SlipTable, apex, goal, h, hopper: Hopper):
    """The table's `(th, s)` plane for the stride from `apex` with the goal's energy over a
    foothold at `h`: `(nth, ns, 2)` of `(dy / rho0, nu')`, interpolated multilinearly in
    `(zeta, nu, eps)`; NaN where a corner stride failed."""
    g = table.grid
    vs = jnp.sqrt(hopper.g * hopper.rho0)
    zeta = (apex[1] - h) / hopper.rho0
    nu = apex[2] / vs
    eps = (goal[1] - h + 0.5 * goal[2] ** 2 / hopper.g) / hopper.rho0
    (iz, wz), (iv, wv), (ie, we) = (_locate(x, *a) for a, x in
                                    ((g.zeta, zeta), (g.nu, nu), (g.eps, eps)))
    zero = jnp.zeros((), jnp.int32)
    cube = jax.lax.dynamic_slice(table.values, (iz, iv, ie, zero, zero, zero),
                                 (2, 2, 2) + table.values.shape[3:])
    w = (jnp.stack([1 - wz, wz])[:, None, None] * jnp.stack([1 - wv, wv])[None, :, None]
         * jnp.stack([1 - we, we])[None, None, :])
    # A failed corner's NaN carries into its cells (no start there): next to the failure
    # boundary the map is steep and a start from it often fails.
    return jnp.einsum("abc,abcijk->ijk", w, cube)


def windless_equivalent(apex, goal, h, hopper: Hopper, wind):
    """The apex and goal of the windless stride whose stance is that of the stride from
    `apex` to `goal` in a flight acceleration `wind`, for the table's start: the apex
    moving at the touchdown speed, `a t_d` faster, and `a t_d^2 / 2` behind, the goal
    moving at the liftoff speed, `a t_u` slower, and `a t_u^2 / 2` behind (`t_d`, `t_u`:
    the falls from the apex and to the goal over a leg at rest length standing on `h`).
    In a headwind the windless table's start for the real apex lies beyond the stride's
    reversal, and the polish cannot come back from there (docs/slip.md, "Deadbeat")."""
    t_d, t_u = (safe_sqrt(2.0 * (z - h - hopper.rho0) / hopper.g) for z in (apex[1], goal[1]))
    seen = jnp.stack([apex[0] - 0.5 * wind * t_d**2, apex[1], apex[2] + wind * t_d])
    aim = jnp.stack([goal[0] - 0.5 * wind * t_u**2, goal[1], goal[2] - wind * t_u])
    return seen, aim


def _target(apex, goal, hopper: Hopper):
    """The stride's target in the table's units: `((y* - y) / rho0, ydot* / sqrt(g rho0))`."""
    return jnp.stack([(goal[0] - apex[0]) / hopper.rho0,
                      goal[2] / jnp.sqrt(hopper.g * hopper.rho0)])


def _bilinear(plane, p, grid: TableGrid):
    """The plane's bilinear interpolant at `p = (th, s)` and its Jacobian (`(2,)`, `(2, 2)`;
    the cell's own slopes, also on its edges)."""
    (i, wi), (j, wj) = _locate(p[0], *grid.th), _locate(p[1], *grid.s)
    c = jax.lax.dynamic_slice(plane, (i, j, jnp.zeros((), jnp.int32)), (2, 2, 2))
    value = ((1 - wi) * (1 - wj) * c[0, 0] + wi * (1 - wj) * c[1, 0]
             + (1 - wi) * wj * c[0, 1] + wi * wj * c[1, 1])
    d_th = ((c[1, 0] - c[0, 0]) * (1 - wj) + (c[1, 1] - c[0, 1]) * wj) * (
        (grid.th[2] - 1) / (grid.th[1] - grid.th[0]))
    d_s = ((c[0, 1] - c[0, 0]) * (1 - wi) + (c[1, 1] - c[1, 0]) * wi) * (
        (grid.s[2] - 1) / (grid.s[1] - grid.s[0]))
    return value, jnp.stack([d_th, d_s], axis=1)


def _refine(plane, p0, target, grid: TableGrid, steps: int = REFINE_STEPS, e0=None):
    """Damped Gauss-Newton steps on the plane's bilinear interpolant in `(th, s)` from `p0`
    towards `target` (no stride is run), each clipped to `REFINE_MAX` and to the axes: a
    step that does not lower the interpolated squared error (or enters a NaN cell) is not
    taken and quarters the next one; a taken one doubles it (up to a full step). On a
    target out of reach it ends near the interpolant's least error. `e0`: the squared
    error at `p0` (default: the interpolant's; a grid node next to a failed one has a value
    of its own but a NaN interpolant). Returns the end point and its squared error."""
    lo = jnp.array([grid.th[0], grid.s[0]])
    hi = jnp.array([grid.th[1], grid.s[1]])
    limit = jnp.asarray(REFINE_MAX)

    def err2(p):
        r = _bilinear(plane, p, grid)[0] - target
        return jnp.where(jnp.all(jnp.isfinite(r)), jnp.sum(r**2), jnp.inf)

    def step(_, carry):
        p, e, trust = carry
        value, jac = _bilinear(plane, p, grid)
        normal = jac.T @ jac
        d = jnp.linalg.solve(normal + 1e-12 * jnp.trace(normal) * jnp.eye(2),
                             jac.T @ (value - target))
        d = jnp.clip(jnp.where(jnp.all(jnp.isfinite(d)), trust * d, 0.0), -limit, limit)
        q = jnp.clip(p - d, lo, hi)
        eq = err2(q)
        better = eq < e
        return (jnp.where(better, q, p), jnp.where(better, eq, e),
                jnp.where(better, jnp.minimum(2.0 * trust, 1.0), 0.25 * trust))

    e0 = err2(p0) if e0 is None else e0
    p, e, _ = jax.lax.fori_loop(0, steps, step, (p0, e0, jnp.asarray(1.0)))
    return p, e


def table_starts(table: SlipTable, apex, goal, h, hopper: Hopper, n_starts: int,
                 terrain=None, wind=None, flat_if_none=False):
    """`n_starts` starting points `(th, s)` of the deadbeat for the stride, best first, with
    their squared errors in the table's units (the refined point's, or its grid node's
    where refining finds nothing better; inf: no start).

    The best cell of each of the `n_starts` best `s` columns (C2 of eq 16 on the plane,
    `table_slice`), each refined by Newton steps on the plane's interpolant (`_refine`),
    then ordered by the refined error.

    With `terrain`, a touchdown angle whose foot does not land on a block at the foothold's
    height `h` (the descent with `wind` meets a wall, a hole, the map's end or another
    block: `jaxhop._models.flight.touchdown`) is no start: the table knows flat ground only.
    With `flat_if_none`, where no angle lands there, the starts are those of flat ground,
    still with error inf (the polish's strides then find the block; `deadbeat_table`
    without `fallback`).
    """
    from ..flight import OK, touchdown

    g = table.grid
    seen, aim = (apex, goal) if wind is None else windless_equivalent(apex, goal, h, hopper,
                                                                        wind)
    plane = table_slice(table, seen, aim, h, hopper)
    target = _target(seen, aim, hopper)
    scale = jnp.stack([hopper.rho0, jnp.sqrt(hopper.g * hopper.rho0)])
    err = (plane - target) * scale
    cost = W_POS * err[..., 0] ** 2 + W_VEL * err[..., 1] ** 2
    cost = jnp.where(jnp.isfinite(cost), cost, jnp.inf)  # (nth, ns)
    th_axis = jnp.linspace(*g.th)
    if terrain is not None:
        def lands(th):
            offset = hopper.rho0 * jnp.stack([jnp.sin(th), -jnp.cos(th)])
            code, block, *_ = touchdown(apex, offset, terrain, hopper,
                                        *([] if wind is None else [wind]))
            return (code == OK) & (terrain.heights[block] == h)

        landing = jax.vmap(lands)(th_axis)
        flat = ~jnp.any(landing[:, None] & jnp.isfinite(cost))
        if flat_if_none:
            landing = landing | flat
        cost = jnp.where(landing[:, None], cost, jnp.inf)
        plane = jnp.where(landing[:, None, None], plane, jnp.nan)
    s_axis = jnp.linspace(*g.s)
    best_th = jnp.argmin(cost, axis=0)
    _, cols = jax.lax.top_k(-jnp.min(cost, axis=0), n_starts)
    cells = jnp.stack([th_axis[best_th[cols]], s_axis[cols]], axis=1)
    # A start's error is its node's (finite wherever the node's stride completed), so only
    # a plane without a completed, landing node has no start.
    node = jnp.sum((plane[best_th[cols], cols] - target) ** 2, axis=-1)
    node = jnp.where(jnp.isfinite(node), node, jnp.inf)
    refined, errs = jax.vmap(lambda p, e: _refine(plane, p, target, g, e0=e))(cells, node)
    order = jnp.argsort(errs)
    errs = errs[order]
    if terrain is not None and flat_if_none:
        errs = jnp.where(flat, jnp.inf, errs)
    return refined[order], errs


# Table start (`jaxhop._models.slip.table`; `docs/slip.md`, "Deadbeat"): Gauss-Newton from one
# start at a time, each only where the ones before it missed `accept`: the table's
# TABLE_STARTS refined starts, best first (stage 1: the first; stage 2: the others), then
# (`fallback`) the multi-start solver's starts (`initial_guesses`, stage 3). A table start's
# polish stops at the trial strides' noise floor (`polish_cost`, or three rejected steps
# in a row), on a target out of reach (an accepted step that gains less than POLISH_STALL
# of C2), or after POLISH_ITER steps; a multi-start one has the same stops after up to
# MULTI_ITER steps. One start at a time keeps a single Gauss-Newton program in the
# compiled decision (a vmap per stage compiled one per stage).
TABLE_STARTS = 3
POLISH_ITER = 6
POLISH_MIN_TRUST = 1.0 / 64
POLISH_STALL = 1e-3
# A deadbeat solve is accepted below this C2 (an apex error of 0.1 mm); a decision accepts
# its own tolerance (`jaxhop._control.decisions.SLIP_STAGE_C2`).
ACCEPT_C2 = 1e-8
N_MULTI = 3  # the multi-start solver's starts (`initial_guesses`)
MULTI_ITER = 16  # their longest polish (the same stops as a table start's)


def polish_cost(tol):
    """The polish's noise floor: C2 of an apex error of ten times the trial strides'
    accuracy (1e-14 at SEARCH_TOL, 1e-8 at DECISION_TOL; `jaxhop._models.slip.kernels`)."""
    return (10.0 * tol.accuracy) ** 2


def deadbeat_table(apex, goal, h, hopper, tol, table, terrain=None, wind=None,
                    fallback=True, accept=ACCEPT_C2, first=0, last=None):
    """The table-start solve: `(th_td, kc, c2, stage)`, `stage` that of the last start run
    (1-3). Starts `first .. last - 1` (traced; default: all, the multi-start ones only with
    `fallback`) are tried in order until one ends with C2 <= `accept`; the best end wins.
    The multi-start guesses are computed only when the loop reaches them.

    Where no touchdown angle of the table lands on the foothold's block (no table start),
    with `fallback` (traced) only the multi-start solver's starts run. `fallback=False`
    (static: a reactive decision) leaves the multi-start solver out of the program, which
    halves its size: the table's starts over flat ground run there instead, each with the
    multi-start's longer polish (`table_starts`, `flat_if_none`; docs/slip.md,
    "Deadbeat")."""
    multi = fallback is not False
    starts, errs = table_starts(table, apex, goal, h, hopper, TABLE_STARTS, terrain, wind,
                                flat_if_none=not multi)
    n_all = TABLE_STARTS + N_MULTI if multi else TABLE_STARTS
    none = ~jnp.isfinite(errs[0])
    if multi:
        first = jnp.where(none, jnp.maximum(first, TABLE_STARTS), first)
        if last is None:
            last = jnp.where(jnp.asarray(fallback) | none, n_all, TABLE_STARTS)
    elif last is None:
        last = n_all
    kc_lo, kc_hi = kc_limits(hopper)

    def more(carry):
        i, _, c2, _ = carry
        return (i < last) & (c2 > accept)

    def next_start(carry):
        i, p, c2, guesses = carry
        table_start = i < TABLE_STARTS
        p0 = starts[jnp.minimum(i, TABLE_STARTS - 1)]
        if multi:
            guesses = run_once((i >= TABLE_STARTS) & jnp.all(jnp.isnan(guesses)),
                               lambda zero: initial_guesses(apex + zero, goal, h, hopper, tol,
                                                            terrain, wind),
                               guesses, tol.fixed_loops)
            p0 = jnp.where(table_start, p0, guesses[jnp.clip(i - TABLE_STARTS, 0, N_MULTI - 1)])

        th, kc, c = deadbeat_gradient(apex, goal, h, hopper, tol,
                                       jnp.where(table_start & ~none, POLISH_ITER, MULTI_ITER),
                                       polish_cost(tol), terrain, wind, p0[None],
                                       POLISH_MIN_TRUST, POLISH_STALL, max(POLISH_ITER, MULTI_ITER))
        better = c < c2
        q = jnp.stack([th, (kc - kc_lo) / (kc_hi - kc_lo)])
        return i + 1, jnp.where(better, q, p), jnp.minimum(c, c2), guesses

    carry = (jnp.asarray(first), starts[0], jnp.asarray(jnp.inf),
             jnp.full((N_MULTI if multi else 0, 2), jnp.nan))
    i, p, c2, _ = bounded_while(more, next_start, carry, n_all, tol.fixed_loops)
    stage = jnp.where(i <= 1, 1, jnp.where(i <= TABLE_STARTS, 2, 3))  # of the last start
    return p[0], kc_lo + p[1] * (kc_hi - kc_lo), c2, stage


# The passes of `deadbeat_slips`: the starts each runs.
_PASSES = ((0, 1), (1, TABLE_STARTS), (TABLE_STARTS, TABLE_STARTS + N_MULTI))


@functools.cache
def _pass_fn():
    def one(apex, goal, h, first, last, hopper, table):
        th, kc, c2, stage = deadbeat_table(apex, goal, h, hopper, SEARCH_TOL, table,
                                            first=first, last=last)
        return th, kc, c2, stage

    return jit(jax.vmap(one, (0, 0, 0, None, None, None, None)))


_controls_batch = jit(jax.vmap(lambda a, g, h, th, kc, hopper: clipped_controls(
    a, g, h, th, kc, hopper, SEARCH_TOL), (0, 0, 0, 0, 0, None)))


def deadbeat_slips(apex, goal, h, hopper: Hopper, table=None, accept: float = ACCEPT_C2,
                   chunk: int = 32):
    """`deadbeat_slip` on a batch of targets over flat footholds, with the table's stages as
    passes over the batch: every target runs the table's best start, only those it misses
    (C2 above `accept`) run the other table starts, only those still missing run the
    multi-start solver's starts.
    Every pass runs in chunks of `chunk` targets (the last one padded), dealt to the local
    devices in turn: one compiled program serves every pass and every batch size (a
    program of this solver takes 20-30 s to compile on a 2-core CPU), and no lane waits
    for a solve it does not need. On an accelerator a larger `chunk` fills the device.

    Arguments:
        apex, goal: `(n, 3)`; h: `(n,)` or a scalar. table: default the cached
        `jaxhop._models.slip.table.slip_table()`.

    Returns:
        `(u, ok, stage)` as NumPy arrays: the controls and flags of `deadbeat_slip`, and the
        last stage each target ran (3: the multi-start fallback).
    """
    from ..._core.batching import chunked_map

    table = slip_table() if table is None else table
    apex = np.atleast_2d(np.asarray(apex, float))
    goal = np.atleast_2d(np.asarray(goal, float))
    n = apex.shape[0]
    h = np.broadcast_to(np.asarray(h, float), (n,))
    th, kc = np.zeros(n), np.zeros(n)
    c2 = np.full(n, np.inf)
    stage = np.zeros(n, np.int32)
    todo = np.arange(n)
    for first, last in _PASSES:
        if todo.size == 0:
            break
        out = chunked_map(_pass_fn(), todo.size, chunk, (apex[todo], goal[todo], h[todo]),
                          (first, last, hopper, table))
        better = out[2] < c2[todo]
        th[todo] = np.where(better, out[0], th[todo])
        kc[todo] = np.where(better, out[1], kc[todo])
        c2[todo] = np.minimum(out[2], c2[todo])
        stage[todo] = out[3]
        todo = todo[c2[todo] > accept]
    u, ok = _controls_batch(apex, goal, h, th, kc, hopper)
    return np.asarray(u), np.asarray(ok), stage
