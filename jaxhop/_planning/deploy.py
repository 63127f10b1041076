"""Deployment by backchaining (Fig. 7): a total order over instantiated policies."""

from __future__ import annotations

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
        pickbest: maps `(safety, depth, robustness)` to a priority key, smallest first
            (ties: the smaller policy index first). `depth` is the number of strides to
            the goal along the backchain.

    Returns:
        The deployed policies, in order: the order of that queue, computed in bulk
        (`docs/planning.md`, "Deployment in bulk").
    """
    preparers = p.tocsc()
    indptr, indices = preparers.indptr, preparers.indices
    n, n_sit = situated.shape[0], p.shape[1]
    robustness = np.ones(n) if robustness is None else robustness
    situated = np.asarray(situated, np.int64)
    depth = np.zeros(n, np.int64)
    joined = np.full(n, -1, np.int64)  # expansions before the policy joined the queue
    key = np.zeros(n)
    goals = np.nonzero(is_goal)[0]
    depth[goals] = 1
    joined[goals] = 0
    key[goals] = np.asarray(pickbest(safety, np.where(is_goal, 1, 0), robustness), float)[goals]
    front = _Front(n, n_sit)
    front.offer(key[goals], goals, situated[goals])
    expanding = []  # the policies that expand their situated policy, in order
    n_expanded, width = 0, _FIRST_WIDTH
    while True:
        # The next `width` expansions, were nothing that joins on the way to jump ahead.
        t_s, t_k, t_i = front.smallest(width)
        if t_s.size == 0:
            break
        w = t_s.size
        child, owner = _preparers(indptr, indices, t_s)
        fresh = joined[child] < 0
        child, owner = front.first_owner(child[fresh], owner[fresh])
        d = depth[t_i][owner] + 1
        kc = np.asarray(pickbest(safety[child], d, robustness[child]), float)
        sc = situated[child]
        # A policy that joins after expansion `o` may jump ahead of expansion `j > o` if
        # its situated policy is unexpanded and its key is not larger: the expansions stop
        # before the first such `j` (on a tie, or where expansions before `j` expand that
        # policy's situated policy, they stop early, which only costs a round).
        open_ = ~front.expanded[sc]
        cut = w
        if open_.any():
            ahead = np.searchsorted(t_k, kc[open_], "left")
            cut = int(min(np.maximum(ahead, owner[open_] + 1).min(), w))
        m = owner < cut
        child, kc, sc = child[m], kc[m], sc[m]
        joined[child] = n_expanded + owner[m] + 1
        depth[child] = d[m]
        key[child] = kc
        front.expand(t_s[:cut])
        expanding.append(t_i[:cut])
        n_expanded += cut
        live = ~front.expanded[sc]
        front.offer(kc[live], child[live], sc[live])
        width = min(2 * width, _MAX_WIDTH) if cut == w else max(_FIRST_WIDTH, 2 * cut)
    return _merge(np.concatenate(expanding) if expanding else np.zeros(0, np.int64),
                  joined, key)


#: Expansions tried at once: the first, the most (doubled while none is cut short).
_FIRST_WIDTH, _MAX_WIDTH = 16, 4096
_NONE = np.iinfo(np.int64).max


class _Front:
    """Per situated policy not yet expanded, the smallest `(key, index)` of its queued
    policies: the one that will expand it (any other is popped after it, with nothing left
    to expand)."""

    def __init__(self, n: int, n_sit: int):
        self.expanded = np.zeros(n_sit, bool)
        self.key = np.full(n_sit, np.inf)
        self.index = np.full(n_sit, _NONE, np.int64)
        self._claim = np.full(n, _NONE, np.int64)

    def offer(self, keys, idx, sit):
        old = self.key[sit]
        np.minimum.at(self.key, sit, keys)
        now = self.key[sit]
        self.index[sit[now < old]] = _NONE
        tie = keys == now
        np.minimum.at(self.index, sit[tie], idx[tie])

    def smallest(self, width: int):
        """The `width` smallest fronts, sorted: situated policies, keys, indices."""
        pool = np.nonzero(self.index < _NONE)[0]
        k, i = self.key[pool], self.index[pool]
        if pool.size > width:
            pick = np.argpartition(k, width - 1)[:width]
            pick = np.nonzero(k <= k[pick].max())[0]  # every key tied at the edge
        else:
            pick = np.arange(pool.size)
        pick = pick[np.lexsort((i[pick], k[pick]))][:width]
        return pool[pick], k[pick], i[pick]

    def expand(self, sit):
        self.expanded[sit] = True
        self.key[sit], self.index[sit] = np.inf, _NONE

    def first_owner(self, child, owner):
        """Each child once, with the first expansion that reaches it."""
        np.minimum.at(self._claim, child, owner)
        first = self._claim[child] == owner
        self._claim[child] = _NONE
        return child[first], owner[first]


def _preparers(indptr, indices, cols):
    """The rows of the CSC columns `cols`, and the position in `cols` of each."""
    starts = indptr[cols]
    lens = indptr[cols + 1] - starts
    owner = np.repeat(np.arange(cols.size), lens)
    offset = np.arange(owner.size) - np.repeat(np.cumsum(lens) - lens, lens)
    return indices[starts[owner] + offset], owner


def _merge(expanding, joined, key):
    """The queue's whole order from its expansions.

    A policy that joined the queue after expansion `t` leaves it just before the first
    later expansion whose `(key, index)` is larger than its own (or at the end), and the
    policies that leave between two expansions leave in `(key, index)` order.
    """
    queued = np.nonzero(joined >= 0)[0]
    by_key = queued[np.argsort(key[queued], kind="stable")]
    rank = np.empty(joined.size, np.int64)
    rank[by_key] = np.arange(by_key.size)
    m = expanding.size
    bound = np.concatenate([[-1], rank[expanding], [by_key.size]])
    r, t = rank[by_key], joined[by_key] + 1
    # Where the running maximum of the expansions' ranks first exceeds a rank after the
    # policy joined, that expansion is the answer; the rest search a table of maxima.
    before = np.maximum(np.searchsorted(np.maximum.accumulate(bound), r, "right"), t)
    hard = np.nonzero(before == t)[0]
    hard = hard[bound[t[hard]] <= r[hard]]
    if hard.size:
        levels = [bound]  # levels[k][j] = max(bound[j : j + 2**k])
        while (1 << len(levels)) <= bound.size:
            prev, h = levels[-1], 1 << (len(levels) - 1)
            nxt = prev.copy()
            nxt[:-h] = np.maximum(prev[:-h], prev[h:])
            levels.append(nxt)
        pos, rh = t[hard], r[hard]
        for k in range(len(levels) - 1, -1, -1):
            ok = pos + (1 << k) <= m + 1
            ok &= levels[k][np.minimum(pos, m + 1)] <= rh
            pos = np.where(ok, pos + (1 << k), pos)
        before[hard] = pos
    before[rank[expanding]] = np.arange(1, m + 1)
    if m + 1 < 1 << 16:
        before = before.astype(np.uint16)  # a radix sort
    return by_key[np.argsort(before, kind="stable")]


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
