"""Build a reactive plan for a terrain: situate, instantiate, graph, deploy (Figs. 7, 10-12)."""

from __future__ import annotations

import dataclasses
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from .._core.batching import bucket, pad_terrain, pad_to, pow2_at_least
from .._core.errors import InputError
from .._core.params import Hopper
from .._core.progress import Progress
from .._core.terrain import Terrain, segments
from . import stages as S
from .deploy import by_robustness, deploy
from .graph import count_edges, situated_matrix
from .policies import (
    PairGrid,
    SituatedTable,
    candidate_pairs,
    goal_y_slack,
    situated_table,
)
from .regions import goal_height_bounds, goal_position_bounds
from .stages import PROBE_HALF_WIDTH, SAFETY_WE, SAFETY_WG
from .templates import Templates, paper_templates

__all__ = ["SAFETY_WE", "SAFETY_WG", "PROBE_HALF_WIDTH", "Plan", "PlanTables", "build_plan",
           "templates_for"]

_DEFAULT_GRID = PairGrid()


class PlanTables(eqx.Module):
    """What the jitted execution controller needs (fixed shapes per plan)."""

    table: SituatedTable
    templates: Templates
    terrain: Terrain
    best_pos: jnp.ndarray
    best_inst: jnp.ndarray
    goals: jnp.ndarray
    #: The SLIP deadbeat's start table (`jaxhop._models.slip.table`); `None`: multi-start solves.
    slip: object = None
    #: Holding strides of the adaptive controller (`jaxhop.parkour`, `hold_tables`): per
    #: situated policy with no deployed instantiated policy, the rank of its best
    #: undeployed one (`best_inst` then names that one), `iinfo(int32).max` elsewhere.
    #: `None`: no holding.
    hold_pos: jnp.ndarray | None = None

    def padded(self, n_blocks: int, n_seg: int, n_inst: int) -> PlanTables:
        """These tables with room for `n_blocks` terrain blocks, `n_seg` segments and
        `n_inst` instantiated policies, so that plans of similar size share one compiled
        controller. The padding never matches: padded blocks have no length and no
        segments, padded segments lie far off the map, and their situated policies have no
        deployed policy."""
        t = self.table
        nb, ns = t.block_first.shape[0], t.seg_block.shape[0]
        end = self.terrain.ends[-1]
        table = SituatedTable(pad_to(t.centre, n_seg, jnp.array([1e6, 0.0])),
                              pad_to(t.seg_block, n_seg, nb - 1),
                              pad_to(t.edge_distance, n_seg, 0.0),
                              pad_to(t.block_first, n_blocks, ns),
                              pad_to(t.block_count, n_blocks, 0),
                              pad_to(t.block_left, n_blocks, end))
        k = n_seg * self.templates.n
        big = jnp.iinfo(jnp.int32).max
        hold = None if self.hold_pos is None else pad_to(self.hold_pos, k, big)
        return PlanTables(table, self.templates, pad_terrain(self.terrain, n_blocks),
                          pad_to(self.best_pos, k, big), pad_to(self.best_inst, k, 0),
                          pad_to(self.goals, n_inst, 0.0), self.slip, hold)


def bucketed(tables: PlanTables, true_terrain: Terrain) -> tuple[PlanTables, Terrain]:
    """`tables` and the true map padded up to shape buckets (`PlanTables.padded`): the
    blocks to a multiple of 32 (one spare at least), the segments to a multiple of 64, the
    instantiated policies to a power of two. A SLIP controller takes minutes to compile;
    with these buckets a perceived map, or another terrain of about the size of the
    built-in ones, runs on the program compiled for the first, from a BHop or a SLIP plan
    (the maps lose their names, which are static fields; the templates keep only what runs
    read of the SLIP adjustments and the segments, the foot lead and the segment length,
    traced: `Templates.for_runs`)."""
    nb = bucket(max(tables.terrain.n_blocks, true_terrain.n_blocks) + 1, 32)
    ns = bucket(tables.table.seg_block.shape[0], 64)
    ni = pow2_at_least(tables.goals.shape[0])
    tables = tables.padded(nb, ns, ni)
    return (dataclasses.replace(tables, terrain=tables.terrain.unnamed(),
                                templates=tables.templates.for_runs()),
            pad_terrain(true_terrain, nb).unnamed())


@dataclasses.dataclass
class Plan:
    """A deployed reactive plan.

    Attributes:
        terrain: the map the plan was built on (the perceived map under ground noise).
        templates, hopper: the templates and parameters used.
        goal: the global goal `(y, z, ydot)`.
        situated: `(n_inst,)` situated policy of each instantiated policy.
        target: `(n_inst,)` situated policy it was instantiated to prepare (-1: goal policy).
        goals: `(n_inst, 3)` goal apex of each instantiated policy.
        safety, margin: `(n_inst,)` eq 34 and the goal's margin in its intersection.
        is_goal: `(n_inst,)` goal policies.
        robustness: `(n_inst,)` safety-sampling score of each goal (`goal_robustness`).
        prepares: `P[a, s] = [goals[a] ∈ D(s)]` (CSR).
        order: deployed instantiated policies in priority order.
        stats: counts and timings (`seconds`, `stage_seconds`).
    """

    terrain: Terrain
    templates: Templates
    hopper: Hopper
    goal: np.ndarray
    situated: np.ndarray
    target: np.ndarray
    goals: np.ndarray
    safety: np.ndarray
    margin: np.ndarray
    is_goal: np.ndarray
    robustness: np.ndarray
    prepares: sp.csr_matrix
    order: np.ndarray
    stats: dict

    @property
    def n_situated(self) -> int:
        return int(self.stats["n_situated"])

    def table(self) -> SituatedTable:
        return situated_table(self.terrain, segments(self.terrain, self.templates.seg_length),
                              self.templates.seg_length)

    def best_per_situated(self):
        """First deployed instantiated policy of each situated policy and its position."""
        big = np.iinfo(np.int32).max
        best_pos = np.full(self.n_situated, big, dtype=np.int64)
        best_inst = np.zeros(self.n_situated, dtype=np.int64)
        pos = np.arange(self.order.size)
        sit = self.situated[self.order]
        first = np.full(self.n_situated, big, dtype=np.int64)
        np.minimum.at(first, sit, pos)
        has = first < big
        best_pos[has] = first[has]
        best_inst[has] = self.order[first[has]]
        return best_pos, best_inst

    def tables(self, slip: bool = False) -> PlanTables:
        """The plan's arrays for the jitted controller; with `slip`, the SLIP deadbeat's
        start table too (built once, then cached on disk: `jaxhop._models.slip.table`)."""
        from .._models.slip.table import slip_table

        best_pos, best_inst = self.best_per_situated()
        return PlanTables(self.table(), self.templates, self.terrain, jnp.asarray(best_pos),
                          jnp.asarray(best_inst), jnp.asarray(self.goals),
                          slip_table() if slip else None)

    def summary(self) -> dict:
        keys = ("n_segments", "n_situated", "n_candidate_pairs", "n_instantiated",
                "n_goal_policies", "n_deployed", "n_edges", "seconds")
        return {k: self.stats[k] for k in keys}


def build_plan(
    terrain: Terrain,
    goal=None,
    templates: Templates | None = None,
    hopper: Hopper | None = None,
    *,
    grid: PairGrid = _DEFAULT_GRID,
    pickbest=by_robustness,
    probe: float = PROBE_HALF_WIDTH,
    progress: bool = True,
) -> Plan:
    """Build the reactive plan of the 2012 paper for the BHop model.

    Arguments:
        terrain: the map (the planner's view of it).
        goal: global goal `(y, z, ydot)`; default: the terrain's.
        templates, hopper: default: the 20 templates of eq 33, an 80 kg, 1 m hopper.
        grid: intersection sampling sizes.
        pickbest: deployment priority (see `deploy.py`).
        probe: half-width (m, m, m/s) of the safety-sampling box around each goal.
        progress: show a progress bar.

    Returns:
        The `Plan`.

    Raises:
        InputError: no goal, a goal that is not finite, or a goal that no situated policy
            reaches (no goal policy; the message says why, `goal_refusal`).
    """
    laps = S.Laps()
    templates = paper_templates() if templates is None else templates
    hopper = Hopper() if hopper is None else hopper
    goal = check_goal(terrain if goal is None else goal)
    lay = S.Layout(terrain, segments(terrain, templates.seg_length), templates, hopper)
    g_ok, g_margin = S.goal_policies(lay, goal, np.arange(lay.n_sit), chunk=None)
    goal_sit = np.nonzero(g_ok)[0]
    if goal_sit.size == 0:
        raise InputError(goal_refusal(terrain, goal, templates, hopper))
    rows, cols = candidate_pairs(lay.gf_world, lay.d_world)
    laps("boxes")
    n_pairs = rows.size
    # Screen: drop pairs empty even before the collision clauses (most of them).
    keep = S.screen(lay, lay.pair_args(rows, cols), grid)
    rows, cols = rows[keep], cols[keep]
    laps("screen")
    with Progress(rows.size, "instantiate", "pair", enabled=progress) as bar:
        found, goals, margin, margin_d = S.instantiate(lay, lay.pair_args(rows, cols), grid,
                                                       bar)
    laps("instantiate")
    sit, tgt, all_goals, all_margin, dg, is_goal = S.instantiated(
        goal, goal_sit, g_margin[goal_sit], rows[found], cols[found], goals[found],
        margin[found], margin_d[found])
    safety = S.safety(lay, sit, dg)
    ids, inside, robustness = S.prepares_and_robustness(lay, all_goals, probe)
    p = situated_matrix(inside, ids, lay.n_sit)
    # Each goal must lie in the domain it was chosen for; drop any that do not (none should).
    keep = S.holds_own_target(p, tgt, is_goal)
    n_dropped = int((~keep).sum())
    if n_dropped:
        warnings.warn(f"{n_dropped} instantiated goals failed the exact domain test; dropped",
                      stacklevel=2)
        sel = np.nonzero(keep)[0]
        sit, tgt, all_goals, all_margin = sit[sel], tgt[sel], all_goals[sel], all_margin[sel]
        safety, is_goal, p, robustness = safety[sel], is_goal[sel], p[sel], robustness[sel]
    robustness[is_goal] = 1.0
    laps("prepares_and_safety_sampling")
    order = deploy(p, sit, safety, is_goal, robustness, pickbest)
    laps("deploy")
    stats = S.counts(lay, n_pairs, rows.size, sit, is_goal, order, count_edges(p, sit),
                     n_dropped) | laps.stats()
    return Plan(terrain, templates, hopper, np.asarray(goal, float), sit, tgt, all_goals,
                safety, all_margin, is_goal, robustness, p.tocsr(), order, stats)


def templates_for(model: str = "bhop") -> Templates:
    """The templates a plan for `model` uses: eq 33's, with the SLIP adjustments for SLIP."""
    if model not in ("bhop", "slip"):
        raise InputError(f"model: expected 'bhop' or 'slip', got {model!r}")
    base = paper_templates()
    return base.for_slip() if model == "slip" else base


def check_goal(goal_or_terrain) -> np.ndarray:
    if isinstance(goal_or_terrain, Terrain):
        if goal_or_terrain.goal is None:
            raise InputError(f"terrain {goal_or_terrain.name!r} has no default goal; pass one")
        goal_or_terrain = goal_or_terrain.goal
    goal = np.asarray(goal_or_terrain, dtype=float)
    if goal.shape != (3,) or not np.all(np.isfinite(goal)):
        raise InputError(f"goal: expected three finite numbers y,z,ydot, got {goal_or_terrain!r}")
    return goal


def goal_refusal(terrain: Terrain, goal, templates: Templates, hopper: Hopper) -> str:
    """Why no situated policy reaches `goal` (a plan without goal policy), in one line.

    In order: off the map; over a hole; not a leg length above the block under it; a speed
    no template's `Gf` holds; a height outside every template's `Gf` at that speed
    (`goal_height_bounds`); no segment within a stride's reach (`goal_position_bounds`);
    else the rise to the goal meets a block (`ascent_y_bounds`).
    """
    y, z, ydot = (float(x) for x in goal)
    where = f"goal ({y:g}, {z:g}, {ydot:g}) has no goal policy:"
    y0, y1 = terrain.y_range
    if not y0 <= y <= y1:
        return f"{where} it lies off the map [{y0:g}, {y1:g}]"
    blocks = terrain.blocks()
    under = [b for b in blocks if b[0] <= y <= b[1]]
    if not under:
        left = max(e for _, e, _ in blocks if e < y)
        right = min(s for s, _, _ in blocks if s > y)
        return (f"{where} it lies over the hole {left:g}-{right:g} m, and no stride from a "
                "block beside it ends there")
    s, e, h = max(under, key=lambda b: b[2])
    block = f"the block under it ({s:g}-{e:g} m, height {h:g} m)"
    rho0 = float(hopper.rho0)
    if z - h - rho0 <= 0:
        return f"{where} it is not a leg length ({rho0:g} m) above {block}"
    lo, hi, _ = _goal_reach(goal, np.array([[y, h]]), templates, hopper)
    zr, lo, hi = z - h - rho0, lo[0], hi[0]
    speed_ok = hi >= lo
    if not speed_ok.any():
        return f"{where} no template's feasible goal set holds the speed {ydot:g} m/s"
    if not np.any(speed_ok & (lo <= zr) & (zr <= hi)):
        energy = 0.5 * float(hopper.m) * ydot**2 + float(hopper.m * hopper.g) * zr
        return (f"{where} its height {zr:.3g} m above {block} (apex energy {energy:.4g} J) "
                f"lies outside every template's goal heights at {ydot:g} m/s "
                f"({lo[speed_ok].min():.3g}-{hi[speed_ok].max():.3g} m)")
    centre = np.asarray(segments(terrain, templates.seg_length).centre)
    reach = _goal_reach(goal, centre, templates, hopper)[2].any(axis=1)
    if not reach.any():
        return (f"{where} no ground segment ({templates.seg_length:g} m) lies within a "
                f"stride's reach of it (on {block} or elsewhere)")
    return (f"{where} every stride that ends there meets a block on its way up (from the "
            f"segments at y = {', '.join(f'{c:g}' for c in centre[reach, 0][:4])})")


def _goal_reach(goal, centre, templates: Templates, hopper: Hopper):
    """`(zr_lo, zr_hi, reach)`, each `(n_seg, n_templates)`: `Gf`'s height interval at the
    goal's speed, and whether `Gf` of each template on each segment `(py, h)` holds the goal
    (collision clauses aside)."""
    y, z, ydot = (jnp.asarray(float(x)) for x in goal)

    def one(t, py, h):
        tmpl = templates.row(t)
        lo, hi = goal_height_bounds(ydot, tmpl, hopper)
        zr = z - h - hopper.rho0
        ylo, yhi = goal_position_bounds(ydot, zr, tmpl, hopper)
        tol = goal_y_slack(y, py, templates.half_length)
        return lo, hi, ((hi >= lo) & (lo <= zr) & (zr <= hi) & (zr > 0)
                        & (y - py >= ylo - tol) & (y - py <= yhi + tol))

    per_seg = jax.vmap(one, (0, None, None))
    out = jax.vmap(per_seg, (None, 0, 0))(jnp.arange(templates.n), jnp.asarray(centre[:, 0]),
                                          jnp.asarray(centre[:, 1]))
    return tuple(np.asarray(x) for x in out)
