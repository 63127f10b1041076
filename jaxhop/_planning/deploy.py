"""Deployment by backchaining (Fig. 7): a total order over instantiated policies."""

from __future__ import annotations

import heapq
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp


def by_safety(safety: np.ndarray, depth: np.ndarray, robustness: np.ndarray) -> np.ndarray:
    """The paper's `pickbest` (section VI-B): highest safety (eq 34) first."""
    return -safety


def by_depth(safety: np.ndarray, depth: np.ndarray, robustness: np.ndarray) -> np.ndarray:
    """Fewest strides to the goal first, then highest safety."""
    return depth * 1e6 - safety


def by_robustness(safety: np.ndarray, depth: np.ndarray, robustness: np.ndarray) -> np.ndarray:
    """Default `pickbest`: most robust goal first, then fewest strides, then highest safety.

    `robustness` is the safety-sampling score of the goal (`goal_robustness`): the fraction
    of a box of perturbed goals that lies in some situated domain.
    """
    return -robustness * 1e12 + depth * 1e6 - safety


PICKBEST = {"robust": by_robustness, "depth": by_depth, "safety": by_safety}


def deploy(
    p: sp.csr_matrix,
    situated: np.ndarray,
    safety: np.ndarray,
    is_goal: np.ndarray,
    robustness: np.ndarray | None = None,
    pickbest: Callable[..., np.ndarray] = by_robustness,
) -> np.ndarray:
    """Order instantiated policies by backchaining from the goal policies.

    A priority queue starts with the goal policies; the best policy is moved to the order,
    and every unused policy that prepares it (its goal lies in the domain of the moved
    policy's situated policy) joins the queue.

    Arguments:
        p: `P[a, s] = [Zg(a) ∈ D(s)]` (see `graph.py`).
        situated: `(n,)` situated policy of each instantiated policy.
        safety: `(n,)` safety of each (eq 34).
        is_goal: `(n,)` which are goal policies.
        robustness: `(n,)` safety-sampling score of each goal (default: all 1).
        pickbest: maps `(safety, depth, robustness)` to a priority key, smallest first.
            `depth` is the number of strides to the goal along the backchain.

    Returns:
        The deployed policies, in order.

    The queue holds plain float keys, each once, and per key a heap of the policies that
    have it: popping the smallest key's smallest policy is popping the smallest `(key,
    policy)` pair, without comparing tuples (a parkour update redeploys 150 000 policies).
    """
    preparers = p.tocsc()
    indptr, indices = preparers.indptr, preparers.indices
    n = situated.shape[0]
    robustness = np.ones(n) if robustness is None else robustness
    depth = np.full(n, np.iinfo(np.int64).max, dtype=np.int64)
    queued = np.zeros(n, dtype=bool)
    expanded = bytearray(p.shape[1])
    sit = situated.tolist()
    keys_heap: list[float] = []
    ties: dict[float, list[int]] = {}

    def push(keys, idx):
        for key, a in zip(keys.tolist(), idx.tolist()):
            bucket = ties.get(key)
            if bucket is None:
                ties[key] = [a]
                heapq.heappush(keys_heap, key)
            else:
                heapq.heappush(bucket, a)

    goals = np.nonzero(is_goal)[0]
    depth[goals] = 1
    keys = pickbest(safety, np.where(is_goal, 1, 0), robustness)
    push(np.asarray(keys, float)[goals], goals)
    queued[goals] = True
    order = []
    while keys_heap:
        key = keys_heap[0]
        bucket = ties[key]
        b = heapq.heappop(bucket)
        if not bucket:
            heapq.heappop(keys_heap)
            del ties[key]
        order.append(b)
        s = sit[b]
        if expanded[s]:
            continue
        expanded[s] = 1
        col = indices[indptr[s]:indptr[s + 1]]
        new = col[~queued[col]]
        if new.size == 0:
            continue
        queued[new] = True
        depth[new] = depth[b] + 1
        push(np.asarray(pickbest(safety[new], depth[new], robustness[new]), float), new)
    return np.asarray(order, dtype=np.int64)


def check_order(order: np.ndarray, p: sp.csr_matrix, situated: np.ndarray,
                is_goal: np.ndarray) -> bool:
    """The deployment invariant: every non-goal policy prepares some earlier policy."""
    seen = np.zeros(p.shape[1], dtype=bool)
    p = p.tocsr()
    for a in order:
        if not is_goal[a]:
            targets = p.indices[p.indptr[a]:p.indptr[a + 1]]
            if not np.any(seen[targets]):
                return False
        seen[situated[a]] = True
    return True
