"""Write the notebooks (without outputs) from the cell sources below.

Run `python notebooks/_make.py` after editing; the .ipynb files are what users open.
"""

import pathlib

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = pathlib.Path(__file__).parent

IMPORTS = '''import os

import jax
import numpy as np

import jaxhop
from jaxhop import _plot

# CI runs the notebooks with JAXHOP_NB_QUICK=1 (coarser sweep grids).
QUICK = bool(os.environ.get("JAXHOP_NB_QUICK"))
STEP = 0.2 if QUICK else 0.05'''

NOTEBOOKS = {
    "01_bhop_planning": [
        ("md", """# Reactive planning for the ball hopper (BHop)

This notebook walks through the pipeline of Arslan & Saranli (2012) on the built-in
`reference` terrain. It goes from policy templates and their regions, through situating
and instantiation, the prepares relation and the deployed order, to reactive runs."""),
        ("code", IMPORTS),
        ("md", """## Templates and their regions (Fig. 9)

Each of the 20 templates has an analytic domain `D` (apex states from which the stride
lands on its segment) and a feasible goal region `Gf`: the apex states reachable from
*every* state of the domain with admissible controls. jaxhop computes `Gf` with an exact
closed form; the test suite checks it against the definition (eq 6) by brute force."""),
        ("code", '''templates, hopper = jaxhop.paper_templates(), jaxhop.Hopper()
fig = _plot.template_regions_figure(templates, hopper)'''),
        ("md", """## The plan

`get_plan` situates the 20 templates on every 15 cm segment and instantiates every pair
whose regions intersect, with a goal chosen to maximise the margin to the boundary. It
builds the prepares relation and deploys by backchaining from the goal. The first call
builds the plan (compilation included); later calls load it from the cache."""),
        ("code", '''terrain = jaxhop.builtin_terrain("reference")
plan = jaxhop.get_plan(terrain, progress=False)
plan.summary()'''),
        ("code", '''fig = _plot.goal_coverage_figure(plan)
fig = _plot.prepares_figure(plan)'''),
        ("md", """## Global domain and two reactive runs (Figs. 10, 13)

At every apex the controller takes the first deployed policy whose domain contains the
measured state and applies the BHop deadbeat control toward its goal. No replanning
happens."""),
        ("code", '''grid = jaxhop.sweep_grid(terrain, dy=STEP, dz=STEP)
inside = jaxhop.in_global_domain(grid, plan.tables(), plan.hopper)
fig = _plot.global_domain_figure(terrain, grid, inside, plan.goal)
runs = jaxhop.run_batch(plan, [[0.6, 1.6, 0.5], [3.6, 1.5, 0.5]])
examples = [{k: v[i] for k, v in runs.items()} for i in range(2)]
fig = _plot.runs_figure(terrain, examples, plan.goal)
[(jaxhop.RESULT_NAMES[int(e["code"])], int(e["steps"])) for e in examples]'''),
        ("md", """## Correct by construction

Every non-goal policy in the order prepares a policy deployed before it. Each stride
therefore moves to a strictly earlier policy, and without disturbances every state in the
global domain reaches the goal."""),
        ("code", '''print("deployment invariant holds:",
      jaxhop.check_order(plan.order, plan.prepares, plan.situated, plan.is_goal))
summary, initial, result = jaxhop.sweep(plan, dy=STEP, dz=STEP)
assert summary["success_rate"] == 1.0
summary'''),
    ],
    "02_robustness_sweeps": [
        ("md", """# Robustness: wind, sensor noise and map errors (Figs. 14-17)

We run the domain-of-attraction sweep of section VI-C on `reference` under the paper's
three disturbances and look at where and why runs fail."""),
        ("code", IMPORTS),
        ("code", '''terrain = jaxhop.builtin_terrain("reference")
plan = jaxhop.get_plan(terrain, progress=False)'''),
        ("md", """## Nominal and sensor noise

Sensor noise is uniform, ±5 cm on `y` and `z` and ±5 cm/s on `ydot`, and fresh at every
apex. The controller sees only the measured state; the simulation uses the true one."""),
        ("code", '''results = {}
for noise in ("none", "sensor"):
    s, initial, r = jaxhop.sweep(plan, disturbance=jaxhop.disturbance_for(noise),
                                 key=jax.random.key(0), dy=STEP, dz=STEP)
    results[noise] = (s, initial, r)
    fig = _plot.doa_figure(terrain, initial, r["code"], r["steps"], plan.goal,
                           f"noise {noise}")
{k: (v[0]["success_rate"], v[0]["failures"]) for k, v in results.items()}'''),
        ("md", """Most sensor-noise failures happen at the **first** apex. The initial state sits on
the edge of the global domain, and its first noisy measurement falls outside every policy.
Runs that survive the first measurement almost always reach the goal:"""),
        ("code", '''s, initial, r = results["sensor"]
failed = r["code"] != 0
first = failed & (r["steps"] == 0)
print(f"failures: {failed.sum()}, at the first apex: {first.sum()}, "
      f"success after the first apex: {1 - (failed & ~first).sum() / (~first).sum():.4f}")'''),
        ("md", """## Wind

A constant -0.2 m/s² horizontal wind acts in every flight phase. The deadbeat does not
know about it, so each stride ends slower than planned. The hopper reaches the goal
*position*, but with the spec's 0.05 m/s velocity tolerance it never stops inside the goal
box. Widening the velocity tolerance shows how much of the failure is that effect alone
(see `docs/decisions.md`)."""),
        ("code", '''for tol in (0.05, 0.15, 0.25):
    r = jaxhop.run_batch(plan, initial, key=jax.random.key(0),
                         disturbance=jaxhop.disturbance_for("wind"),
                         tolerance=np.array([0.05, 0.05, tol]))
    print(f"velocity tolerance {tol}: success {np.mean(r['code'] == 0):.3f}")'''),
        ("md", """## Map errors

Under `ground` noise the planner sees block heights off by up to ±15 cm (one draw per
block) and plans on that map. The hopper runs on the true terrain."""),
        ("code", '''heights = np.asarray(terrain.heights)
noise = np.asarray(jax.random.uniform(jax.random.key(1), heights.shape, minval=-0.15,
                                      maxval=0.15))
perceived = terrain.with_heights(heights + noise)
plan_p = jaxhop.get_plan(perceived, terrain.goal, progress=False)
grid = jaxhop.sweep_grid(terrain, dy=STEP, dz=STEP)
init_p = grid[jaxhop.in_global_domain(grid, plan_p.tables(), plan_p.hopper)]
r = jaxhop.run_batch(plan_p, init_p, true_terrain=terrain)
fig = _plot.doa_figure(terrain, init_p, r["code"], r["steps"], plan_p.goal, "ground noise")
print("success", np.mean(r["code"] == 0))'''),
    ],
}


def build():
    for name, cells in NOTEBOOKS.items():
        nb = new_notebook(cells=[new_markdown_cell(src) if kind == "md" else
                                 new_code_cell(src) for kind, src in cells])
        nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                     "language": "python"}
        nbformat.write(nb, HERE / f"{name}.ipynb")


if __name__ == "__main__":
    build()
