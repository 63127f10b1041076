"""Write the notebooks (without outputs) from the cell sources below.

Run `python notebooks/_make.py` after editing; the .ipynb files are what users open.
"""

import hashlib
import pathlib

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = pathlib.Path(__file__).parent

IMPORTS = '''import os

import jax
import numpy as np

import jaxhop
from jaxhop import plot as _plot

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
        ("md", """## Explore first

`jaxhop.explore(plan)` runs the reactive controller from the initial apex of the sliders,
with the controller, disturbance and seed of the dropdowns, and draws the run over the
terrain (top). The `policy` slider picks a deployed policy by its position in the order;
the bottom panel shades its domain at the apex's `ydot` (dark red) and its feasible goal
(light green), and marks the segments of the policies it prepares (orange). Everything is
compiled when the explorer is built; a change redraws in a fraction of a second. It needs
`pip install "jaxhop[notebook]"` (ipywidgets); `docs/explore.md` says more."""),
        ("code", '''terrain = jaxhop.builtin_terrain("reference")
plan = jaxhop.get_plan(terrain, progress=False)  # built once, then loaded from the cache
explorer = jaxhop.explore(plan, [0.6, 1.6, 0.5])
explorer'''),
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
(at the top of this notebook) builds the plan, compilation included; later calls load it
from the cache."""),
        ("code", '''plan.summary()'''),
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
summary, initial, result = jaxhop.sweep(plan, initial=jaxhop.SweepGrid(dy=STEP, dz=STEP))
assert summary["success_rate"] == 1.0
summary'''),
    ],
    "02_robustness_sweeps": [
        ("md", """# Robustness: wind, sensor noise and map errors (Figs. 14-17)

We run the domain-of-attraction sweep of section VI-C on `reference` under the paper's
three disturbances, with two controllers: the paper's (`controller="paper"`, Fig. 8) and
the adaptive one (`controller="adaptive"`: a wind observer, foothold sensing and recovery
outside the domains; `docs/decisions.md`, "Adaptive controller"). The goal tolerance is
the strict default, 0.05 m, 0.05 m, 0.05 m/s."""),
        ("code", IMPORTS),
        ("code", '''terrain = jaxhop.builtin_terrain("reference")
plan = jaxhop.get_plan(terrain, progress=False)


def sweep(noise, controller, plan=plan, true_terrain=None):
    s, initial, r = jaxhop.sweep(plan, jaxhop.RunSettings(controller=controller),
                                 initial=jaxhop.SweepGrid(dy=STEP, dz=STEP),
                                 key=jax.random.key(0), true_terrain=true_terrain,
                                 disturbance=jaxhop.disturbance_for(noise))
    _plot.doa_figure(true_terrain or terrain, initial, r["code"], r["steps"], plan.goal,
                     f"{'ground' if true_terrain else noise} noise, {controller} controller")
    return s, initial, r'''),
        ("md", """## Nominal and sensor noise

Sensor noise is uniform, ±5 cm on `y` and `z` and ±5 cm/s on `ydot`, and fresh at every
apex. The controller sees only the measured state; the simulation uses the true one.
Without noise both controllers give the same runs."""),
        ("code", '''results = {(n, c): sweep(n, c)
           for n in ("none", "sensor") for c in ("paper", "adaptive")}
none_paper, none_adaptive = results["none", "paper"][2], results["none", "adaptive"][2]
assert np.array_equal(none_paper["code"], none_adaptive["code"])
assert np.array_equal(none_paper["steps"], none_adaptive["steps"])
{k: (v[0]["success_rate"], v[0]["failures"]) for k, v in results.items()}'''),
        ("md", """With the paper's controller most sensor-noise failures happen at the **first**
apex: the initial state sits on the edge of the global domain, and its first noisy
measurement falls outside every policy. The adaptive controller recovers such a state
into the nearest domain and goes on (`recoveries` counts those strides)."""),
        ("code", '''for c in ("paper", "adaptive"):
    s, initial, r = results["sensor", c]
    failed = r["code"] != 0
    first = failed & (r["steps"] == 0)
    print(f"{c:8s}: failures {failed.sum()}, at the first apex {first.sum()}, "
          f"recovered strides {s['recoveries']['total']}")'''),
        ("md", """## Wind

A constant -0.2 m/s² horizontal wind acts in every flight phase. The paper's deadbeat
does not know about it, so each stride ends slower than planned: the hopper reaches the
goal *position*, but never stops inside the 0.05 m/s velocity tolerance. The adaptive
controller estimates the wind from each stride's prediction error and inverts the flight
with it; its only failures are collisions in the first descent, before any control acts."""),
        ("code", '''wind = {c: sweep("wind", c) for c in ("paper", "adaptive")}
{c: (v[0]["success_rate"], v[0]["failures"], v[0]["first_stride_failures"])
 for c, v in wind.items()}'''),
        ("md", """## Map errors

Under `ground` noise the planner sees block heights off by up to ±15 cm (one draw per
block) and plans on that map. The hopper runs on the true terrain. The adaptive
controller senses the height of the block under its foot at touchdown."""),
        ("code", '''heights = np.asarray(terrain.heights)
noise = np.asarray(jax.random.uniform(jax.random.key(1), heights.shape, minval=-0.15,
                                      maxval=0.15))
perceived = terrain.with_heights(heights + noise)
plan_p = jaxhop.get_plan(perceived, terrain.goal, progress=False)
ground = {c: sweep("none", c, plan_p, terrain) for c in ("paper", "adaptive")}
{c: (v[0]["success_rate"], v[0]["failures"]) for c, v in ground.items()}'''),
    ],
}


SLIP = [
    ("md", """# The SLIP model with BHop plans (section VII, Figs. 19-21)

The ball hopper (BHop) behind the plans has an instantaneous stance. A real spring-mass
runner is closer to the spring-loaded inverted pendulum (SLIP, eq 10): a point mass on a
massless spring leg that stays on the ground for a while and swings over its foot.
jaxhop integrates the SLIP stance with diffrax (Tsit5, float64, events at the bottom of
the stance and at liftoff). This notebook checks the model, inverts it with the
position-aware deadbeat of eqs 12-16, and then drives it with the *unchanged* BHop plan:
the reactive controller has to absorb the mismatch.

The first SLIP call of each kind compiles the stance solver (a minute or so)."""),
    ("code", '''%matplotlib inline
import os

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import jaxhop
from jaxhop import plot as _plot

# CI runs the notebooks with JAXHOP_NB_QUICK=1 (smaller batches, one terrain).
QUICK = bool(os.environ.get("JAXHOP_NB_QUICK"))
N = 9 if QUICK else 41
hopper = jaxhop.Hopper()'''),
    ("md", """## Explore one stride

`jaxhop.explore_stride(hopper)` draws one SLIP stride over flat ground from the apex of the
sliders with the touchdown angle `th_td` and the stiffnesses `kc`, `kd` of the sliders:
the descent, the compression and decompression (legs drawn at touchdown, bottom and
liftoff) and the rise, with the next apex and the result code. The `deadbeat` button
solves for the controls that reach the `target` apex (the open red circle) and reports
the error. Building it compiles the stride and the deadbeat (about half a minute); a
change then redraws at once. It needs `pip install "jaxhop[notebook]"`."""),
    ("code", '''stride_explorer = jaxhop.explore_stride(hopper)
stride_explorer'''),
    ("md", """## One stride, and its apex return map

A stride starts at an apex `(y, z, ydot)`. The controls are the touchdown angle `th_td`
(positive: foot ahead of the body) and the leg stiffness while compressing (`kc`) and
decompressing (`kd`). We sweep the touchdown angle from one apex over flat ground at
height 0, once with `kd = kc` and once with a stiffer decompression. `jax.vmap` runs the
whole sweep as one batch."""),
    ("code", '''apex = jnp.array([0.0, 1.3, 1.0])
th = np.linspace(-0.05, 0.3, N)
kc = 20_000.0  # N/m
same = np.stack([th, np.full(N, kc), np.full(N, kc)], 1)
stiffer = np.stack([th, np.full(N, kc), np.full(N, 1.3 * kc)], 1)
stride_batch = jaxhop.jit(jax.vmap(jaxhop.slip_apex_map, (None, 0, None, None)))
next_same, code_same = stride_batch(apex, same, 0.0, hopper)
next_stiff, code_stiff = stride_batch(apex, stiffer, 0.0, hopper)

fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
for nxt, code, label in ((next_same, code_same, "kd = kc"),
                         (next_stiff, code_stiff, "kd = 1.3 kc")):
    ok = np.asarray(code) == 0
    axes[0].plot(th[ok], np.asarray(nxt)[ok, 2], "o-", ms=3, label=label)
    axes[1].plot(th[ok], np.asarray(nxt)[ok, 1], "o-", ms=3, label=label)
axes[0].set_ylabel("next apex velocity ydot (m/s)")
axes[1].set_ylabel("next apex height z (m)")
for ax in axes:
    ax.set_xlabel("touchdown angle th_td (rad)")
    ax.axvline(0.0, color="0.7", lw=0.8)
    ax.grid(alpha=0.3)
    ax.legend()
fig.suptitle("SLIP apex return map from the apex (0, 1.3 m, 1.0 m/s), kc = 20 kN/m")
fig.tight_layout()'''),
    ("md", """A steeper touchdown angle brakes the body: the next apex is slower and, with
`kd = kc`, higher, because the total energy is conserved (the stance is lossless and the
flight ballistic). A stiffer decompression (`kd > kc`) releases more energy than the
compression stored. Energy per unit mass, before and after:"""),
    ("code", '''def energy(a):
    a = np.asarray(a)
    return 0.5 * a[..., 2] ** 2 + float(hopper.g) * a[..., 1]


e0 = energy(apex)
ok = np.asarray(code_same) == 0
rel = np.abs(energy(next_same)[ok] - e0) / e0
print(f"kd = kc:     {ok.sum()} strides, largest relative energy change {rel.max():.1e}")
gain = energy(next_stiff)[np.asarray(code_stiff) == 0] - e0
print(f"kd = 1.3 kc: energy gained {gain.min():.3f} .. {gain.max():.3f} J/kg")
assert rel.max() < 1e-7 and gain.min() > 0'''),
    ("md", """## Deadbeat: choosing the controls for a target apex

The SLIP apex map has no closed form, so the deadbeat (eqs 12-16) is a search. `kd`
follows from energy (eq 12), and `(th_td, kc)` are found by Gauss-Newton with forward-mode
derivatives through the diffrax solve. We ask for `N` target apexes ahead of the same start
and check the result with the simulated stride (the batch of strides, vmapped as above)."""),
    ("code", '''s = np.linspace(0.0, 1.0, N)
targets = np.stack([0.55 + 0.35 * s, 1.25 + 0.1 * s, 0.7 + 0.6 * s], 1)
# One target at a time, with the program the explorer above compiled (a deadbeat vmapped
# over the targets is a program of its own: another 45 s of compilation).
deadbeat = jaxhop.jit(jaxhop.deadbeat_slip)
solves = [deadbeat(apex, jnp.asarray(t), 0.0, hopper) for t in targets]
u = jnp.stack([uu for uu, _ in solves])
solved = np.array([bool(ok) for _, ok in solves])
reached, code = stride_batch(apex, u, 0.0, hopper)
err = np.abs(np.asarray(reached) - targets).max(axis=1)
for t, uu, e, good in zip(targets, np.asarray(u), err, np.asarray(solved)):
    print(f"target {np.round(t, 3)}: th_td {uu[0]:+.4f} rad, kc {uu[1]:7.0f}, "
          f"kd {uu[2]:7.0f} N/m -> error {e:.1e}{'' if good else '  (limits hit)'}")
assert np.all(err[np.asarray(solved)] < 1e-3)'''),
    ("md", """## SLIP running on a BHop plan (Fig. 19)

Now the SLIP model runs on `reference` with the plan built for BHop. At every apex the
controller still picks the first deployed policy whose domain holds the measured state,
but it applies the *SLIP* deadbeat toward that policy's goal. The goals were computed for
BHop, and the SLIP deadbeat cannot always reach them (its controls are limited and its
stance moves the body along the ground). The next apex is therefore off the planned one,
and the controller simply picks again. The shaded regions are cross-sections of the
chosen policy's domain (dark red, at the apex's velocity) and feasible goal (light green,
at the goal's velocity) at each apex, as in the paper's Figs. 13 and 19."""),
    ("code", '''terrain = jaxhop.builtin_terrain("reference")
plan = jaxhop.get_plan(terrain, progress=False)
starts = np.array([[0.6, 1.6, 0.5], [3.6, 1.5, 0.5]])
paper = jaxhop.RunSettings(controller="paper")  # the paper's controller, Fig. 8
slip = jaxhop.run_batch(plan, starts, jaxhop.RunSettings(model="slip", controller="paper"),
                        key=jax.random.key(0))
bhop = jaxhop.run_batch(plan, starts, paper, key=jax.random.key(0))
slip_runs = [{k: v[i] for k, v in slip.items()} for i in range(len(starts))]
bhop_runs = [{k: v[i] for k, v in bhop.items()} for i in range(len(starts))]
fig = _plot.runs_figure(terrain, bhop_runs, plan.goal, "BHop on 'reference'", plan=plan)
fig = _plot.slip_runs_figure(plan, slip_runs)
for i in range(len(starts)):
    print(f"start {starts[i]}: BHop {jaxhop.RESULT_NAMES[bhop['code'][i]]} in "
          f"{bhop['steps'][i]} strides, SLIP {jaxhop.RESULT_NAMES[slip['code'][i]]} in "
          f"{slip['steps'][i]} strides")'''),
    ("md", """The legs drawn at touchdown and liftoff show what differs from BHop: the SLIP
foot lands ahead of the body and the body vaults over it, so the stance covers ground.
This notebook runs the plain BHop plan, *without* the SLIP adjustments of section VII-A
(eqs 35-37, which `--model slip` plans with: `docs/decisions.md`, "SLIP on BHop plans"),
so some runs fail where the paper's succeed.

## A longer terrain (Fig. 21)

The paper's last figure runs SLIP across a longer course that starts in a deep well. The
open circles are the goals of the policies chosen at each apex, each joined to the apex
the SLIP stride actually reached. (With `JAXHOP_NB_QUICK=1` this cell reuses the
`reference` run instead, to spare a second plan and a second compilation.)"""),
    ("code", '''if QUICK:
    long_plan, long_run = plan, slip_runs[1]
else:
    long_plan = jaxhop.get_plan(jaxhop.builtin_terrain("long"), progress=False)
    start = [1.65, 1.1, 0.5]  # in the deep well
    slip_paper = jaxhop.RunSettings(model="slip", controller="paper")
    r = jaxhop.run_batch(long_plan, [start], slip_paper, key=jax.random.key(0))
    long_run = {k: v[0] for k, v in r.items()}
fig = _plot.long_run_figure(long_plan, long_run, "slip")
steps = int(long_run["steps"])
gap = np.abs(long_run["apexes"][1:steps + 1] - long_plan.goals[long_run["policies"][:steps]])
print(f"{jaxhop.RESULT_NAMES[long_run['code']]} in {steps} strides; distance from the "
      f"chosen BHop goal per stride: median {np.nanmedian(gap[:, :2]):.3f} m (position), "
      f"{np.nanmedian(gap[:, 2]):.3f} m/s (velocity)")'''),
]

PARKOUR = [
    ("md", """# Parkour with MPPC (Albracht et al. 2024)

The second planner in jaxhop is a receding-horizon jump planner for a hopping leg on
parkour courses: blocks to jump on and over, floor areas where the leg must not land, and
environments that change while the robot runs. At every replan, MPPC plans a sequence of
ballistic jumps a horizon ahead (2 m) and executes only the first. The original solves a
mixed-integer program with Drake and SNOPT. jaxhop solves the same problem exactly over a
grid of landing points: all-pairs jump feasibility in JAX, then dynamic programming over
the number of jumps."""),
    ("code", '''%matplotlib inline
import os

import matplotlib.pyplot as plt
import numpy as np

from jaxhop import mppc

# CI runs the notebooks with JAXHOP_NB_QUICK=1 (a coarser landing grid).
QUICK = bool(os.environ.get("JAXHOP_NB_QUICK"))
GRID = 0.04 if QUICK else 0.02  # m
mppc.list_courses()'''),
    ("md", """## A static course

`mppc-sim-1` is one of the nine courses that ship with the package (the original's
simulation course). Blocks are grey; red strips on the floor are restricted areas."""),
    ("code", '''course = mppc.load_course("mppc-sim-1")
planner = mppc.MPPC(settings=mppc.Settings(grid=GRID))
result = mppc.run_course(course, planner)
out = result.to_json()
{k: out[k] for k in ("finished", "jumps", "flight_time", "violations", "replan_ms")}'''),
    ("code", '''fig = mppc.plot_run(course, result)
fig'''),
    ("md", """The solid blue lines are the foot paths of the executed jumps; the dashed orange
ones are the whole plan made at the first replan. Each replan looks 2 m ahead and keeps
only its first jump, so the plan made later in the run can differ from the first one.
Below we compare the plan of each replan with the jump that was then executed."""),
    ("code", '''first = [p.jumps[0] for p in result.plans]
same = all(abs(f.x1 - e.x1) < 1e-12 and abs(f.t - e.t) < 1e-12
           for f, e in zip(first, result.executed))
print(f"{len(result.plans)} replans, {len(result.executed)} executed jumps; "
      f"every executed jump is its replan's first jump: {same}")
fig, axes = plt.subplots(1, 2, figsize=(11, 3.2))
axes[0].plot([p.n_jumps for p in result.plans], "o-", ms=4)
axes[0].set_xlabel("replan")
axes[0].set_ylabel("jumps in the plan")
axes[0].set_title("Planned jumps to the horizon end")
axes[1].bar(range(len(result.executed)), [j.t for j in result.executed], color="tab:blue")
axes[1].set_xlabel("executed jump")
axes[1].set_ylabel("flight time (s)")
axes[1].set_title(f"Executed jumps: {result.flight_time:.2f} s of flight in total")
fig.tight_layout()'''),
    ("md", """## Planned and executed, replan by replan

Drawing the plan of a later replan shows the horizon moving with the robot."""),
    ("code", '''mid = len(result.plans) // 2
fig = mppc.plot_run(course, result, replan=mid)
fig'''),
    ("md", """## A changing course

On `mppc-hw-dynamic-1` the blocks move while the robot runs: each snapshot replaces the
environment from a given jump on. The planner only sees the environment in force at each
replan. The independent checker verifies every executed jump against the environment it
was made in, and counts violations."""),
    ("code", '''dyn = mppc.load_course("mppc-hw-dynamic-1")
print(f"{len(dyn.snapshots)} snapshots, from jumps {[k for k, _ in dyn.snapshots]}")
res = mppc.run_course(dyn, mppc.MPPC(settings=mppc.Settings(grid=GRID)))
ref = {r["course"]: r for r in mppc.reference_results()["results"] if r["mode"] == "as_given"}
print(f"jaxhop: finished {res.finished}, {len(res.executed)} jumps, "
      f"{res.flight_time:.3f} s flight, {len(res.violations)} violations")
print(f"original (Drake + SNOPT): finished {ref[dyn.name]['finished']}, "
      f"{ref[dyn.name]['jumps']} jumps, {ref[dyn.name]['flight_time_s']:.3f} s flight")
assert not res.violations
mppc.plot_run(dyn, res)'''),
]

MUJOCO = [
    ("md", """# Plan in jaxhop, run in MuJoCo

The plans and the reactive SLIP controller of jaxhop drive a hopper simulated by MuJoCo
(`jaxhop.mujoco`, the extra `jaxhop[mujoco]`): a body of mass `m` with its rotation
locked, a leg with 3 % of `m` on a hip hinge, a prismatic leg with a 2 % foot, contact
and friction. At every apex of the body the controller measures its state and returns the
touchdown angle and the two leg stiffnesses; the runner servoes the leg to the angle in
the descent and applies the spring force `k (rho0 - rho)` in stance (`docs/mujoco.md`)."""),
    ("code", '''import os

import jax
import numpy as np

import jaxhop
from jaxhop import mujoco as mj

# CI runs the notebooks with JAXHOP_NB_QUICK=1 (fewer runs, in this process).
QUICK = bool(os.environ.get("JAXHOP_NB_QUICK"))
terrain = jaxhop.builtin_terrain("reference")
plan = jaxhop.get_plan(terrain, templates=jaxhop.paper_templates().for_slip(),
                       progress=False)
mj.DEFAULT'''),
    ("md", """## One run

`run_recorded` runs one closed loop in this process and keeps the trajectory (every 10
ms): the body, the foot, the apexes and the footholds. The first decision compiles the
SLIP controller (about a minute on a CPU); later ones take tens of milliseconds."""),
    ("code", '''job = mj.job_for(terrain, plan, max_steps=30 if QUICK else 60)
run, trajectory = mj.run_recorded(job, np.array([0.6, 1.6, 0.5]))
print(jaxhop.Result(run["code"]).name.lower(), run["why"], "after", run["steps"], "strides")
fig = mj.trajectory_figure(terrain, run, trajectory, plan.goal)'''),
    ("md", """## The same states in both simulators

`sweep_initial(plan, SweepGrid(runs=n))` picks `n` evenly spaced states of the sweep grid in the
global domain (`jaxhop sweep --runs n` does the same). Each runs in MuJoCo (over
processes, one per core) and in jaxhop's SLIP model, with the same controller and the
same noise draws."""),
    ("code", '''states = jaxhop.sweep_initial(plan, jaxhop.SweepGrid(runs=4 if QUICK else 64))
mujoco_runs = mj.run_many(job, states, processes=1 if QUICK else None)
slip_runs = jaxhop.run_batch(plan, states, jaxhop.RunSettings(model="slip"),
                             key=jax.random.key(0))
for name, r in (("MuJoCo", mujoco_runs), ("jaxhop SLIP", slip_runs)):
    ok = r["code"] == 0
    print(f"{name:12s} success {ok.mean():.3f}, mean strides {r['steps'][ok].mean():.1f}")
both = (mujoco_runs["code"] == 0) & (slip_runs["code"] == 0)
print(f"{both.sum()} of {len(states)} states succeed in both")'''),
    ("md", """The MuJoCo hopper needs more strides than jaxhop's SLIP: its leg loses energy
at every touchdown and liftoff, which the controller does not model; it corrects the loss
at the next apex from the measured state alone."""),
]

NOTEBOOKS["03_slip"] = SLIP
NOTEBOOKS["04_parkour"] = PARKOUR
NOTEBOOKS["06_mujoco"] = MUJOCO


def build(out: pathlib.Path = HERE):
    for name, cells in NOTEBOOKS.items():
        nb = new_notebook(cells=[new_markdown_cell(src) if kind == "md" else
                                 new_code_cell(src) for kind, src in cells])
        for i, cell in enumerate(nb.cells):  # stable ids: regenerating changes no line
            cell.id = hashlib.sha1(f"{name}/{i}".encode()).hexdigest()[:8]
        nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                     "language": "python"}
        nbformat.write(nb, pathlib.Path(out) / f"{name}.ipynb")


if __name__ == "__main__":
    build()
