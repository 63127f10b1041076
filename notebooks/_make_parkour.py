"""Write notebooks/05_parkour_compare.ipynb (without outputs) from the cells below.

Run `python notebooks/_make_parkour.py` after editing. With `JAXHOP_NB_QUICK=1` the
notebook uses a short course and a coarse intersection grid.
"""

import pathlib

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = pathlib.Path(__file__).parent
NAME = "05_parkour_compare"

CELLS = [
    ("md", """# The 2012 reactive planner on MPPC parkour courses

Arslan & Saranli's reactive planner (2012) was built for a fixed terrain. MPPC (Albracht
et al. 2024) replans a jump sequence after every jump on a changing course, without a
formal domain of attraction. This notebook brings the reactive planner onto the MPPC
courses (`docs/parkour_reactive.md`):

1. a course becomes a terrain with forbidden floor (restricted areas, edge margins);
2. the templates are scaled (Froude) from the 80 kg, 1 m hopper to the MPPC leg;
3. after a snapshot the plan is updated incrementally, and checked against a rebuild;
4. both planners run the course with and without disturbances."""),
    ("code", '''import os
import time

import jax
import matplotlib.pyplot as plt
import numpy as np

import jaxhop
from jaxhop import PairGrid, dimensionless_templates, paper_templates, scaled_templates
from jaxhop.mppc import course_from_dict, load_course
from jaxhop.parkour import build_course_plan, course_map, leg_hopper, leg_templates
from jaxhop.parkour import (COURSE_GRID, course_plans, initial_states, pad_plans,
                            run_mppc_noisy, run_reactive, same_deployment)

# CI runs the notebooks with JAXHOP_NB_QUICK=1: a short course and a coarse grid.
QUICK = bool(os.environ.get("JAXHOP_NB_QUICK"))
SHORT = {
    "name": "short", "start": 0.0, "goal": 1.6,
    "margins": {"horizontal": 0.03, "vertical": 0.05},
    "obstacles": [{"position": 0.9, "width": 0.12, "height": 0.1}],
    "restricted": [{"position": 1.2, "width": 0.2}],
    "snapshots": [{"from_jump": 2,
                   "obstacles": [{"position": 0.9, "width": 0.12, "height": 0.1},
                                 {"position": 0.45, "width": 0.1, "height": 0.08}],
                   "restricted": [{"position": 1.2, "width": 0.2}]}],
}
course = course_from_dict(SHORT) if QUICK else load_course("mppc-hw-dynamic-1")
GRID = PairGrid(4, 4) if QUICK else COURSE_GRID
RUNS = 8 if QUICK else 32
course.name, len(course.snapshots)'''),
    ("md", """## Course to terrain

Obstacles become blocks. The floor is cut at every obstacle edge, edge +- `Mh` and
restricted-area boundary (and on an absolute lattice), so each block is landable or
forbidden: restricted areas (red) and the `Mh` bands next to edges (orange) carry no
policy, and a touchdown there is the failure `restricted` / `margin`. In the planner's map
the bands on obstacle tops are raised by `Mv` (dashed), so its collision-free regions keep
the foot `Mv` above the edges."""),
    ("code", '''hop = leg_hopper()
cmap = course_map(course, hopper=hop)
fig, ax = plt.subplots(figsize=(10, 2.5))
colors = {0: "0.6", 7: "tab:red", 8: "tab:orange"}
for (s, e, h), hp, k in zip(cmap.true.blocks(), np.asarray(cmap.plan.heights), cmap.kind):
    ax.fill_between([s, e], -0.02, h, color=colors[int(k)], lw=0)
    if hp != h:
        ax.plot([s, e], [hp, hp], "k--", lw=0.8)
ax.plot(cmap.goal[0], cmap.goal[1], "g*", ms=12)
ax.set(xlabel="y (m)", ylabel="z (m)", title=f"{course.name}: blocks and forbidden floor")
ax.set_aspect("equal")'''),
    ("md", """## Size-independent templates

In Froude units (velocities over `sqrt(g rho0)`, energies over `m g rho0`, lengths over
`rho0`) the paper's 20 templates are the same for any hopper. `scaled_templates(hopper)`
multiplies the paper's values by the ratio of the two hoppers' scales, which is exactly 1
for the 80 kg, 1 m hopper: its plan is the paper's, bit for bit (tested). The MPPC leg
(`rho0 = rt = 0.19 m`, `g = 8.0665`) gets an extra energy band: it can jump higher,
relative to its leg, than the paper's hopper."""),
    ("code", '''assert np.array_equal(scaled_templates(jaxhop.Hopper()).as_array(),
                      paper_templates().as_array())
tm = leg_templates(hop)
print("dimensionless (v_lo, v_hi, e_lo, e_hi) of the first paper templates:")
print(np.round(dimensionless_templates()[:5, :4], 3))
print(f"leg: {tm.n} templates, segment {tm.seg_length * 100:.2f} cm, "
      f"top energy {float(tm.e_hi.max()):.2f} J/kg")'''),
    ("md", """## Plan, snapshot, incremental update

The first environment's plan is built in full; each snapshot updates only the pairs,
prepares rows and robustness scores whose dependency range meets a changed block, then
redeploys. A full rebuild of the same snapshot gives the same deployment."""),
    ("code", '''t0 = time.perf_counter()
cps = course_plans(course, hop, tm, grid=GRID, rebuild=1)
print(f"total {time.perf_counter() - t0:.1f} s; full build {cps.build_s:.1f} s")
print("updates (s):", np.round(cps.update_s, 2))
print("rebuild of the first snapshot (s):", np.round(cps.rebuild_s, 2),
      "same deployment:", cps.rebuild_equal)
print("policies per environment:", [cp.stats["n_instantiated"] for cp in cps.plans])'''),
    ("md", """## Runs: reactive (BHop) and MPPC, with and without disturbances

Reactive runs start from seeded apexes near the start that the plan covers. Disturbances
are Froude-scaled from the 2012 paper's (wind, sensor noise) plus a landing-position
noise; MPPC gets the same ones (`docs/parkour_reactive.md`)."""),
    ("code", '''padded = pad_plans(cps)
apex0, coverage = initial_states(cps, padded, RUNS, 0, hop)
rows = []
for noise in ("none", "wind", "sensor", "landing"):
    res = run_reactive(cps, padded, apex0, hopper=hop, noise=noise, seed=1, controller="paper")
    ok = res["code"] == 0
    mppc = [run_mppc_noisy(course, noise, s) for s in ([0] if noise == "none" else range(4))]
    rows.append((noise, ok.mean(), res["steps"][ok].mean() if ok.any() else float("nan"),
                 np.mean([m["success"] for m in mppc]),
                 np.mean([m["jumps"] for m in mppc])))
print(f"coverage of the start box: {coverage:.2f}")
print("noise     reactive success  strides | mppc success  jumps")
for r in rows:
    print(f"{r[0]:8s}  {r[1]:16.2f}  {r[2]:7.1f} | {r[3]:12.2f}  {r[4]:5.1f}")'''),
    ("code", '''res = run_reactive(cps, padded, apex0[:1], hopper=hop, controller="paper")
m = run_mppc_noisy(course, "none")
fig, ax = plt.subplots(figsize=(10, 2.5))
for (s, e, h), k in zip(cmap.true.blocks(), cmap.kind):
    ax.fill_between([s, e], -0.02, h, color=colors[int(k)], lw=0)
ap = res["apexes"][0]
ax.plot(ap[:, 0], ap[:, 1], "b.-", lw=0.8, label="reactive: apexes")
ax.plot(res["footholds"][0][:, 0], res["footholds"][0][:, 1], "bv", ms=4)
ax.plot([j["x1"] for j in m["executed"]], [j["z1"] for j in m["executed"]], "m^",
        label="MPPC: landings")
ax.legend(loc="upper right")
ax.set(xlabel="y (m)", ylabel="z (m)")'''),
    ("md", """## Measured on all nine courses

`benchmarks/parkour_compare.py` runs every course, 12 seeded runs per cell; its results
are stored in `benchmarks/results/` (the device and load are named in each file, timings
in `benchmarks/parkour.md`). Reactive BHop with the adaptive controller and with the
paper's, reactive SLIP on the leg's SLIP templates (adaptive), and MPPC with its
observer; the success rate per course and disturbance:"""),
    ("code", '''import json
import pathlib

RESULTS = pathlib.Path("..") / "benchmarks" / "results"
files = ["cpu2-parkour-controllers-2026-11.json", "cpu2-parkour-slip-leg-2026-11.json",
         "cpu2-parkour-mppc-observer-2026-11.json"]
success = {}
for name in files:
    for r in json.loads((RESULTS / name).read_text())["rows"]:
        model = {"bhop": "BHop", "slip": "SLIP"}.get(r["model"], r["model"])
        who = "MPPC" if r["planner"] == "mppc" else f"{model} {r['controller']}"
        success[(who, r["noise"], r["course"])] = r["success_rate"]
planners = ["BHop adaptive", "BHop paper", "SLIP adaptive", "MPPC"]
noises = ["none", "wind", "sensor", "landing"]
courses = sorted({c for _, _, c in success})
head = f"mean of the {len(courses)} courses"
print(f"{head:22s}" + "".join(f"{n:>9s}" for n in noises))
for who in planners:
    means = [np.mean([success[(who, n, c)] for c in courses]) if all(
        (who, n, c) in success for c in courses) else np.nan for n in noises]
    print(f"{who:22s}" + "".join(f"{m:9.2f}" if np.isfinite(m) else f"{'-':>9s}" for m in means))

fig, axes = plt.subplots(1, len(noises), figsize=(13, 3.6), sharey=True)
for ax, n in zip(axes, noises):
    for i, who in enumerate(planners):
        vals = [success.get((who, n, c), np.nan) for c in courses]
        ax.bar(np.arange(len(courses)) + 0.2 * (i - 1.5), vals, 0.2,
               label=who if n == noises[0] else None)
    ax.set(title=n, xticks=range(len(courses)), ylim=(0, 1.05))
    ax.set_xticklabels([c.replace("mppc-", "") for c in courses], rotation=70, fontsize=7)
axes[0].set_ylabel("success")
fig.legend(loc="upper center", ncol=len(planners), fontsize=8)
fig.tight_layout(rect=(0, 0, 1, 0.9))'''),
    ("md", """A dash: a cell not measured on every course. Reading the table and the causes
of each failure: `benchmarks/parkour.md` and `docs/parkour_reactive.md`."""),
]


def build() -> nbformat.NotebookNode:
    nb = new_notebook()
    nb.cells = [new_markdown_cell(src) if kind == "md" else new_code_cell(src)
                for kind, src in CELLS]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    return nb


def main():
    path = HERE / f"{NAME}.ipynb"
    nbformat.write(build(), path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
