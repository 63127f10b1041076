"""Figures of a plan: template regions (Fig. 9), goal coverage and the prepares relation."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from ._plan import Plan
from ._plot import draw_terrain


def template_regions_figure(templates, hopper, n: int = 121):
    """Domain and feasible-goal regions of every template in `(ydot, zr)` (Fig. 9).

    Left: `D(Φ)` (eqs 38-41); right: `Gf(Φ)` by the exact closed form. One colour per
    template; the y extent (not shown) is a band of width `2l` (domain) or
    `dy_hi - dy_lo - 2l` (goal) around the touchdown / liftoff line.
    """
    import jax
    import jax.numpy as jnp

    from ._regions import domain_height_bounds, goal_height_bounds

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    cmap = plt.get_cmap("tab20")
    v = jnp.linspace(-5.0, 5.0, n)
    for t in range(templates.n):
        tmpl = templates.row(t)
        for ax, fn in zip(axes, (domain_height_bounds, goal_height_bounds)):
            lo, hi = (np.asarray(x) for x in jax.vmap(fn, (0, None, None))(v, tmpl, hopper))
            ok = hi > lo
            if ok.any():
                ax.fill_between(np.asarray(v), np.where(ok, lo, np.nan), np.where(ok, hi, np.nan),
                                color=cmap(t % 20), alpha=0.55, lw=0)
    for ax, title in zip(axes, ("domains D(Φ)", "feasible goals Gf(Φ)")):
        ax.set_xlabel("apex velocity ydot (m/s)")
        ax.set_title(f"{templates.n} templates: {title}")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("apex height above virtual ground zr (m)")
    fig.tight_layout()
    return fig


def goal_coverage_figure(plan: Plan, ydot: float = 0.5, tol: float = 0.25):
    """Instantiated goals over the terrain (Fig. 11): goals with `|ydot - ydot0| < tol`."""
    fig, ax = plt.subplots(figsize=(11, 3.8))
    draw_terrain(ax, plan.terrain)
    g = plan.goals
    sel = np.abs(g[:, 2] - ydot) < tol
    sc = ax.scatter(g[sel, 0], g[sel, 1], c=plan.robustness[sel], s=3, cmap="viridis", lw=0,
                    vmin=0, vmax=1, zorder=3)
    fig.colorbar(sc, ax=ax, label="safety-sampling score", fraction=0.03, pad=0.01)
    ax.plot(plan.goal[0], plan.goal[1], "ko", ms=7, label="global goal", zorder=4)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"Goals of instantiated policies with |ydot - {ydot}| < {tol} m/s "
                 f"({int(sel.sum())} of {len(g)})")
    fig.tight_layout()
    return fig


def prepares_figure(plan: Plan, max_points: int = 400_000):
    """The prepares relation as a sparse pattern (Fig. 12), policies ordered along `y`.

    Rows: instantiated policies; columns: situated policies whose domain holds the row's
    goal (`P`; the full graph is `P` times the situated → instantiated membership).
    """
    p = plan.prepares.tocoo()
    table = plan.table()
    y_sit = np.repeat(np.asarray(table.centre)[:, 0], plan.templates.n)
    order_rows = np.argsort(y_sit[plan.situated], kind="stable")
    rank_row = np.empty_like(order_rows)
    rank_row[order_rows] = np.arange(order_rows.size)
    order_cols = np.argsort(y_sit, kind="stable")
    rank_col = np.empty_like(order_cols)
    rank_col[order_cols] = np.arange(order_cols.size)
    rows, cols = rank_row[p.row], rank_col[p.col]
    if rows.size > max_points:
        keep = np.random.default_rng(0).choice(rows.size, max_points, replace=False)
        rows, cols = rows[keep], cols[keep]
    fig, ax = plt.subplots(figsize=(6.5, 6))
    ax.plot(cols, rows, ",", color="tab:blue", alpha=0.6)
    ax.set_xlim(0, plan.n_situated)
    ax.set_ylim(plan.situated.size, 0)
    ax.set_xlabel("prepared situated policy (ordered along y)")
    ax.set_ylabel("instantiated policy (ordered along y)")
    ax.set_title(f"Prepares relation: {p.nnz} entries of P, {plan.stats['n_edges']} edges")
    fig.tight_layout()
    return fig
