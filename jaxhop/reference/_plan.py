"""The whole plan, as the paper's algorithm runs it: situate, instantiate every pair, build
the prepares matrix, sample safety, deploy by backchaining (Figs. 7, 10-12)."""

from __future__ import annotations

import dataclasses
import heapq
import time

import numpy as np
import scipy.sparse as sp

from ._model import Hopper, Templates, Terrain, paper_templates, segments
from ._policies import (
    Situation,
    candidate_pairs,
    goal_policy_margin,
    pair_box,
    pair_goals,
    situate_goals,
    world_boxes,
)
from ._regions import template_boxes

SAFETY_WE = 0.5
SAFETY_WG = 1.0
PROBE_HALF_WIDTH = 0.2


@dataclasses.dataclass
class Plan:
    """A deployed plan; the fields mean what they mean in `jaxhop.Plan`."""

    situation: Situation
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
    timings: dict

    @property
    def terrain(self) -> Terrain:
        return self.situation.terrain

    @property
    def hopper(self) -> Hopper:
        return self.situation.hopper


def situate(terrain: Terrain, templates: Templates | None = None,
            hopper: Hopper | None = None) -> Situation:
    """Every template on every segment (eq 8)."""
    templates = paper_templates() if templates is None else templates
    hopper = Hopper() if hopper is None else hopper
    return Situation(terrain, segments(terrain, templates.seg_length), templates, hopper)


def instantiate(sit: Situation, rows, cols, gf_world, d_world, n_v=16, n_z=16):
    """Goal of every candidate pair (`pair_goals`: each pair's grid, as `pair_goal` takes
    it alone, computed for many pairs at once).

    Returns:
        `(found, goals, margin, margin_d)` per pair.
    """
    return pair_goals(sit, rows, cols, pair_box(gf_world, d_world, rows, cols), (n_v, n_z))


def goal_policies(sit: Situation, goal):
    """Situated policies that reach the global goal, and the goal's margin in each."""
    nt = sit.templates.n
    ok = np.zeros(sit.n_situated, bool)
    margin = np.full(sit.n_situated, -np.inf)
    for s in range(sit.n_situated):
        ok[s], margin[s] = goal_policy_margin(sit, goal, s % nt, s // nt)
    return ok, margin


def prepares_and_robustness(sit: Situation, goals, half_width=PROBE_HALF_WIDTH, batch=4096):
    """`P[a, s] = [Zg(a) in D(s)]` (CSR) and the safety-sampling score of every goal,
    `batch` goals at a time."""
    n = goals.shape[0]
    rows, cols = [], []
    robustness = np.zeros(n)
    for start in range(0, n, batch):
        ids, inside, robustness[start:start + batch] = situate_goals(
            sit, goals[start:start + batch], half_width)
        r, c = np.nonzero(inside)
        rows.append(r + start)
        cols.append(ids[r, c])
    rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    cols = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    # One entry per (goal, situated policy), columns sorted within each row.
    key = np.unique(rows.astype(np.int64) * sit.n_situated + cols)
    indices = key % sit.n_situated
    indptr = np.concatenate([[0], np.cumsum(np.bincount(key // sit.n_situated, minlength=n))])
    p = sp.csr_matrix((np.ones(indices.size, bool), indices, indptr),
                      shape=(n, sit.n_situated))
    return p, robustness


def robust_key(safety, depth, robustness):
    """Default `pickbest`: most robust goal, then fewest strides, then highest safety."""
    return -robustness * 1e12 + depth * 1e6 - safety


def safety_key(safety, depth, robustness):
    """The paper's `pickbest`: highest safety (eq 34)."""
    return -safety


def depth_key(safety, depth, robustness):
    """Fewest strides to the goal, then highest safety."""
    return depth * 1e6 - safety


def deploy(p: sp.csr_matrix, situated, safety, is_goal, robustness, key=robust_key):
    """Backchaining (Fig. 7): a priority queue seeded with the goal policies; the best one
    joins the order and every policy that prepares it is queued once.

    Policies of one situated policy share a domain, so a situated policy's preparers are
    queued when the first of its instantiated policies is deployed.
    """
    n = situated.size
    preparers = p.tocsc()
    queued = np.zeros(n, bool)
    expanded = set()
    depth = np.zeros(n, np.int64)
    heap = []
    for a in np.nonzero(is_goal)[0]:
        depth[a] = 1
        heap.append((float(key(safety[a], 1, robustness[a])), int(a)))
        queued[a] = True
    heapq.heapify(heap)
    order = []
    while heap:
        _, b = heapq.heappop(heap)
        order.append(b)
        s = int(situated[b])
        if s in expanded:
            continue
        expanded.add(s)
        col = preparers.indices[preparers.indptr[s]:preparers.indptr[s + 1]]
        for a in col[~queued[col]]:
            queued[a] = True
            depth[a] = depth[b] + 1
            heapq.heappush(heap, (float(key(safety[a], depth[a], robustness[a])), int(a)))
    return np.asarray(order, np.int64)


def build_plan(terrain: Terrain, goal=None, templates: Templates | None = None,
               hopper: Hopper | None = None, *, key=robust_key,
               probe: float = PROBE_HALF_WIDTH, n_v: int = 16, n_z: int = 16) -> Plan:
    """The reactive plan, step for step as `jaxhop.build_plan` computes it.

    Returns:
        A `Plan` whose `timings` split the seconds spent per stage.
    """
    clock = [time.perf_counter()]
    timings = {}

    def lap(name):
        now = time.perf_counter()
        timings[name] = now - clock[0]
        clock[0] = now

    goal = np.asarray(terrain.goal if goal is None else goal, float)
    sit = situate(terrain, templates, hopper)
    gf_world, d_world = world_boxes(sit, *template_boxes(sit.regions))
    rows, cols = candidate_pairs(gf_world, d_world)
    lap("situate")
    found, goals, margin, margin_d = instantiate(sit, rows, cols, gf_world, d_world, n_v, n_z)
    lap("instantiate")
    g_ok, g_margin = goal_policies(sit, goal)
    goal_sit = np.nonzero(g_ok)[0]
    lap("goal_policies")

    nt = sit.templates.n
    sit_of = np.concatenate([goal_sit, rows[found]])
    target = np.concatenate([np.full(goal_sit.size, -1), cols[found]])
    all_goals = np.concatenate([np.broadcast_to(goal, (goal_sit.size, 3)), goals[found]])
    all_margin = np.concatenate([g_margin[goal_sit], margin[found]])
    dg = np.concatenate([g_margin[goal_sit], margin_d[found]])
    safety = SAFETY_WE * sit.segs.edge_distance[sit_of // nt] ** 3 + SAFETY_WG * dg
    is_goal = np.arange(sit_of.size) < goal_sit.size

    p, robustness = prepares_and_robustness(sit, all_goals, probe)
    # A goal must lie in the domain it was chosen for (the exact, simulated test).
    keep = is_goal | np.asarray(p[np.arange(sit_of.size), np.maximum(target, 0)]).ravel()
    n_dropped = int((~keep).sum())
    if n_dropped:
        sel = np.nonzero(keep)[0]
        sit_of, target, all_goals, all_margin = sit_of[sel], target[sel], all_goals[sel], \
            all_margin[sel]
        safety, is_goal, p, robustness = safety[sel], is_goal[sel], p[sel], robustness[sel]
    robustness[is_goal] = 1.0
    lap("graph_and_safety_sampling")
    order = deploy(p, sit_of, safety, is_goal, robustness, key)
    lap("deploy")
    per_situated = np.bincount(sit_of, minlength=sit.n_situated)
    stats = {
        "n_segments": sit.segs.n,
        "n_situated": sit.n_situated,
        "n_candidate_pairs": int(rows.size),
        "n_instantiated": int(sit_of.size),
        "n_goal_policies": int(is_goal.sum()),
        "n_deployed": int(order.size),
        "n_edges": int(np.asarray(p.astype(np.int64) @ per_situated).sum()),
        "n_dropped": n_dropped,
        "seconds": round(sum(timings.values()), 3),
    }
    return Plan(sit, goal, sit_of, target, all_goals, safety, all_margin, is_goal, robustness,
                p.tocsr(), order, stats, timings)
