"""Build a reactive plan for a terrain: situate, instantiate, graph, deploy (Figs. 7, 10-12)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import time
import warnings
import zipfile
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from tqdm.auto import tqdm

from ._deploy import by_robustness, deploy
from ._errors import InputError
from ._graph import count_edges, situated_matrix
from ._params import Hopper
from ._policies import (
    PairGrid,
    SituatedTable,
    candidate_pairs,
    candidate_situated,
    goal_policy_margin,
    goal_robustness,
    pair_goal,
    pair_may_intersect,
    situated_table,
    template_boxes,
)
from ._templates import Templates, paper_templates
from ._terrain import Terrain, segments

SAFETY_WE = 0.5
SAFETY_WG = 1.0
_PAIR_CHUNK = 4096
_FORMAT = 3
PROBE_HALF_WIDTH = 0.2
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
        stats: counts and timings (SPEC section 15 `plan` keys).
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


def _pair_batch(ti, si, tj, sj, boxes, table, templates, terrain, hopper, grid):
    return jax.vmap(pair_goal, (0, 0, 0, 0, 0, None, None, None, None, None))(
        ti, si, tj, sj, boxes, table, templates, terrain, hopper, grid)


_pair_batch_jit = jax.jit(_pair_batch, static_argnames=("grid",))


def _screen_batch(ti, si, tj, sj, boxes, table, templates, hopper, grid):
    return jax.vmap(pair_may_intersect, (0, 0, 0, 0, 0, None, None, None, None))(
        ti, si, tj, sj, boxes, table, templates, hopper, grid)


_screen_batch_jit = jax.jit(_screen_batch, static_argnames=("grid",))


def _situated_batch(goals, table, templates, terrain, hopper):
    return jax.vmap(candidate_situated, (0, None, None, None, None))(
        goals, table, templates, terrain, hopper)


_situated_batch_jit = jax.jit(_situated_batch)


def _goal_policies(goal, table, templates, terrain, hopper):
    n_seg = table.seg_block.shape[0]
    nt = templates.n
    s = jnp.arange(n_seg * nt)
    return jax.vmap(goal_policy_margin, (None, 0, 0, None, None, None, None))(
        goal, s % nt, s // nt, table, templates, terrain, hopper)


_goal_policies_jit = jax.jit(_goal_policies)


def _robustness(goals, table, templates, terrain, hopper, half_width):
    return jax.vmap(goal_robustness, (0, None, None, None, None, None))(
        goals, table, templates, terrain, hopper, half_width)


_robustness_jit = jax.jit(_robustness)


def _map_chunks(fn, n, size, batched, consts, bar=None):
    """`fn(*batched_chunk, *consts)` over `n` items in padded chunks of `size`, all devices.

    Every chunk has the same shape (the last is padded by repeating the last item), so one
    compilation serves the whole plan. Chunks go to the local devices round-robin and are
    dispatched before any result is read, so each device works on its share at once (on a
    CPU, one device uses about one core; see `_cli._use_all_cores`).

    Returns:
        The outputs concatenated over items, as NumPy arrays (a tuple if `fn` returns one).
    """
    devices = jax.local_devices()
    on_device = {}
    pending = []
    for i, start in enumerate(range(0, n, size)):
        dev = devices[i % len(devices)]
        if dev not in on_device:
            on_device[dev] = jax.device_put(consts, dev)
        idx = np.arange(start, start + size).clip(max=max(n - 1, 0))
        args = [jax.device_put(np.asarray(a)[idx], dev) for a in batched]
        pending.append((min(size, n - start), fn(*args, *on_device[dev])))
    parts = []
    for count, out in pending:
        parts.append(jax.tree.map(lambda x, c=count: np.asarray(x)[:c], out))
        if bar is not None:
            bar.update(count)
    if not parts:
        raise ValueError("_map_chunks: nothing to map")
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


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
    t_start = time.perf_counter()
    templates = paper_templates() if templates is None else templates
    hopper = Hopper() if hopper is None else hopper
    goal = _check_goal(terrain if goal is None else goal)
    segs = segments(terrain, templates.seg_length)
    table = situated_table(terrain, segs, templates.seg_length)
    nt, n_seg = templates.n, segs.n
    n_sit = nt * n_seg

    gf_rel, d_rel = (np.asarray(x) for x in template_boxes(templates, hopper))
    centre = np.asarray(segs.centre)
    t_of = np.arange(n_sit) % nt
    s_of = np.arange(n_sit) // nt
    offset = np.stack([centre[s_of, 0], centre[s_of, 1] + hopper.rho0, np.zeros(n_sit)], 1)
    gf_world = gf_rel[t_of] + offset[:, :, None]
    d_world = d_rel[t_of] + offset[:, :, None]
    rows, cols = candidate_pairs(gf_world, d_world)
    boxes = np.stack([np.maximum(gf_world[rows, 1:, 0], d_world[cols, 1:, 0]),
                      np.minimum(gf_world[rows, 1:, 1], d_world[cols, 1:, 1])], axis=2)

    stages = {}
    mark = t_start

    def lap(name):
        nonlocal mark
        now = time.perf_counter()
        stages[name] = round(now - mark, 3)
        mark = now

    lap("boxes")
    n_pairs = rows.size
    # Screen: drop pairs empty even before the collision clauses (most of them).
    pair_args = (t_of[rows], s_of[rows], t_of[cols], s_of[cols], boxes)
    keep = _map_chunks(partial(_screen_batch_jit, grid=grid), n_pairs, 4 * _PAIR_CHUNK,
                       pair_args, (table, templates, hopper)) if n_pairs else np.zeros(0, bool)
    rows, cols, boxes = rows[keep], cols[keep], boxes[keep]
    n_screened = rows.size
    lap("screen")
    bar = tqdm(total=n_screened, desc="instantiate", unit="pair", disable=not progress,
               file=sys.stderr, leave=False)
    if n_screened:
        found, goals, margin, margin_d = _map_chunks(
            partial(_pair_batch_jit, grid=grid), n_screened, _PAIR_CHUNK,
            (t_of[rows], s_of[rows], t_of[cols], s_of[cols], boxes),
            (table, templates, terrain, hopper), bar)
    else:
        found, goals = np.zeros(0, bool), np.zeros((0, 3))
        margin, margin_d = np.zeros(0), np.zeros(0)
    bar.close()
    lap("instantiate")

    g_ok, g_margin = (np.asarray(x) for x in _goal_policies_jit(
        jnp.asarray(goal), table, templates, terrain, hopper))
    goal_sit = np.nonzero(g_ok)[0]

    de = np.asarray(segs.edge_distance)
    sit = np.concatenate([goal_sit, rows[found]])
    tgt = np.concatenate([np.full(goal_sit.size, -1), cols[found]])
    all_goals = np.concatenate([np.broadcast_to(goal, (goal_sit.size, 3)), goals[found]])
    all_margin = np.concatenate([g_margin[goal_sit], margin[found]])
    dg = np.concatenate([g_margin[goal_sit], margin_d[found]])
    safety = SAFETY_WE * de[s_of[sit]] ** 3 + SAFETY_WG * dg
    is_goal = np.arange(sit.size) < goal_sit.size

    chunk = 8192
    if sit.size:
        ids, inside = _map_chunks(_situated_batch_jit, sit.size, chunk, (all_goals,),
                                  (table, templates, terrain, hopper))
    else:  # the goal is out of every policy's reach: an empty plan
        ids, inside = np.zeros((0, 3 * nt), np.int64), np.zeros((0, 3 * nt), bool)
    p = situated_matrix(inside, ids, n_sit)
    lap("prepares")
    # Each goal must lie in the domain it was chosen for; drop any that do not (none should).
    keep = is_goal | np.asarray(p[np.arange(sit.size), np.maximum(tgt, 0)]).ravel()
    n_dropped = int((~keep).sum())
    if n_dropped:
        warnings.warn(f"{n_dropped} instantiated goals failed the exact domain test; dropped",
                      stacklevel=2)
        sel = np.nonzero(keep)[0]
        sit, tgt, all_goals, all_margin = sit[sel], tgt[sel], all_goals[sel], all_margin[sel]
        safety, is_goal, p = safety[sel], is_goal[sel], p[sel]

    robustness = np.ones(sit.size)
    if sit.size:
        robustness = np.asarray(_map_chunks(
            _robustness_jit, sit.size, chunk, (all_goals,),
            (table, templates, terrain, hopper, jnp.full(3, float(probe)))), float)
    robustness[is_goal] = 1.0
    lap("safety_sampling")
    order = deploy(p, sit, safety, is_goal, robustness, pickbest)
    lap("deploy")
    stats = {
        "n_segments": int(n_seg),
        "n_situated": int(n_sit),
        "n_candidate_pairs": int(n_pairs),
        "n_screened_pairs": int(n_screened),
        "n_instantiated": int(sit.size),
        "n_goal_policies": int(is_goal.sum()),
        "n_deployed": int(order.size),
        "n_edges": count_edges(p, sit),
        "n_dropped": n_dropped,
        "seconds": round(time.perf_counter() - t_start, 3),
        "stage_seconds": stages,
    }
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


# --- cache (SPEC section 16) -------------------------------------------------------------


def plan_key(terrain: Terrain, goal, templates: Templates, hopper: Hopper,
             grid: PairGrid = _DEFAULT_GRID) -> str:
    from . import __version__

    payload = {
        "version": __version__,
        "format": _FORMAT,
        "blocks": terrain.blocks(),
        "goal": [float(g) for g in goal],
        "templates": templates.to_dict(),
        "hopper": [float(hopper.m), float(hopper.g), float(hopper.rho0)],
        "grid": [grid.n_v, grid.n_z],
        "probe": PROBE_HALF_WIDTH,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def cache_dir() -> str:
    return os.environ.get("JAXHOP_CACHE", os.path.join(os.path.expanduser("~"), ".cache",
                                                       "jaxhop"))


def save_plan(plan: Plan, path: str, key: str) -> None:
    p = plan.prepares.tocsr()
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        np.savez_compressed(
            f, key=np.asarray(key), situated=plan.situated, target=plan.target,
            goals=plan.goals, safety=plan.safety, margin=plan.margin, is_goal=plan.is_goal,
            robustness=plan.robustness,
            p_indptr=p.indptr, p_indices=p.indices, p_shape=np.asarray(p.shape),
            order=plan.order, stats=np.asarray(json.dumps(plan.stats)))
    os.replace(tmp, path)


def load_plan(path: str, key: str, terrain: Terrain, goal, templates: Templates,
              hopper: Hopper) -> Plan:
    """Load a cached plan; raises `ValueError` if it is corrupt or was built for other inputs."""
    try:
        with np.load(path) as z:
            if str(z["key"]) != key:
                raise ValueError("stale cache (key mismatch)")
            n = int(z["situated"].shape[0])
            shape = tuple(int(s) for s in z["p_shape"])
            p = sp.csr_matrix((np.ones(z["p_indices"].size, bool), z["p_indices"],
                               z["p_indptr"]), shape=shape)
            plan = Plan(terrain, templates, hopper, np.asarray(goal, float), z["situated"],
                        z["target"], z["goals"], z["safety"], z["margin"], z["is_goal"],
                        z["robustness"], p,
                        z["order"], json.loads(str(z["stats"])))
    except (OSError, KeyError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as err:
        raise ValueError(f"corrupt cache ({err})") from None
    if plan.goals.shape != (n, 3) or shape[0] != n or plan.order.max(initial=-1) >= n:
        raise ValueError("corrupt cache (inconsistent shapes)")
    return plan


def get_plan(terrain: Terrain, goal=None, templates: Templates | None = None,
             hopper: Hopper | None = None, *, cache: bool = True, progress: bool = True,
             log=None) -> Plan:
    """The plan for these inputs: from the cache when a valid one exists, else built and saved.

    A corrupt or stale cache file is reported (one line through `log`, default a warning)
    and rebuilt, never trusted.
    """
    templates = paper_templates() if templates is None else templates
    hopper = Hopper() if hopper is None else hopper
    goal = _check_goal(terrain if goal is None else goal)
    if not cache:
        return build_plan(terrain, goal, templates, hopper, progress=progress)
    key = plan_key(terrain, goal, templates, hopper)
    path = os.path.join(cache_dir(), f"plan-{key[:24]}.npz")
    if os.path.exists(path):
        try:
            t0 = time.perf_counter()
            plan = load_plan(path, key, terrain, goal, templates, hopper)
            plan.stats["loaded_seconds"] = round(time.perf_counter() - t0, 3)
            plan.stats["from_cache"] = True
            return plan
        except ValueError as err:
            msg = f"plan cache {path}: {err}; rebuilding"
            (log or (lambda m: warnings.warn(m, stacklevel=2)))(msg)
    plan = build_plan(terrain, goal, templates, hopper, progress=progress)
    plan.stats["from_cache"] = False
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        save_plan(plan, path, key)
    except OSError as err:
        (log or (lambda m: warnings.warn(m, stacklevel=2)))(f"cannot write plan cache: {err}")
    return plan
