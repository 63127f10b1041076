"""The stages of a reactive plan, shared by full builds and course updates (Figs. 7, 10-12).

situate -> candidate pairs -> screen -> instantiate -> goal policies -> prepares -> safety
sampling -> deploy. Each jitted stage is a one-sample function of `policies.py` vmapped over
a batch and run by `chunked_map` on a few fixed chunk shapes (`Layout.chunking`), so that a
whole plan, or a whole course of updates, compiles each stage at most twice.
"""

from __future__ import annotations

import functools
import hashlib
import os
import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._core.batching import chunked_map
from .._core.params import Hopper
from .._core.programs import jit, stored_array, stored_program
from .._core.terrain import Terrain
from .policies import (
    PROBE_CENTRE,
    ascent_sides,
    candidate_situated,
    descent_sides,
    goal_policy_margin,
    goal_robustness,
    landing_window,
    pair_goal,
    pair_limits,
    pair_may_intersect,
    probe_candidates,
    situated_table,
    tall,
    template_boxes,
)
from .regions import foot_lead
from .templates import Templates

#: Weights of the edge distance (cubed) and of the goal margin in the safety of eq 34.
SAFETY_WE = 0.5
SAFETY_WG = 1.0
#: Half-width (m, m, m/s) of the safety-sampling box around each goal, 1 m hopper.
PROBE_HALF_WIDTH = 0.2
#: Chunk sizes: pairs instantiated, pairs screened (cheap: 4x), rows of `P`, probes. On
#: a CPU smaller chunks do less work: with 1 024 pairs and 2 048 rows `reference` builds
#: in 1.6-1.7 CPU seconds against 2.3-2.5 with 4 096 and 8 192, the plan bit for bit the
#: same (docs/planning.md, "Chunks that fit the caches").
PAIR_CHUNK = 1024
SCREEN_CHUNK = 4 * PAIR_CHUNK
ROW_CHUNK = 2048
PROBE_CHUNK = 16384
GOAL_CHUNK = 1024
#: On a GPU or TPU every chunk is this many times larger (a batch costs there about what
#: its longest lane costs).
ACCELERATOR_CHUNK_SCALE = 4


# --- one sample, vmapped at the edge ------------------------------------------------------


def _screen(ti, si, tj, sj, boxes, table, templates, hopper, limits, grid):
    return jax.vmap(pair_may_intersect, (0, 0, 0, 0, 0, None, None, None, None, None))(
        ti, si, tj, sj, boxes, table, templates, hopper, grid, limits)


def _pairs(ti, si, tj, sj, boxes, table, templates, terrain, hopper, limits, sides, grid,
           rise=True):
    return jax.vmap(pair_goal, (0, 0, 0, 0, 0) + (None,) * 8)(
        ti, si, tj, sj, boxes, table, templates, terrain, hopper, grid, rise, limits, sides)


def _rows(goals, allowed, table, templates, terrain, hopper, window=None):
    ids, inside = jax.vmap(candidate_situated, (0, None, None, None, None, None))(
        goals, table, templates, terrain, hopper, window)
    return ids, inside & allowed[ids]


def _rows_and_robustness(goals, allowed, table, templates, terrain, hopper, half_width):
    """`_rows` and `_robustness` of each goal from one set of touchdowns: a goal is the
    centre of its own probe box."""
    def one(goal):
        ids, inside = probe_candidates(goal, table, templates, terrain, hopper, half_width)
        c = PROBE_CENTRE
        return (ids[c], inside[c] & allowed[ids[c]],
                jnp.mean(jnp.any(inside, axis=1).astype(float)))

    return jax.vmap(one)(goals)


def _goal_policies(goal, ti, si, table, templates, terrain, hopper):
    return jax.vmap(goal_policy_margin, (None, 0, 0, None, None, None, None))(
        goal, ti, si, table, templates, terrain, hopper)


def _robustness(goals, table, templates, terrain, hopper, half_width):
    return jax.vmap(goal_robustness, (0, None, None, None, None, None))(
        goals, table, templates, terrain, hopper, half_width)


def _held(points, allowed, table, templates, terrain, hopper, window=None):
    """Whether an allowed situated policy's domain holds each probe point."""
    def held(p):
        ids, inside = candidate_situated(p, table, templates, terrain, hopper, window)
        return jnp.any(inside & allowed[ids])

    return jax.vmap(held)(points)


def stored(name: str, fn, **static):
    """`fn` with its `static` keyword arguments bound, compiled as a saved program
    (`jaxhop._core.programs.stored_program`, one per argument shapes): a fresh process
    loads each traced program from disk instead of tracing it again. The first updates of
    a course in a process traced every stage anew for an update's smaller chunks and
    windows (1.1-2.5 s against 0.1-0.3 s once traced; `docs/parkour_reactive.md`).
    `fn` returns one array or a tuple of several."""
    bound = partial(fn, **static)
    tag = "plan-" + name + "".join(f"-{k}={v}" for k, v in sorted(static.items()))

    def call(*args):
        out = stored_program(tag, bound, args)(*jax.tree_util.tree_leaves(args))
        return out[0] if len(out) == 1 else tuple(out)

    return call


limits_jit = jit(pair_limits, static_argnames=("grid",))


# --- situate ------------------------------------------------------------------------------

_BOX_CACHE: dict = {}
#: Template boxes of the built-in templates (eq 33's, BHop and SLIP-adjusted, 1 m hopper),
#: as `relative_boxes` computes them (`docs/make_template_boxes.py` writes the file).
SHIPPED_BOXES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                             "data", "template_boxes.npz")


def box_key(templates: Templates, hopper: Hopper) -> str:
    """The name of a set of template boxes: a SHA-256 of everything they depend on (the
    templates' rows, segment length and SLIP adjustments, which shift and bound the
    regions, and the hopper)."""
    key = (templates.as_array().tobytes(), float(templates.seg_length), templates.slip,
           float(hopper.m), float(hopper.g), float(hopper.rho0))
    return hashlib.sha256(repr(key).encode()).hexdigest()[:32]


@functools.cache
def _shipped() -> dict:
    try:
        with np.load(SHIPPED_BOXES) as f:
            return {k: f[k] for k in f.files}
    except OSError:
        return {}


def computed_boxes(templates: Templates, hopper: Hopper) -> np.ndarray:
    """`(2, n_templates, 3, 2)`: `template_boxes`, computed op by op."""
    return np.stack([np.asarray(x) for x in template_boxes(templates, hopper)])


def relative_boxes(templates: Templates, hopper: Hopper):
    """`template_boxes` as NumPy arrays, once per templates and hopper (`box_key`).

    They are computed op by op, not as one compiled program: compiled, XLA rewrites some
    divisions as multiplications and moves the boxes, and with them every pair's sampling
    grid, in the last bits (docs/planning.md). Op by op costs a fresh process about 6 s
    (2-core CPU), so the built-in templates' boxes ship with jaxhop and others are kept on
    disk beside the compiled programs (`stored_array`).
    """
    key = box_key(templates, hopper)
    if key not in _BOX_CACHE:
        both = _shipped().get(key)
        if both is None:
            both = stored_array("template-boxes", lambda: computed_boxes(templates, hopper),
                                (templates, hopper))
        _BOX_CACHE[key] = (both[0], both[1])
    return _BOX_CACHE[key]


def chunk_sizes(chunk: int, n: int, chunking: str) -> tuple[int, int]:
    """`chunked_map`'s `(size, tail)` for `n` items.

    `"fixed"`: `chunk` only. `"fit"`: `chunk // 8` if that holds all `n`, else `chunk`.
    `"tail"` (an update): whole `chunk`s, then `chunk // 8` for the rest, so that padding
    wastes at most `chunk // 8` items. Either way two shapes at most are compiled.
    """
    if chunking == "tail":
        return chunk, chunk // 8
    if chunking == "fit" and n <= chunk // 8:
        return chunk // 8, chunk // 8
    return chunk, chunk


def overlap(a, b):
    """The overlap of boxes `a` and `b`, `(..., 2)` intervals `(lo, hi)` (empty: lo > hi)."""
    return np.stack([np.maximum(a[..., 0], b[..., 0]), np.minimum(a[..., 1], b[..., 1])], -1)


class Layout:
    """The situated policies of a plan: one per template and segment (Fig. 7).

    Situated policy `i` is template `t_of[i]` on segment `s_of[i]`; `gf_world`, `d_world`
    are the `(n_sit, 3, 2)` boxes of its `Gf` and domain in world coordinates. The jitted
    stages see `jtable`, `jterrain` and `jallowed` (a course pads them to buckets) and cut
    their batches as `chunking` says (`chunk_sizes`).
    """

    chunking = "fixed"
    #: `descent_sides` and `ascent_sides` pad their block lists to a multiple of this.
    sides_step = 4

    def __init__(self, terrain: Terrain, segs, templates: Templates, hopper: Hopper):
        self.terrain, self.segs, self.templates, self.hopper = terrain, segs, templates, hopper
        self.table = situated_table(terrain, segs, templates.seg_length)
        self.nt, self.n_seg = templates.n, segs.n
        self.n_sit = self.nt * self.n_seg
        self.t_of = np.arange(self.n_sit) % self.nt
        self.s_of = np.arange(self.n_sit) // self.nt
        gf_rel, d_rel = self.gf_rel, self.d_rel = relative_boxes(templates, hopper)
        self._limits = {}
        centre = np.asarray(segs.centre)
        offset = np.stack([centre[self.s_of, 0], centre[self.s_of, 1] + hopper.rho0,
                           np.zeros(self.n_sit)], 1)
        self.gf_world = gf_rel[self.t_of] + offset[:, :, None]
        self.d_world = d_rel[self.t_of] + offset[:, :, None]
        self.jtable, self.jterrain = self.table, terrain.unnamed()
        self.jallowed = jnp.ones(self.n_sit, bool)

    def limits(self, grid):
        """The templates' `pair_limits` on `grid` (computed once per layout and grid)."""
        if grid not in self._limits:
            # A pair's ydot range, as `pair_args` has it (world and relative ydot agree).
            v_box = overlap(self.gf_rel[:, None, 2], self.d_rel[None, :, 2])
            self._limits[grid] = limits_jit(self.templates, self.hopper, jnp.asarray(v_box),
                                            grid=grid)
        return self._limits[grid]

    def side_windows(self):
        """`(descent, ascent)`: `(n_blocks, 2)` per block of `jterrain`, the `y` interval
        outside which no other block binds a collision clause of `pair_goal` for a pair that
        lands (descent) or takes off (ascent) there (`descent_sides`, `ascent_sides`).

        A higher block `c` left of the landing block binds the descent only through
        `e_c - ydot t_H - lead` (`ydot > 0`), at most `e_c + max|lead|`, and only where that
        exceeds the cell's own domain bound `d_lo` (`dom_lo = max(d_lo, c_lo)`), which
        lies in the domain boxes of the block's situated policies; mirrored on the right.
        On the rise a block left of the take-off block enters as `e_c + ydot t_up -
        min(ydot, 0) t_h <= e_c + max|ydot| max t_up` against the goal bound `g_lo` in the
        `Gf` boxes. Leaving out a term that never exceeds the other side of a `max` (`min`)
        changes no result, bit for bit (a test compares a course's pairs with and
        without). The boxes are widened by `rho0` besides, far more than their corner
        sampling can miss by (`template_boxes`).
        """
        n = self.jterrain.n_blocks
        block = np.asarray(self.table.seg_block)[self.s_of]
        rho0, g = float(self.hopper.rho0), float(self.hopper.g)
        v_lo = np.nanmin([self.d_rel[:, 2, 0], self.gf_rel[:, 2, 0]])
        v_hi = np.nanmax([self.d_rel[:, 2, 1], self.gf_rel[:, 2, 1]])
        lead = float(np.nanmax(np.abs(np.asarray(
            foot_lead(np.linspace(v_lo, v_hi, 2001), self.templates)))))
        t_up = np.sqrt(2.0 * max(float(np.nanmax(self.gf_rel[:, 1, 1])), 0.0) / g)
        rise = float(np.nanmax(np.abs(self.gf_rel[:, 2, :]))) * t_up

        def window(boxes, pad):
            # NaN boxes (a template without a region) pair with nothing: left out.
            lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
            np.fmin.at(lo, block, boxes[:, 0, 0])
            np.fmax.at(hi, block, boxes[:, 0, 1])
            return np.stack([lo - pad, hi + pad], 1)

        return window(self.d_world, rho0 + lead), window(self.gf_world, rho0 + rise)

    def pair_args(self, rows, cols):
        """`(ti, si, tj, sj, boxes)` of pairs `(rows, cols)`; `boxes`: their overlap in z, ydot."""
        boxes = overlap(self.gf_world[rows, 1:], self.d_world[cols, 1:])
        return self.t_of[rows], self.s_of[rows], self.t_of[cols], self.s_of[cols], boxes

    def map(self, fn, n, chunk, batched, consts=(), bar=None):
        """`chunked_map` with this layout's chunk sizes, on `plan_devices()`: `chunk` is a
        CPU's, `ACCELERATOR_CHUNK_SCALE` times larger on an accelerator."""
        devices = plan_devices()
        if devices[0].platform != "cpu":
            chunk *= ACCELERATOR_CHUNK_SCALE
        size, tail = chunk_sizes(chunk, n, self.chunking)
        return chunked_map(fn, n, size, batched, consts, tail=tail, bar=bar, devices=devices)


def plan_devices():
    """The devices the stages run on: every local device, but one on a CPU.

    CPU devices share the same cores, and a CPU executable is bound to its device: spread
    over several CPU devices, a fresh process compiles every stage once per device. On one
    device it compiles each once, at the price of a somewhat slower warm build in a
    process that has several CPU devices (measurements in docs/planning.md).
    """
    devices = jax.local_devices()
    return devices[:1] if devices[0].platform == "cpu" else devices


# --- the jitted stages --------------------------------------------------------------------


def screen(lay: Layout, args, grid) -> np.ndarray:
    """Which pairs may intersect before the collision clauses (`pair_may_intersect`)."""
    n = args[0].shape[0]
    if n == 0:
        return np.zeros(0, bool)
    return lay.map(stored("screen", _screen, grid=grid), n, SCREEN_CHUNK, args,
                   (lay.jtable, lay.templates, lay.hopper, lay.limits(grid)))


def instantiate(lay: Layout, args, grid, bar=None):
    """`(found, goal, margin, margin_d)` of each pair (`pair_goal`)."""
    n = args[0].shape[0]
    if n == 0:
        return np.zeros(0, bool), np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    rise = tall(lay.jterrain, lay.hopper)
    descent, ascent = lay.side_windows()
    sides = (descent_sides(lay.jterrain, lay.sides_step, descent),
             ascent_sides(lay.jterrain, lay.hopper, lay.sides_step, ascent))
    return lay.map(stored("pairs", _pairs, grid=grid, rise=rise), n, PAIR_CHUNK, args,
                   (lay.jtable, lay.templates, lay.jterrain, lay.hopper, lay.limits(grid),
                    sides), bar)


def goal_policies(lay: Layout, goal, idx, chunk: int | None = GOAL_CHUNK):
    """`(ok, margin)` of situated policies `idx` for the global goal (`goal_policy_margin`).

    `chunk=None`: one batch of all of `idx`.
    """
    consts = (lay.jtable, lay.templates, lay.jterrain, lay.hopper)
    goal = jnp.asarray(goal)
    fn = stored("goals", _goal_policies)
    if chunk is None:
        return tuple(np.asarray(x) for x in fn(goal, lay.t_of[idx], lay.s_of[idx], *consts))
    return lay.map(partial(fn, goal), idx.size, chunk, (lay.t_of[idx], lay.s_of[idx]), consts)


def prepares_rows(lay: Layout, goals):
    """`(ids, inside)`: the allowed situated policies whose domain holds each goal."""
    n = goals.shape[0]
    if n == 0:
        return np.zeros((0, 3 * lay.nt), np.int64), np.zeros((0, 3 * lay.nt), bool)
    window = landing_window(goals, lay.templates, lay.jterrain, lay.hopper)
    return lay.map(stored("rows", _rows, window=window), n, ROW_CHUNK, (goals,),
                   (lay.jallowed, lay.jtable, lay.templates, lay.jterrain, lay.hopper))


def prepares_and_robustness(lay: Layout, goals, half_width):
    """`prepares_rows` and `robustness` of each goal, in one pass over the probes."""
    n = goals.shape[0]
    if n == 0:
        return np.zeros((0, 3 * lay.nt), np.int64), np.zeros((0, 3 * lay.nt), bool), np.ones(0)
    fn = stored("rows-robustness", _rows_and_robustness)
    ids, inside, rob = lay.map(fn, n, ROW_CHUNK, (goals,),
                               (lay.jallowed, lay.jtable, lay.templates, lay.jterrain,
                                lay.hopper, jnp.full(3, float(half_width))))
    return ids, inside, np.array(rob, float)


def robustness(lay: Layout, goals, half_width) -> np.ndarray:
    """Safety sampling of each goal (`goal_robustness`)."""
    fn = stored("robustness", _robustness)
    return np.asarray(lay.map(fn, goals.shape[0], ROW_CHUNK, (goals,),
                              (lay.jtable, lay.templates, lay.jterrain, lay.hopper,
                               jnp.full(3, float(half_width)))), float)


def held(lay: Layout, points) -> np.ndarray:
    """Whether an allowed situated domain holds each probe point."""
    window = landing_window(points, lay.templates, lay.jterrain, lay.hopper)
    return lay.map(stored("held", _held, window=window), points.shape[0], PROBE_CHUNK, (points,),
                   (lay.jallowed, lay.jtable, lay.templates, lay.jterrain, lay.hopper))


def probe_offsets(half_width) -> np.ndarray:
    """`(27, 3)` probe offsets of safety sampling: the corners, edge and face centres and
    centre of the box `+- half_width` (`goal_robustness`'s probes)."""
    grid = np.stack(np.meshgrid(*[np.arange(-1.0, 2.0)] * 3, indexing="ij"), -1)
    return grid.reshape(-1, 3) * np.asarray(half_width, float)


# --- instantiated policies ----------------------------------------------------------------


def instantiated(goal, goal_sit, goal_margin, rows, cols, goals, margin, margin_d):
    """Goal policies first, then the nonempty pairs.

    Returns:
        `(situated, target, goals, margin, goal_margin_d, is_goal)`, one row each
        (`target` -1 for a goal policy).
    """
    n_goal = goal_sit.size
    sit = np.concatenate([goal_sit, rows]).astype(np.int64)
    tgt = np.concatenate([np.full(n_goal, -1), cols]).astype(np.int64)
    all_goals = np.concatenate([np.broadcast_to(goal, (n_goal, 3)), goals])
    all_margin = np.concatenate([goal_margin, margin])
    dg = np.concatenate([goal_margin, margin_d])
    return sit, tgt, all_goals, all_margin, dg, np.arange(sit.size) < n_goal


def holds_own_target(p, tgt, is_goal) -> np.ndarray:
    """Whether each goal lies in the domain it was chosen for (goal policies: true)."""
    return is_goal | np.asarray(p[np.arange(tgt.size), np.maximum(tgt, 0)]).ravel()


def safety(lay: Layout, sit, goal_margin_d) -> np.ndarray:
    """Eq 34: the segment's edge distance cubed and the goal's margin, weighted."""
    de = np.asarray(lay.segs.edge_distance)
    return SAFETY_WE * de[lay.s_of[sit]] ** 3 + SAFETY_WG * goal_margin_d


def counts(lay: Layout, n_pairs, n_screened, sit, is_goal, order, n_edges, n_dropped) -> dict:
    """The count keys of `Plan.stats`."""
    return {
        "n_segments": int(lay.n_seg),
        "n_situated": int(lay.n_sit),
        "n_candidate_pairs": int(n_pairs),
        "n_screened_pairs": int(n_screened),
        "n_instantiated": int(sit.size),
        "n_goal_policies": int(is_goal.sum()),
        "n_deployed": int(order.size),
        "n_edges": n_edges,
        "n_dropped": n_dropped,
    }


class Laps:
    """Wall-clock (and, with `cpu`, process CPU) seconds of each stage of a build."""

    def __init__(self, digits: int = 3, cpu: bool = False):
        self.digits, self.cpu = digits, cpu
        self.start = self.mark = time.perf_counter()
        self.c_start = self.c_mark = time.process_time()
        self.wall, self.cpu_s = {}, {}

    def __call__(self, name: str) -> None:
        now, cnow = time.perf_counter(), time.process_time()
        self.wall[name] = round(now - self.mark, self.digits)
        self.cpu_s[name] = round(cnow - self.c_mark, self.digits)
        self.mark, self.c_mark = now, cnow

    def stats(self) -> dict:
        """`seconds` and `stage_seconds` (and their CPU twins)."""
        out = {"seconds": round(time.perf_counter() - self.start, self.digits),
               "stage_seconds": self.wall}
        if self.cpu:
            out["cpu_seconds"] = round(time.process_time() - self.c_start, self.digits)
            out["stage_cpu_seconds"] = self.cpu_s
        return out
