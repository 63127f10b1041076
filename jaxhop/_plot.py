"""Figures: pure functions that take results and return a matplotlib Figure."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402

from ._flight import RESULT_NAMES  # noqa: E402
from ._plan import Plan  # noqa: E402
from ._terrain import Terrain  # noqa: E402


def draw_terrain(ax, terrain: Terrain, perceived: Terrain | None = None, depth: float = 0.6):
    """Blocks as filled rectangles; holes stay empty. A perceived map is drawn dashed."""
    bottom = float(np.min(terrain.heights)) - depth
    for s, e, h in terrain.blocks():
        ax.fill_between([s, e], [bottom, bottom], [h, h], color="0.55", lw=0, zorder=1)
        ax.plot([s, s, e, e], [bottom, h, h, bottom], color="0.25", lw=1.0, zorder=2)
    if perceived is not None:
        for s, e, h in perceived.blocks():
            ax.plot([s, e], [h, h], "k--", lw=0.8, zorder=2)
    ax.set_xlabel("y (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal")


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


def _arc(y0, z0, vy, vz, t1, g, n=20):
    t = np.linspace(0.0, t1, n)
    return y0 + vy * t, z0 + vz * t - 0.5 * g * t**2


def draw_run(ax, apexes: np.ndarray, footholds: np.ndarray, rho0: float = 1.0,
             g: float = 9.81, color="tab:blue", label=None):
    """COM path of a run from its apexes and footholds (nominal ballistic arcs)."""
    apexes = apexes[np.all(np.isfinite(apexes), axis=1)]
    feet = footholds[np.all(np.isfinite(footholds), axis=1)]
    for k, (y, h) in enumerate(feet):
        a = apexes[k]
        zr = a[1] - h - rho0
        t_d = np.sqrt(max(2 * zr / g, 0.0))
        ys, zs = _arc(a[0], a[1], a[2], 0.0, t_d, g)
        ax.plot(ys, zs, color=color, lw=1.2, zorder=5, label=label if k == 0 else None)
        ax.plot([y, y], [h, h + rho0], color="0.3", lw=0.6, zorder=4)
        if k + 1 < len(apexes):
            b = apexes[k + 1]
            t_up = np.sqrt(max(2 * (b[1] - h - rho0) / g, 0.0))
            y_lo = b[0] - b[2] * t_up
            ax.plot([ys[-1], y_lo], [zs[-1], zs[-1]], color=color, lw=1.2, zorder=5)
            ys2, zs2 = _arc(y_lo, h + rho0, b[2], g * t_up, t_up, g)
            ax.plot(ys2, zs2, color=color, lw=1.2, zorder=5)
    ax.plot(feet[:, 0], feet[:, 1], "v", color=color, ms=5, zorder=6)
    ax.plot(apexes[:, 0], apexes[:, 1], ".", color=color, ms=5, zorder=6)
    ax.plot(apexes[0, 0], apexes[0, 1], "x", color=color, ms=8, mew=2, zorder=6)


def runs_figure(terrain: Terrain, runs: list[dict], goal=None, title="Example runs",
                perceived: Terrain | None = None, rho0: float = 1.0, g: float = 9.81):
    """Example runs over the terrain (Fig. 13): COM path, apexes (dots), footholds (triangles).

    Each run is a dict with `apexes`, `footholds`, `code`, `steps`.
    """
    fig, ax = plt.subplots(figsize=(11, 3.8))
    draw_terrain(ax, terrain, perceived)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, run in enumerate(runs):
        label = f"run {i + 1}: {RESULT_NAMES[int(run['code'])]} in {int(run['steps'])} strides"
        draw_run(ax, run["apexes"], run["footholds"], rho0, g, colors[i % len(colors)], label)
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=7, label="global goal", zorder=7)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title + "  (x: start, dots: apexes, triangles: footholds)")
    fig.tight_layout()
    return fig


def doa_figure(terrain: Terrain, initial: np.ndarray, code: np.ndarray, steps: np.ndarray,
               goal=None, title="Domain of attraction", dy: float = 0.05, dz: float = 0.05):
    """Domain-of-attraction map (Figs. 16, 17, 20): success shaded by strides, failures red."""
    fig, ax = plt.subplots(figsize=(11, 3.8))
    draw_terrain(ax, terrain)
    ok = code == 0
    cmap = ListedColormap(plt.get_cmap("Greens")(np.linspace(0.25, 1.0, 256)))
    sc = ax.scatter(initial[ok, 0], initial[ok, 1], c=steps[ok], cmap=cmap, s=5, marker="s",
                    lw=0, zorder=3)
    ax.scatter(initial[~ok, 0], initial[~ok, 1], c="tab:red", s=6, marker="s", lw=0, zorder=3,
               label=f"failure ({int((~ok).sum())})")
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=7, label="global goal", zorder=4)
    fig.colorbar(sc, ax=ax, label="strides to goal", fraction=0.03, pad=0.01)
    ax.legend(loc="upper left", fontsize=8)
    rate = 100.0 * ok.mean() if ok.size else 0.0
    ax.set_title(f"{title}: {rate:.1f}% of {ok.size} initial apexes reach the goal")
    fig.tight_layout()
    return fig


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


def animate_run(terrain: Terrain, run: dict, path: str, rho0: float = 1.0, g: float = 9.81,
                fps: int = 25, goal=None) -> str:
    """Write a GIF of a run: the body, its leg, the terrain and the footholds.

    The flight is redrawn from the apexes and footholds (nominal ballistic arcs; the BHop
    stance is instantaneous, shown as the COM sliding `dy` at `rho0` over the foot).
    Returns the path written.
    """
    from matplotlib.animation import FuncAnimation, PillowWriter

    apexes = run["apexes"][np.all(np.isfinite(run["apexes"]), axis=1)]
    feet = run["footholds"][np.all(np.isfinite(run["footholds"]), axis=1)]
    frames = []  # (com_y, com_z, foot_y, foot_z, in_contact)
    dt = 1.0 / fps
    for k, (yf, h) in enumerate(feet):
        a = apexes[k]
        t_d = np.sqrt(max(2 * (a[1] - h - rho0) / g, 0.0))
        for t in np.arange(0.0, t_d, dt):
            cy, cz = a[0] + a[2] * t, a[1] - 0.5 * g * t * t
            frames.append((cy, cz, cy, cz - rho0, False))
        if k + 1 < len(apexes):
            b = apexes[k + 1]
            t_up = np.sqrt(max(2 * (b[1] - h - rho0) / g, 0.0))
            y_lo = b[0] - b[2] * t_up
            for s in np.linspace(0.0, 1.0, 4):
                frames.append((yf + s * (y_lo - yf), h + rho0, yf, h, True))
            for t in np.arange(0.0, t_up, dt):
                cy = y_lo + b[2] * t
                cz = h + rho0 + g * t_up * t - 0.5 * g * t * t
                frames.append((cy, cz, cy, cz - 0.3 * rho0, False))
    if not frames:
        frames.append((apexes[0, 0], apexes[0, 1], apexes[0, 0], apexes[0, 1] - rho0, False))
    fig, ax = plt.subplots(figsize=(9, 3.4))
    draw_terrain(ax, terrain)
    if goal is not None:
        ax.plot(goal[0], goal[1], "ko", ms=6)
    ax.set_ylim(float(np.min(terrain.heights)) - 0.6, float(np.max(apexes[:, 1])) + 0.3)
    (leg,) = ax.plot([], [], color="0.2", lw=2, zorder=6)
    (body,) = ax.plot([], [], "o", color="tab:orange", ms=12, zorder=7)
    (marks,) = ax.plot([], [], "v", color="tab:blue", ms=6, zorder=5)
    ax.set_title(f"{RESULT_NAMES[int(run['code'])]} in {int(run['steps'])} strides")
    contacts: list[tuple[float, float]] = []

    def draw(i):
        cy, cz, fy, fz, contact = frames[i]
        if contact and (not contacts or contacts[-1] != (fy, fz)):
            contacts.append((fy, fz))
        leg.set_data([cy, fy], [cz, fz])
        body.set_data([cy], [cz])
        if contacts:
            marks.set_data(*zip(*contacts))
        return leg, body, marks

    anim = FuncAnimation(fig, draw, frames=len(frames), blit=True)
    anim.save(path, writer=PillowWriter(fps=fps))
    plt.close(fig)
    return path
