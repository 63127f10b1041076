"""`jaxhop demo`: the main job on the built-in `reference` terrain."""

from __future__ import annotations

import json
import os
import time

import jax
import numpy as np

from .._control.decisions import in_global_domain
from .._core.params import disturbance_for
from .._core.terrain import builtin_terrain
from .._execution.batches import run_batch, sweep, sweep_grid
from .._execution.settings import ExecSettings, RunSettings
from .._models.flight import RESULT_NAMES
from .._planning.cache import get_plan
from .._planning.plan import build_plan

EXAMPLE_STARTS = ((0.6, 1.6, 0.5), (3.6, 1.5, 0.5))
# Fig. 21: SLIP on `long`, starting in the deep well.
LONG_START = (1.65, 1.1, 0.5)


def _nearest_inside(initial: np.ndarray, target) -> np.ndarray:
    return initial[np.argmin(np.sum((initial - np.asarray(target)) ** 2, axis=1))]


def demo(out: str = "jaxhop-demo", cache: bool = True, log=print) -> dict:
    """Plan on `reference`, two example runs, sweeps under disturbances, figures, summary.

    Writes `template_regions.png` (Fig. 9), `terrain_domain.png` (Fig. 10),
    `goal_coverage.png` (Fig. 11), `prepares.png` (Fig. 12), `example_runs.png` (Fig. 13),
    `run.gif`, `disturbance_wind.png` and `disturbance_sensor.png` (Figs. 14-15: the
    offline plan open loop against the adaptive reactive controller), `doa_none.png`,
    `doa_wind.png` (Fig. 16) and `doa_sensor.png` (Fig. 17) with the adaptive controller,
    `doa_wind_paper.png` (the paper's controller under wind), `slip_long.png` (Fig. 21:
    SLIP on `long` with its BHop plan) and `summary.json` into `out`, and prints a short
    table. Every run uses the default goal tolerance (0.05 m, 0.05 m, 0.05 m/s).
    """
    import matplotlib.pyplot as plt

    from .._execution.replay import open_loop_replay
    from .._viz.animate import animate_run
    from .._viz.draw import RunStyle
    from .._viz.plot import (
        disturbance_figure,
        doa_figure,
        global_domain_figure,
        goal_coverage_figure,
        long_run_figure,
        prepares_figure,
        runs_figure,
        template_regions_figure,
    )

    os.makedirs(out, exist_ok=True)
    t0 = time.perf_counter()
    terrain = builtin_terrain("reference")
    plan = get_plan(terrain, log=log) if cache else build_plan(terrain)
    log(f"plan: {plan.stats['n_instantiated']} instantiated policies "
        f"({plan.stats['seconds']} s{', from cache' if plan.stats.get('from_cache') else ''})")
    tables = plan.tables()
    grid = sweep_grid(terrain)
    inside = in_global_domain(grid, tables, plan.hopper)
    initial = grid[inside]

    figures = {}

    def save(fig, name):
        path = os.path.join(out, name)
        fig.savefig(path, dpi=130)
        plt.close(fig)
        figures[name.split(".")[0]] = path

    save(template_regions_figure(plan.templates, plan.hopper), "template_regions.png")
    save(global_domain_figure(terrain, grid, inside, plan.goal), "terrain_domain.png")
    save(goal_coverage_figure(plan), "goal_coverage.png")
    save(prepares_figure(plan), "prepares.png")

    starts = np.stack([_nearest_inside(initial, s) for s in EXAMPLE_STARTS])
    runs = run_batch(plan, starts, RunSettings(controller="paper"), key=jax.random.key(0))
    examples = [{k: v[i] for k, v in runs.items()} for i in range(len(starts))]
    save(runs_figure(terrain, examples, plan.goal, "Two reactive BHop runs on 'reference'",
                     plan=plan), "example_runs.png")
    figures["run_animation"] = animate_run(terrain, examples[0], os.path.join(out, "run.gif"),
                                           goal=plan.goal)

    # Figs. 14-15: the first example's plan replayed open loop vs. the adaptive reactive
    # controller (docs/decisions.md, "Adaptive controller").
    disturbed = {}
    for noise, mode in (("wind", "controls"), ("sensor", "goals")):
        dist, key, tol = disturbance_for(noise), jax.random.key(1), (0.05, 0.05, 0.05)
        reactive = run_batch(plan, starts[:1], RunSettings(tolerance=np.asarray(tol)), key=key,
                             disturbance=dist, execution=ExecSettings(chunk=len(starts)))
        reactive = {k: v[0] for k, v in reactive.items()}
        replay = open_loop_replay(plan, examples[0], disturbance=dist, key=key, mode=mode,
                                  tolerance=tol)
        save(disturbance_figure(terrain, examples[0], replay, reactive, plan.goal, noise,
                                RunStyle(wind=float(dist.wind)), note="adaptive controller"),
             f"disturbance_{noise}.png")
        disturbed[noise] = {
            "tolerance": list(tol),
            "open_loop": {"replays": mode, "result": RESULT_NAMES[int(replay["code"])],
                          "steps": int(replay["steps"])},
            "reactive": {"result": RESULT_NAMES[int(reactive["code"])],
                         "steps": int(reactive["steps"])}}

    sweeps = {}
    for noise, controller in (("none", "adaptive"), ("wind", "adaptive"),
                              ("sensor", "adaptive"), ("wind", "paper")):
        name = noise if controller == "adaptive" else f"{noise}, paper"
        sweeps[name], _, res = sweep(plan, RunSettings(controller=controller),
                                     initial=initial, key=jax.random.key(0),
                                     disturbance=disturbance_for(noise),
                                     execution=ExecSettings(progress=True))
        save(doa_figure(terrain, initial, res["code"], res["steps"], plan.goal,
                        f"BHop, noise {noise}, {controller} controller"),
             f"doa_{noise}{'' if controller == 'adaptive' else '_paper'}.png")

    # Fig. 21: the SLIP model across `long`, driven by the BHop plan (compiles the SLIP
    # stride and deadbeat: about a minute).
    long_terrain = builtin_terrain("long")
    long_plan = get_plan(long_terrain, log=log) if cache else build_plan(long_terrain)
    slip = run_batch(long_plan, np.asarray([LONG_START]),
                     RunSettings(model="slip", controller="paper"), key=jax.random.key(0))
    slip = {k: v[0] for k, v in slip.items()}
    save(long_run_figure(long_plan, slip, "slip"), "slip_long.png")
    log(f"SLIP on 'long': {RESULT_NAMES[int(slip['code'])]} in {int(slip['steps'])} strides")

    summary = {
        "terrain": terrain.name,
        "goal": plan.goal.tolist(),
        "plan": plan.summary(),
        "examples": [{"start": s.tolist(), "result": RESULT_NAMES[int(e["code"])],
                      "steps": int(e["steps"])} for s, e in zip(starts, examples)],
        "disturbed": disturbed,
        "slip_long": {"start": list(LONG_START), "result": RESULT_NAMES[int(slip["code"])],
                      "steps": int(slip["steps"])},
        "sweeps": sweeps,
        "figures": figures,
        "seconds": round(time.perf_counter() - t0, 2),
    }
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)

    p = summary["plan"]
    print(f"jaxhop demo on 'reference' -> {out}/")
    print(f"  plan: {p['n_segments']} segments, {p['n_situated']} situated, "
          f"{p['n_instantiated']} instantiated, {p['n_deployed']} deployed")
    for e in summary["examples"]:
        print(f"  run from {np.round(e['start'], 2).tolist()}: {e['result']} in "
              f"{e['steps']} strides")
    for noise, d in summary["disturbed"].items():
        print(f"  {noise} noise from {EXAMPLE_STARTS[0]}: open loop {d['open_loop']['result']}"
              f" after {d['open_loop']['steps']}, reactive {d['reactive']['result']} after "
              f"{d['reactive']['steps']} strides")
    sl = summary["slip_long"]
    print(f"  SLIP on 'long' from {sl['start']}: {sl['result']} in {sl['steps']} strides")
    print(f"  {'sweep':13s} {'runs':>6s} {'success':>8s} {'mean':>6s}  failures")
    for noise, s in sweeps.items():
        fails = ", ".join(f"{k} {v}" for k, v in s["failures"].items() if v) or "-"
        print(f"  {noise:13s} {s['n_initial_conditions']:6d} {s['success_rate']:8.4f} "
              f"{s['mean_steps']:6.2f}  {fails}")
    print(f"  figures: {', '.join(os.path.basename(v) for v in figures.values())}; "
          f"total {summary['seconds']} s")
    return summary
