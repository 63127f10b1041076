"""The prepares relation (Definition 2, eq 32) in sparse form.

Instantiated `a` prepares instantiated `b` iff `Zg(a) ∈ D(situated(b))`. Because the test only
involves `situated(b)`, the relation factors through situated policies:
`prepares = P @ M`, with `P[a, s] = [Zg(a) ∈ D(s)]` (n_instantiated x n_situated) and
`M[s, b] = [situated(b) = s]`. We store `P` (CSR); `M` is the `situated` column of the plan.
The full graph can be materialised on demand (`prepares_matrix`).
"""

import numpy as np
import scipy.sparse as sp


def situated_matrix(goal_in: np.ndarray, ids: np.ndarray, n_situated: int) -> sp.csr_matrix:
    """`P` from per-policy candidate ids and their membership mask."""
    rows = np.repeat(np.arange(ids.shape[0]), ids.shape[1])
    keep = goal_in.reshape(-1)
    data = np.ones(int(keep.sum()), dtype=bool)
    p = sp.csr_matrix((data, (rows[keep], ids.reshape(-1)[keep])),
                      shape=(ids.shape[0], n_situated))
    p.sum_duplicates()
    return p


def membership_matrix(situated: np.ndarray, n_situated: int) -> sp.csr_matrix:
    n = situated.shape[0]
    return sp.csr_matrix((np.ones(n, dtype=bool), (situated, np.arange(n))),
                         shape=(n_situated, n))


def count_edges(p: sp.csr_matrix, situated: np.ndarray) -> int:
    """Number of edges of the full prepares graph without building it."""
    per_situated = np.bincount(situated, minlength=p.shape[1])
    return int(np.asarray(p.astype(np.int64) @ per_situated).sum())


def prepares_matrix(p: sp.csr_matrix, situated: np.ndarray) -> sp.csr_matrix:
    """The full prepares graph as CSR: row `a`, column `b` iff `a` prepares `b`."""
    return (p.astype(np.int32) @ membership_matrix(situated, p.shape[1]).astype(np.int32)) \
        .astype(bool).tocsr()
