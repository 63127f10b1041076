"""Interactive explorers for notebooks (ipywidgets): a plan's runs and policies (`explore`)
and one SLIP stride with its deadbeat (`explore_stride`); `docs/explore.md`.

Each explorer is an `Explorer`: a widget box whose controls redraw one matplotlib figure in
place, so it needs no interactive backend and runs headless. Its artists' data are
replaced and only they are drawn by Agg over the figure's static background (terrain,
axes), rendered once; the result goes to an image widget as a PNG. Every program a value
change calls is compiled when the explorer is built: the dropdowns offer only what was
compiled then (`models`, `controllers`), and everything else a control sets (apex,
disturbance, seed, controls, targets) is a traced value of the same shape.
"""

from __future__ import annotations

import io
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._control.decisions import in_global_domain
from .._core.params import Hopper, disturbance_for
from .._core.programs import jit
from .._core.result import RESULT_NAMES
from .._core.terrain import make_terrain
from .._execution.batches import run_batch, sweep_grid
from .._execution.settings import RunSettings
from .._models.slip.deadbeat import deadbeat_slip
from .._models.slip.kernels import RATIO_HI, RATIO_LO, kc_limits
from .._planning.plan import Plan
from .draw import draw_terrain, policy_cross_sections, stride_paths
from .stride_path import stride_path_jit

#: The disturbances `explore` offers by default (`disturbance_for`; `ground` changes the
#: map, hence the plan, and is left out).
NOISES = ("none", "wind", "sensor", "wind+sensor")

#: The explorers' figures' resolution (dots per inch).
DPI = 80
TITLE = {"loc": "left", "fontsize": 9}

deadbeat_jit = jit(deadbeat_slip)


def _widgets():
    try:
        import ipywidgets
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError('the explorers need ipywidgets: pip install "jaxhop[notebook]"') from err
    return ipywidgets


class Explorer:
    """An explorer: `widget` (display it, or let a notebook cell end with the explorer),
    `figure` (its matplotlib figure), `controls` (name -> widget), `artists` (name ->
    matplotlib artist, drawn over the static background), `result` (what the figure shows
    now, as a dict), `image` (the image widget; `image.value` is the PNG shown) and
    `status` (the text widget under the figure)."""

    def __init__(self, figure, controls: dict, artists: dict, draw):
        ipw = _widgets()
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        self._canvas = FigureCanvasAgg(figure)
        for artist in artists.values():
            artist.set_animated(True)  # left out of the background
        for ax in figure.axes:
            ax.set_autoscale_on(False)
        self._canvas.draw()
        self._background = self._canvas.copy_from_bbox(figure.bbox)
        self.figure, self.controls, self.artists, self.result = figure, controls, artists, {}
        self.image = ipw.Image(format="png")
        self.status = ipw.HTML()
        self._draw, self._held = draw, False
        for w in controls.values():
            if not isinstance(w, ipw.Button):
                w.observe(lambda change: self.redraw(), names="value")
        rows = [ipw.HBox(list(controls.values())[i:i + 4]) for i in range(0, len(controls), 4)]
        self.widget = ipw.VBox([*rows, self.image, self.status])
        self.redraw()

    def values(self) -> dict:
        return {k: w.value for k, w in self.controls.items() if hasattr(w, "value")}

    def set(self, **values):
        """Set several controls at once, with one redraw."""
        self._held = True
        try:
            for k, v in values.items():
                self.controls[k].value = v
        finally:
            self._held = False
        self.redraw()

    def redraw(self):
        if self._held:
            return
        from PIL import Image

        self._draw(self, self.values())
        canvas = self._canvas
        canvas.restore_region(self._background)
        for artist in self.artists.values():
            self.figure.draw_artist(artist)
        buf = io.BytesIO()
        Image.frombuffer("RGBA", canvas.get_width_height(), canvas.buffer_rgba()).save(
            buf, format="png", compress_level=1)
        self.image.value = buf.getvalue()

    def _repr_mimebundle_(self, **kwargs):
        return self.widget._repr_mimebundle_(**kwargs)


def _slider(ipw, label, lo, hi, value, step):
    return ipw.FloatSlider(value=float(np.clip(value, lo, hi)), min=lo, max=hi, step=step,
                           description=label, continuous_update=False, readout_format=".3f")


def _run_text(run: dict, most: int | None = None) -> str:
    """The result, strides and policy sequence of a run (the first `most` policies)."""
    steps = int(run["steps"])
    used = [str(int(p)) for p in run["policies"][:steps]]
    more = ", ..." if most is not None and len(used) > most else ""
    return (f"{RESULT_NAMES[int(run['code'])]} in {steps} strides; policies "
            f"{', '.join(used[:most]) or 'none'}{more}")


def explore(plan: Plan, apex0=None, *, models: Sequence[str] = ("bhop",),
            controllers: Sequence[str] = ("adaptive", "paper"), noises: Sequence[str] = NOISES,
            seeds: int = 10) -> Explorer:
    """An explorer of a plan's reactive runs and deployed policies.

    The top panel draws the run (`run_batch`) from the initial apex set by the sliders `y`,
    `z`, `ydot`, with the model, controller, disturbance (`disturbance_for`) and seed
    (`key(seed)`) of the dropdowns: its path over the terrain, apexes, footholds, result and
    policy sequence. The bottom panel draws the deployed policy at position `policy` of the
    order: its domain's cross-section at the slider's `ydot` and its feasible goal's at its
    goal's (`policy_cross_sections`), its goal, and the segments of the situated policies it
    prepares (`plan.prepares`).

    Arguments:
        plan: a deployed plan.
        apex0: the first initial apex (default: the first grid state in the global domain).
        models: the models offered (`"bhop"`, `"slip"`); each is compiled here, SLIP's
            lane-pool step included (minutes the first time, `docs/explore.md`).
        controllers, noises: the controllers and disturbance names offered.
        seeds: the seeds offered, `0 .. seeds - 1`.

    Returns:
        An `Explorer`. Raises `ImportError` without ipywidgets.
    """
    ipw = _widgets()
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon

    terrain, hopper = plan.terrain, plan.hopper
    if apex0 is None:
        grid = sweep_grid(terrain)
        apex0 = grid[np.argmax(in_global_domain(grid, plan.tables(), hopper))]
    y0, y1 = terrain.y_range
    h = np.asarray(terrain.heights)
    controls = {
        "y": _slider(ipw, "y (m)", y0, y1, apex0[0], 0.01),
        "z": _slider(ipw, "z (m)", float(h.min()) + 0.5, float(h.max()) + 3.0, apex0[1], 0.01),
        "ydot": _slider(ipw, "ydot (m/s)", 0.0, 1.5, apex0[2], 0.01),
        "policy": ipw.IntSlider(value=0, min=0, max=len(plan.order) - 1,
                                description="policy", continuous_update=False),
        "model": ipw.Dropdown(options=list(models), description="model"),
        "controller": ipw.Dropdown(options=list(controllers), description="controller"),
        "noise": ipw.Dropdown(options=list(noises), description="disturbance"),
        "seed": ipw.Dropdown(options=list(range(seeds)), description="seed"),
    }
    fig = Figure(figsize=(7.6, 6.8), dpi=DPI)
    ax_run, ax_pol = fig.subplots(2, 1, sharex=True)
    for ax in (ax_run, ax_pol):
        draw_terrain(ax, terrain)
        ax.plot(*plan.goal[:2], "ko", ms=6, zorder=7)
        ax.set_ylim(float(h.min()) - 0.65, float(h.max()) + 3.2)
    artists = {
        "path": ax_run.plot([], [], color="tab:blue", lw=1.2, zorder=5)[0],
        "apexes": ax_run.plot([], [], ".", color="tab:blue", ms=5, zorder=6)[0],
        "footholds": ax_run.plot([], [], "v", color="tab:blue", ms=5, zorder=6)[0],
        "start": ax_run.plot([], [], "x", color="tab:blue", ms=8, mew=2, zorder=6)[0],
        "domain": ax_pol.add_patch(Polygon(np.zeros((1, 2)), fc="darkred", alpha=0.28,
                                           zorder=3)),
        "goal_region": ax_pol.add_patch(Polygon(np.zeros((1, 2)), fc="limegreen", alpha=0.3,
                                                zorder=3)),
        "goal": ax_pol.plot([], [], "o", mfc="none", mec="darkgreen", ms=7, zorder=6)[0],
        "prepared": ax_pol.plot([], [], color="tab:orange", lw=4, zorder=4)[0],
        "apex": ax_pol.plot([], [], "x", color="tab:blue", ms=8, mew=2, zorder=6)[0],
        "run_title": ax_run.set_title("\n", **TITLE),
        "policy_title": ax_pol.set_title("\n", **TITLE),
    }
    fig.tight_layout()
    centre = np.asarray(plan.table().centre)
    half = plan.templates.half_length

    def run(values):
        settings = RunSettings(model=values["model"], controller=values["controller"])
        dist = disturbances[values["noise"]]
        out = run_batch(plan, [[values["y"], values["z"], values["ydot"]]], settings,
                        key=jax.random.key(values["seed"]), disturbance=dist)
        return {k: v[0] for k, v in out.items()}, float(dist.wind)

    # Compile every program a value change can call: one run per model and controller
    # (disturbances and seeds are traced values of one shape), and the disturbances' arrays.
    disturbances = {noise: disturbance_for(noise) for noise in noises}
    for model in models:
        for controller in controllers:
            run({**{k: w.value for k, w in controls.items()}, "model": model,
                 "controller": controller})

    last = {}

    def draw(ex: Explorer, values):
        key = tuple(v for k, v in values.items() if k != "policy")
        if last.get("key") != key:  # the policy picker alone draws the same run
            last.update(key=key, run=run(values))
        r, wind = last["run"]
        apexes = r["apexes"][np.all(np.isfinite(r["apexes"]), axis=1)]
        feet = r["footholds"][np.all(np.isfinite(r["footholds"]), axis=1)]
        parts = []
        for p in stride_paths(apexes, feet, float(hopper.rho0), float(hopper.g),
                              values["model"], wind):
            pieces = [p["descent"], ([p["td"][0], p["lo"][0]], [p["td"][1], p["lo"][1]])]
            pieces += [p["ascent"]] if p["ascent"] is not None else []
            parts += [np.stack(q, 1) for q in pieces] + [np.full((1, 2), np.nan)]
        path = np.concatenate(parts) if parts else np.zeros((0, 2))
        artists["path"].set_data(path[:, 0], path[:, 1])
        artists["apexes"].set_data(apexes[:, 0], apexes[:, 1])
        artists["footholds"].set_data(feet[:, 0], feet[:, 1])
        artists["start"].set_data([values["y"]], [values["z"]])
        head = (f"{values['model']}, {values['controller']} controller, {values['noise']}, "
                f"seed {values['seed']}: ")
        artists["run_title"].set_text(head + "\n" + _run_text(r, 12))
        a = int(plan.order[values["policy"]])
        apex = np.array([values["y"], values["z"], values["ydot"]])
        dom, goal_poly = policy_cross_sections(plan, [a], [apex])[0]
        for name, poly in (("domain", dom), ("goal_region", goal_poly)):
            artists[name].set_xy(np.zeros((1, 2)) if poly is None else poly)
        goal = np.asarray(plan.goals[a])
        artists["goal"].set_data([goal[0]], [goal[1]])
        artists["apex"].set_data([apex[0]], [apex[1]])
        segs = np.unique(plan.prepares[a].indices // plan.templates.n)
        ys = np.stack([centre[segs, 0] - half, centre[segs, 0] + half,
                       np.full(segs.size, np.nan)], 1).ravel()
        zs = np.repeat(centre[segs, 1], 3)
        zs[2::3] = np.nan
        artists["prepared"].set_data(ys, zs)
        artists["policy_title"].set_text(
            f"deployed policy {values['policy']} of {len(plan.order)} (instantiated {a}):\n"
            f"domain at ydot {apex[2]:.2f}, goal ({goal[0]:.2f}, {goal[1]:.2f}, "
            f"{goal[2]:.2f}), prepares policies on segments: {segs.size}")
        ex.result = {**r, "policy": a, "prepared_segments": segs}
        ex.status.value = head + _run_text(r)

    return Explorer(fig, controls, artists, draw)


def explore_stride(hopper: Hopper | None = None, apex=(0.0, 1.3, 1.0), u=None, *,
                   ground: float = 0.0) -> Explorer:
    """An explorer of one SLIP stride over flat ground at height `ground`.

    Sliders set the apex `(y, z, ydot)` and the controls `(th_td, kc, kd)`; the figure draws
    the stride's COM path (`stride_path`: descent, compression, decompression, rise), the
    foothold and the leg at touchdown, bottom and liftoff, and the status line gives
    `slip_stride`'s next apex and result code. The button `deadbeat` solves for the controls
    that take the apex to the target apex of the `target` sliders (`deadbeat_slip`), sets
    the control sliders to them and reports the next apex's error to the target.

    Arguments:
        hopper: the hopper (default `Hopper()`).
        apex: the first apex; `u`: the first controls (default: `th_td = 0.1`, both
            stiffnesses at the middle of the `kc` range).

    Returns:
        An `Explorer`. Raises `ImportError` without ipywidgets.
    """
    ipw = _widgets()
    from matplotlib.figure import Figure

    hopper = Hopper() if hopper is None else hopper
    rho0 = float(hopper.rho0)
    kc_lo, kc_hi = (float(k) for k in kc_limits(hopper))
    u = (0.1, 0.5 * (kc_lo + kc_hi), 0.5 * (kc_lo + kc_hi)) if u is None else u
    terrain = make_terrain([(-4.0 * rho0 + apex[0], 8.0 * rho0 + apex[0], ground)])
    z_lo, z_hi = ground + 0.9 * rho0, ground + 2.0 * rho0
    v_hi = 3.0 * float(np.sqrt(hopper.g * hopper.rho0))
    controls = {
        "y": _slider(ipw, "y (m)", apex[0] - rho0, apex[0] + rho0, apex[0], 0.01),
        "z": _slider(ipw, "z (m)", z_lo, z_hi, apex[1], 0.01),
        "ydot": _slider(ipw, "ydot (m/s)", 0.0, v_hi, apex[2], 0.01),
        "th": _slider(ipw, "th_td (rad)", -0.4, 0.6, u[0], 0.001),
        "kc": _slider(ipw, "kc (N/m)", kc_lo, kc_hi, u[1], 10.0),
        "kd": _slider(ipw, "kd (N/m)", RATIO_LO * kc_lo, RATIO_HI * kc_hi, u[2], 10.0),
        "target_y": _slider(ipw, "target y", apex[0], apex[0] + 2 * rho0, apex[0] + 0.7, 0.01),
        "target_z": _slider(ipw, "target z", z_lo, z_hi, apex[1], 0.01),
        "target_ydot": _slider(ipw, "target ydot", 0.0, v_hi, apex[2], 0.01),
        "deadbeat": ipw.Button(description="deadbeat"),
    }
    fig = Figure(figsize=(5.6, 3.8), dpi=DPI)
    ax = fig.subplots()
    draw_terrain(ax, terrain, depth=0.3)
    ax.set_xlim(apex[0] - 0.6 * rho0, apex[0] + 2.2 * rho0)
    ax.set_ylim(ground - 0.3, z_hi + 0.2)
    artists = {
        "path": ax.plot([], [], color="tab:blue", lw=1.3, zorder=5)[0],
        "legs": ax.plot([], [], color="0.2", lw=0.8, zorder=4)[0],
        "foot": ax.plot([], [], "v", color="tab:blue", ms=6, zorder=6)[0],
        "next_apex": ax.plot([], [], "o", color="tab:blue", ms=5, zorder=6)[0],
        "target": ax.plot([], [], "o", mfc="none", mec="tab:red", ms=8, mew=1.5, zorder=6)[0],
        "title": ax.set_title("\n", **TITLE),
    }
    fig.tight_layout()
    state = {"deadbeat": None}

    def stride(values):
        apex = jnp.asarray([values["y"], values["z"], values["ydot"]], float)
        ctrl = jnp.asarray([values["th"], values["kc"], values["kd"]], float)
        return jax.tree.map(np.asarray, stride_path_jit(apex, ctrl, terrain, hopper))

    def target(values):
        return np.array([values["target_y"], values["target_z"], values["target_ydot"]])

    def draw(ex: Explorer, values):
        p = stride(values)
        artists["path"].set_data(p.path[:, 0], p.path[:, 1])
        legs = [np.stack([p.foot, q]) for q in (p.touchdown, p.bottom, p.liftoff)]
        legs = np.concatenate([np.vstack([leg, np.full((1, 2), np.nan)]) for leg in legs])
        artists["legs"].set_data(legs[:, 0], legs[:, 1])
        artists["foot"].set_data([p.foot[0]], [p.foot[1]])
        artists["next_apex"].set_data([p.next_apex[0]], [p.next_apex[1]])
        goal = target(values)
        artists["target"].set_data([goal[0]], [goal[1]])
        nxt = ", ".join(f"{x:.4f}" for x in p.next_apex)
        text = f"next apex ({nxt}): {RESULT_NAMES[int(p.code)]}"
        solved = state["deadbeat"]
        if solved is not None:
            err = float(np.max(np.abs(p.next_apex - solved["target"])))
            text += (f"\ndeadbeat to ({', '.join(f'{x:.3f}' for x in solved['target'])}): "
                     f"{'within the limits' if solved['ok'] else 'limits hit'}, error {err:.1e}")
            solved["error"] = err
        artists["title"].set_text(text)
        ex.result = {"next_apex": p.next_apex, "code": int(p.code), "foot": p.foot,
                     "path": p.path, "deadbeat": solved}
        ex.status.value = text

    def solve(values):
        apex = jnp.asarray([values["y"], values["z"], values["ydot"]], float)
        ctrl, ok = deadbeat_jit(apex, jnp.asarray(target(values)), float(ground), hopper)
        return np.asarray(ctrl), bool(ok)

    solve({**{k: w.value for k, w in controls.items() if k != "deadbeat"}})  # compile

    def forget(change):
        state["deadbeat"] = None  # a moved apex or target: the solution no longer applies

    # Observed before the explorer's redraw, so that the redraw sees it forgotten.
    for k in ("y", "z", "ydot", "target_y", "target_z", "target_ydot"):
        controls[k].observe(forget, names="value")
    explorer = Explorer(fig, controls, artists, draw)

    def on_deadbeat(_):
        values = explorer.values()
        ctrl, ok = solve(values)
        state["deadbeat"] = {"target": target(values), "u": ctrl, "ok": ok}
        explorer.set(th=float(ctrl[0]), kc=float(ctrl[1]), kd=float(ctrl[2]))

    controls["deadbeat"].on_click(on_deadbeat)
    return explorer
