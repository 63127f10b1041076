"""Figures: pure functions that take results and return a matplotlib Figure."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402

from .._control.decisions import model_for  # noqa: E402
from .._core.result import RESULT_NAMES, result_name  # noqa: E402
from .._core.terrain import Terrain  # noqa: E402
from .._planning.plan import Plan  # noqa: E402
from .draw import (  # noqa: E402
    RunStyle,
    draw_cross_sections,
    draw_run,
    draw_terrain,
    policy_cross_sections,
)


def global_domain_figure(terrain: Terrain, states: np.ndarray, inside: np.ndarray,
                         goal=None, ydot0: float = 0.5):
    """Global domain (union of deployed policies' domains) at `ydot = ydot0` (Fig. 10)."""
    fig, ax = plt.subplots(figsize=(11, 3.6))
    draw_terrain(ax, terrain)
    ax.scatter(states[inside, 0], states[inside, 1], s=4, c="tab:red", marker="s", lw=0,
               label=f"apex states in the global domain (ydot = {ydot0} m/s)", zorder=3)
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=7, label="global goal", zorder=4)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"Global domain on '{terrain.name}': {int(inside.sum())} of {len(states)} "
                 "grid states")
    fig.tight_layout()
    return fig


def _headroom(ax, terrain: Terrain, runs, extra: float = 0.9):
    """Leave room above the highest apex for the legend."""
    tops = [np.nanmax(np.asarray(r["apexes"])[:, 1]) for r in runs
            if np.isfinite(np.asarray(r["apexes"])[:, 1]).any()]
    top = max(tops, default=float(np.max(terrain.heights)) + 1.5)
    ax.set_ylim(float(np.min(terrain.heights)) - 0.65, top + extra)


def _run_label(i, run, prefix="run"):
    return (f"{prefix} {i + 1}: {RESULT_NAMES[int(run['code'])]} in {int(run['steps'])} "
            "strides")


def runs_figure(terrain: Terrain, runs: list[dict], goal=None, title="Example runs",
                perceived: Terrain | None = None, plan: Plan | None = None,
                style: RunStyle | None = None):
    """Example runs over the terrain (Figs. 13, 19): COM path, apexes, footholds.

    Each run is a dict with `apexes`, `footholds`, `code`, `steps` (and `policies` when
    `plan` is given). With `plan`, the cross-sections of the domain (dark red) and feasible
    goal (light green) of the policy used at each apex are shaded (`policy_cross_sections`).
    `style` (`RunStyle`): the model, hopper and wind the paths are rebuilt with (default:
    BHop, the reference hopper, no wind).
    """
    style = RunStyle() if style is None else style
    model = style.model
    fig, ax = plt.subplots(figsize=(11, 3.8))
    draw_terrain(ax, terrain, perceived)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    legs = not model_for(model).instant_stance
    for i, run in enumerate(runs):
        if plan is not None:
            sections = policy_cross_sections(plan, run["policies"][: int(run["steps"])],
                                             run["apexes"])
            draw_cross_sections(ax, sections, label=i == 0)
        draw_run(ax, run["apexes"], run["footholds"], style.rho0, style.g,
                 colors[i % len(colors)], _run_label(i, run), model=model, wind=style.wind,
                 legs=legs)
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=7, label="global goal", zorder=7)
    _headroom(ax, terrain, runs, 1.0 if plan is None else 1.3)
    ax.legend(loc="upper left", fontsize=8, ncol=2 if plan is not None else 1)
    ax.set_title(title + "  (x: start, dots: apexes, triangles: footholds)")
    fig.tight_layout()
    return fig


def slip_runs_figure(plan: Plan, runs: list[dict], title: str | None = None):
    """SLIP runs driven by a BHop plan, with region cross-sections at each apex (Fig. 19)."""
    title = title or f"SLIP runs on '{plan.terrain.name}' with the BHop plan"
    return runs_figure(plan.terrain, runs, plan.goal, title, plan=plan,
                       style=RunStyle("slip", plan.hopper))


def long_run_figure(plan: Plan, run: dict, model: str = "slip", title: str | None = None,
                    true_terrain: Terrain | None = None):
    """One run across a long terrain (Fig. 21): path, legs, footholds and policy goals.

    The initial apex is an `x`, the final apex a filled dot. The goal of the policy chosen at
    each apex is an open circle joined to the apex actually reached (the SLIP deadbeat
    cannot realise the BHop goals exactly; the reactive controller absorbs the difference).
    """
    terrain = plan.terrain if true_terrain is None else true_terrain
    name = model_for(model).name.upper()
    steps = int(run["steps"])
    apexes = np.asarray(run["apexes"])[: steps + 1]
    apexes = apexes[np.all(np.isfinite(apexes), axis=1)]
    pol = np.asarray(run["policies"])[:steps]
    goals = np.asarray(plan.goals)[pol[pol >= 0]]
    fig, ax = plt.subplots(figsize=(13, 4.2))
    draw_terrain(ax, terrain)
    draw_run(ax, run["apexes"], run["footholds"], float(plan.hopper.rho0),
             float(plan.hopper.g), "tab:blue",
             f"{name} COM path: {RESULT_NAMES[int(run['code'])]} in {steps} strides",
             model=model, legs=True)
    ax.plot(goals[:, 0], goals[:, 1], "o", mfc="none", mec="tab:green", ms=6, zorder=7,
            label="goal of the policy chosen at each apex")
    for k in range(min(len(goals), len(apexes) - 1)):
        ax.plot([goals[k, 0], apexes[k + 1, 0]], [goals[k, 1], apexes[k + 1, 1]],
                color="tab:green", lw=0.8, zorder=7)
    ax.plot(apexes[-1, 0], apexes[-1, 1], "o", color="tab:blue", ms=7, zorder=8,
            label="final apex")
    ax.plot(plan.goal[0], plan.goal[1], "ks", ms=6, mfc="none", mew=1.5, zorder=8,
            label="global goal")
    ax.plot([], [], "x", color="tab:blue", ms=8, mew=2, label="initial apex")
    ax.plot([], [], "v", color="tab:blue", ms=5, label="footholds")
    ax.plot([], [], color="0.2", lw=0.7, label="leg at touchdown / liftoff")
    back = int(np.sum(np.diff(apexes[:, 0]) < 0))
    ax.legend(loc="upper left", fontsize=8, ncol=2)
    ax.set_title(title or f"{name} across '{terrain.name}' with the reactive planner "
                 f"({back} backward stride{'' if back == 1 else 's'})")
    ax.set_ylim(float(np.min(terrain.heights)) - 0.6,
                max(float(np.max(apexes[:, 1])), float(np.max(goals[:, 1], initial=0))) + 0.8)
    fig.tight_layout()
    return fig


def doa_figure(terrain: Terrain, initial: np.ndarray, code: np.ndarray, steps: np.ndarray,
               goal=None, title="Domain of attraction", dy: float = 0.05, dz: float = 0.05):
    """Domain-of-attraction map (Figs. 16, 17, 20): success shaded by strides, failures red.

    Works for BHop and SLIP sweeps alike; the legend splits failures by kind (SLIP adds
    `solver`).
    """
    code, steps = np.asarray(code), np.asarray(steps)
    initial = np.asarray(initial)
    fig, ax = plt.subplots(figsize=(11, 3.8))
    draw_terrain(ax, terrain)
    ok = code == 0
    cmap = ListedColormap(plt.get_cmap("Greens")(np.linspace(0.25, 1.0, 256)))
    sc = ax.scatter(initial[ok, 0], initial[ok, 1], c=steps[ok], cmap=cmap, s=5, marker="s",
                    lw=0, zorder=3)
    kinds = ", ".join(f"{result_name(c)} {int((code == c).sum())}"
                      for c in np.unique(code[~ok]))
    ax.scatter(initial[~ok, 0], initial[~ok, 1], c="tab:red", s=6, marker="s", lw=0, zorder=3,
               label=f"failure ({int((~ok).sum())}{': ' + kinds if kinds else ''})")
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=7, label="global goal", zorder=4)
    fig.colorbar(sc, ax=ax, label="strides to goal", fraction=0.03, pad=0.01)
    ax.legend(loc="upper left", fontsize=8)
    rate = 100.0 * ok.mean() if ok.size else 0.0
    ax.set_title(f"{title}: {rate:.1f}% of {ok.size} initial apexes reach the goal")
    fig.tight_layout()
    return fig


def disturbance_figure(terrain: Terrain, nominal: dict, open_loop: dict, reactive: dict,
                       goal=None, noise: str = "wind", style: RunStyle | None = None,
                       note: str = ""):
    """Nominal run against the same plan under a disturbance (Figs. 14-15).

    Top: the nominal run and its plan replayed open loop under the disturbance
    (`open_loop_replay`). Bottom: the nominal run and the reactive controller under the same
    disturbance. Apexes where the reactive run chose a policy the nominal run never used are
    circled. `style` (`RunStyle`): the hopper, and the wind that bends the disturbed runs'
    arcs. `note` is added to the titles (say, a goal tolerance other than the default).
    """
    style = RunStyle() if style is None else style
    rho0, g = style.rho0, style.g
    fig, axes = plt.subplots(2, 1, figsize=(11, 6.6), sharex=True)
    nominal_used = set(np.asarray(nominal["policies"])[: int(nominal["steps"])].tolist())
    for ax, other, what, color in (
            (axes[0], open_loop, "offline plan, open loop", "tab:red"),
            (axes[1], reactive, "reactive controller", "tab:green")):
        draw_terrain(ax, terrain)
        draw_run(ax, nominal["apexes"], nominal["footholds"], rho0, g, "0.45",
                 f"no noise: {RESULT_NAMES[int(nominal['code'])]} in "
                 f"{int(nominal['steps'])} strides", ls="--")
        draw_run(ax, other["apexes"], other["footholds"], rho0, g, color,
                 f"{what} under {noise} noise: {RESULT_NAMES[int(other['code'])]} in "
                 f"{int(other['steps'])} strides", wind=style.wind)
        if goal is not None:
            ax.plot(goal[0], goal[1], "ko", ms=7, label="global goal", zorder=7)
        ax.set_title(f"No noise vs. {what} under {noise} noise" + (f" ({note})" if note
                                                                        else ""))
        if ax is axes[1]:
            steps = int(reactive["steps"])
            pol = np.asarray(reactive["policies"])[:steps]
            new = np.array([p not in nominal_used for p in pol.tolist()], bool)
            ap = np.asarray(reactive["apexes"])[:steps][new]
            ax.plot(ap[:, 0], ap[:, 1], "o", ms=11, mfc="none", mec="tab:green", mew=1.2,
                    zorder=7, label=f"new policy chosen ({int(new.sum())} apexes)")
        _headroom(ax, terrain, (nominal, open_loop, reactive), 1.0)
        ax.legend(loc="upper left", fontsize=8, ncol=2)
    axes[0].set_xlabel("")
    fig.suptitle("x: start, dots: apexes, triangles: footholds", fontsize=9, y=0.995)
    fig.tight_layout()
    return fig


# --- figures of a plan ----------------------------------------------------------------


def template_regions_figure(templates, hopper, n: int = 121):
    """Domain and feasible-goal regions of every template in `(ydot, zr)` (Fig. 9).

    Left: `D(Φ)` (eqs 38-41); right: `Gf(Φ)` by the exact closed form. One colour per
    template; the y extent (not shown) is a band of width `2l` (domain) or
    `dy_hi - dy_lo - 2l` (goal) around the touchdown / liftoff line.
    """
    import jax
    import jax.numpy as jnp

    from .._planning.regions import domain_height_bounds, goal_height_bounds

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
