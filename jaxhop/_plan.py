"""Build a reactive plan for a terrain: situate, instantiate, graph, deploy (Figs. 7, 10-12)."""

from __future__ import annotations

import dataclasses
import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from . import _stages as S
from ._deploy import by_robustness, deploy
from ._errors import InputError
from ._graph import count_edges, situated_matrix
from ._params import Hopper
from ._policies import PairGrid, SituatedTable, candidate_pairs, situated_table
from ._progress import Progress
from ._stages import PROBE_HALF_WIDTH, SAFETY_WE, SAFETY_WG
from ._templates import Templates, paper_templates
from ._terrain import Terrain, segments

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

    def tables(self) -> PlanTables:
        best_pos, best_inst = self.best_per_situated()
        return PlanTables(self.table(), self.templates, self.terrain, jnp.asarray(best_pos),
                          jnp.asarray(best_inst), jnp.asarray(self.goals))

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
        pickbest: deployment priority (see `_deploy`).
        probe: half-width (m, m, m/s) of the safety-sampling box around each goal.
        progress: show a progress bar.

    Returns:
        The `Plan`.

    Raises:
        InputError: no goal, or a goal that is not finite.
    """
    laps = S.Laps()
    templates = paper_templates() if templates is None else templates
    hopper = Hopper() if hopper is None else hopper
    goal = _check_goal(terrain if goal is None else goal)
    lay = S.Layout(terrain, segments(terrain, templates.seg_length), templates, hopper)
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
    g_ok, g_margin = S.goal_policies(lay, goal, np.arange(lay.n_sit), chunk=None)
    goal_sit = np.nonzero(g_ok)[0]
    sit, tgt, all_goals, all_margin, dg, is_goal = S.instantiated(
        goal, goal_sit, g_margin[goal_sit], rows[found], cols[found], goals[found],
        margin[found], margin_d[found])
    safety = S.safety(lay, sit, dg)
    ids, inside = S.prepares_rows(lay, all_goals)
    p = situated_matrix(inside, ids, lay.n_sit)
    laps("prepares")
    # Each goal must lie in the domain it was chosen for; drop any that do not (none should).
    keep = S.holds_own_target(p, tgt, is_goal)
    n_dropped = int((~keep).sum())
    if n_dropped:
        warnings.warn(f"{n_dropped} instantiated goals failed the exact domain test; dropped",
                      stacklevel=2)
        sel = np.nonzero(keep)[0]
        sit, tgt, all_goals, all_margin = sit[sel], tgt[sel], all_goals[sel], all_margin[sel]
        safety, is_goal, p = safety[sel], is_goal[sel], p[sel]
    robustness = S.robustness(lay, all_goals, probe) if sit.size else np.ones(0)
    robustness[is_goal] = 1.0
    laps("safety_sampling")
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


def _check_goal(goal_or_terrain) -> np.ndarray:
    if isinstance(goal_or_terrain, Terrain):
        if goal_or_terrain.goal is None:
            raise InputError(f"terrain {goal_or_terrain.name!r} has no default goal; pass one")
        goal_or_terrain = goal_or_terrain.goal
    goal = np.asarray(goal_or_terrain, dtype=float)
    if goal.shape != (3,) or not np.all(np.isfinite(goal)):
        raise InputError(f"goal: expected three finite numbers y,z,ydot, got {goal_or_terrain!r}")
    return goal
