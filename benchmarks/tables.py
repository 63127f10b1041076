"""Markdown tables of the benchmark results in `benchmarks/results/`.

    python benchmarks/tables.py            # print the tables
    python benchmarks/tables.py --write    # put them into their pages

Two pages hold the tables: `benchmarks/README.md` (speed, robustness on `reference`, GPUs,
goals, explorers) and `benchmarks/parkour.md` (the parkour courses). `--write` replaces what
lies between the markers `<!-- tables:start -->` and `<!-- tables:end -->` of each, so
every number in those tables is written in one place, its results file. Formats: times to
three significant digits (microseconds or milliseconds below 10 ms), ratios truncated to
0.1 (never rounded up), success rates to four decimals for sweeps and two for the parkour
courses' 12 runs.

Uses the standard library only.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import re
import sys

HERE = pathlib.Path(__file__).resolve().parent
RESULTS = HERE / "results"
README = HERE / "README.md"
PARKOUR = HERE / "parkour.md"
START, END = "<!-- tables:start -->", "<!-- tables:end -->"

COURSES = ["mppc-hw-disturbances", "mppc-hw-dynamic-1", "mppc-hw-dynamic-2",
           "mppc-hw-dynamic-3", "mppc-hw-dynamic-4", "mppc-sim-1", "mppc-hw-static",
           "mppc-sim-2", "mppc-hw-two-rounds"]
NOISES = ["none", "wind", "sensor", "landing"]

# Conditions of a run that its results file does not record (the file's own fields win).
CONDITIONS = {
    "cpu2-bench-2026-11.json": "jax 0.10.2, nothing else running",
}


def load(name: str) -> dict:
    with open(RESULTS / name) as f:
        return json.load(f)


def sig3(x: float) -> str:
    """`x` to three significant digits, without exponent."""
    if x == 0:
        return "0"
    digits = max(0, 2 - int(math.floor(math.log10(abs(x)))))
    return f"{x:,.{digits}f}".replace(",", " ")


def seconds(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if x < 1e-4:
        return f"{x * 1e6:.0f} µs"
    if x < 1e-2:
        return f"{sig3(x * 1e3)} ms"
    return sig3(x)


def ratio(x: float) -> str:
    return f"{math.floor(x * 10 + 1e-9) / 10:.1f}×"


def rate(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}f}"


def failures(counts: dict | None) -> str:
    parts = [f"`{k}` {v}" for k, v in (counts or {}).items() if v]
    return ", ".join(parts) if parts else "none"


def span(values, fmt) -> str:
    lo, hi = min(values), max(values)
    return fmt(lo) if fmt(lo) == fmt(hi) else f"{fmt(lo)}-{fmt(hi)}"


def load_average(text: str) -> str:
    found = re.search(r"load average [0-9.]+", text or "")
    return found.group(0) if found else "load not recorded"


def load_of(meta: dict) -> str:
    return f"load average {meta['load']}" if "load" in meta else "load not recorded"


def table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


def twin() -> list[str]:
    # Later files measure the current code; a benchmark they repeat shows only their row.
    files = ["cpu2-bench-2026-11.json", "cpu2-bench-slip-table-2026-11.json",
             "cpu2-bench-twin-2026-11.json", "cpu2-bench-plan-2026-12.json"]
    data = [load(name) for name in files]
    out = ["### JAX against the NumPy twin (`run.py`)"]
    rows = []
    for i, (name, d) in enumerate(zip(files, data), 1):
        jax = f"jax {d['jax_version']}" if "jax_version" in d else CONDITIONS[name]
        conditions = f", {d['conditions']}" if "conditions" in d else ""
        out.append(f"{i}. `results/{name}`: {d['device']}, {jax}{conditions}, "
                   f"{'subsampled twin' if d['quick'] else 'full sizes'}.")
        later = {b["name"] for e in data[i:] for b in e["benchmarks"]}
        for b in d["benchmarks"]:
            if b["name"] in later:
                continue
            twin_s = b["numpy_s"]
            has_twin = not math.isnan(twin_s)
            rows.append([f"`{b['name']}`", b["size"], seconds(b["jax_s"]), seconds(twin_s),
                         f"**{ratio(b['speedup'])}**" if has_twin else "-",
                         sig3(b["compile_s"]) if b["compile_s"] else "in the JAX time",
                         str(i)])
    out.append("")
    out += table(["name", "size", "JAX (s)", "twin (s)", "speedup", "JAX compile (s)",
                  "file"], rows)
    k, prof = next((k, d["profile"]) for k, d in reversed(list(enumerate(data, 1)))
                   if "jax_plan_stage_s" in d.get("profile", {}))
    stages = "; ".join(
        f"{who} " + ", ".join(f"{n.replace('_', ' ')} {v:.2f}" for n, v in prof[key].items())
        for who, key in (("JAX", "jax_plan_stage_s"), ("twin", "numpy_plan_stage_s")))
    return out + ["", f"`plan_build` by stage, warm (s, file {k}): {stages}."]


def robustness_bhop() -> list[str]:
    name = "cpu2-robustness-bhop-2026-11.json"
    data = load(name)
    meta = data["meta"]
    runs = data["runs"]
    noises = list(dict.fromkeys(r["noise"] for r in runs))
    rows = []
    for noise in noises:
        ada = sorted((r for r in runs if r["noise"] == noise and r["controller"] == "adaptive"),
                     key=lambda r: r["seed"])
        pap = sorted((r for r in runs if r["noise"] == noise and r["controller"] == "paper"),
                     key=lambda r: r["seed"])
        rows.append([f"`{noise}`", " / ".join(str(r["n_initial_conditions"]) for r in ada),
                     " / ".join(f"**{rate(r['success_rate'])}**" for r in ada),
                     span([r["mean_steps"] for r in ada], lambda x: f"{x:.1f}"),
                     " / ".join(str(r["recoveries"]["total"]) for r in ada),
                     " / ".join(rate(r["success_rate"]) for r in pap)])
    return [f"### Robustness, BHop (`robustness.py`, `results/{name}`)",
            f"`reference`, {meta['device']}, jax {meta['jax']}, {load_of(meta)}, grid "
            f"{meta['grid_step']} m, default tolerance; seeds 0 / 1 / 2.", ""] + table(
        ["noise", "initial apexes", "adaptive: success", "strides (mean)",
         "recovered strides", "paper's controller: success"], rows)


def robustness_slip() -> list[str]:
    name = "cpu2-robustness-slip-2026-12.json"
    data = load(name)
    meta = data["meta"]
    runs = [r for r in data["runs"] if r.get("grid_step") == 0.2]

    def pick(noise, controller, domain):
        return sorted((r for r in runs if r["noise"] == noise and r["controller"] == controller
                       and r["domain"] == domain), key=lambda r: r["seed"])

    def cell(rs):
        if not rs:
            return "-"
        if len(rs) == 1:
            r = rs[0]
            n = f"{r['n_initial_conditions']} apexes, " if "n_initial_conditions" in r else ""
            return f"{rate(r['success_rate'])} ({n}{failures(r.get('failures'))})"
        mean = sum(r["success_rate"] for r in rs) / len(rs)
        per = ", ".join(rate(r["success_rate"]) for r in rs)
        n = [r["n_initial_conditions"] for r in rs if "n_initial_conditions" in r]
        apexes = f", {min(n)}-{max(n)} apexes" if n else ""
        return f"mean **{rate(mean)}**; seeds {rs[0]['seed']}-{rs[-1]['seed']}: {per}{apexes}"

    rows = [[f"`{noise}`", cell(pick(noise, "adaptive", "verified")),
             cell(pick(noise, "paper", "verified")), cell(pick(noise, "paper", "plan"))]
            for noise in ("none", "wind", "ground")]
    return [f"### Robustness, SLIP on a 0.2 m grid (`results/{name}`)",
            f"`reference`, {meta['device']}, jax {meta['jax']}, {load_of(meta)}, the "
            "command line's SLIP controller and plan (table-start deadbeat, direction rule); "
            "seed 0 unless listed; `ground` with the same initial apexes for both "
            "controllers in the SLIP domain. Full-grid SLIP sweeps: `docs/results.md`.",
            ""] + table(
        ["noise", "adaptive, SLIP domain", "paper's controller, SLIP domain",
         "paper's controller, global domain"], rows)


def parkour_bhop() -> list[str]:
    ctl = load("cpu2-parkour-controllers-2026-11.json")
    obs = load("cpu2-parkour-mppc-observer-2026-11.json")

    def row_of(rows, course, noise, **match):
        for r in rows:
            if r["course"] == course and r["noise"] == noise and all(
                    r.get(k) == v for k, v in match.items()):
                return r
        raise KeyError((course, noise, match))

    cols = {"adaptive": (ctl["rows"], {"controller": "adaptive"}),
            "paper": (ctl["rows"], {"controller": "paper"}),
            "mppc": (obs["rows"], {"planner": "mppc"})}
    table_rows, sums = [], {(n, c): 0.0 for n in NOISES for c in cols}
    for course in COURSES:
        cells = []
        for noise in NOISES:
            parts = []
            for c, (rows, match) in cols.items():
                s = row_of(rows, course, noise, **match)["success_rate"]
                sums[noise, c] += s / len(COURSES)
                parts.append(rate(s, 2))
            cells.append(" / ".join(parts))
        table_rows.append([course] + cells)
    table_rows.append(["**mean of the nine**"] + [
        f"**{rate(sums[n, 'adaptive'], 2)}** / {rate(sums[n, 'paper'], 2)} / "
        f"{rate(sums[n, 'mppc'], 2)}" for n in NOISES])

    def medians(rows, **match):
        return [r.get("replan_ms_median") or r["replan_ms"]["median"] for r in rows
                if all(r.get(k) == v for k, v in match.items())]

    ms = lambda x: f"{x:.3g}"  # noqa: E731
    return ["### Reactive BHop against MPPC on the parkour courses (`parkour_compare.py`)",
            "Success, *adaptive / paper's controller / MPPC with its observer*. Reactive: "
            "`results/cpu2-parkour-controllers-2026-11.json`, 12 seeded runs per cell, "
            f"{ctl['device']} (the adaptive sensor column: "
            f"{load_average(ctl['note_sensor'])} at the start). MPPC: "
            f"`results/cpu2-parkour-mppc-observer-2026-11.json`, {obs['device']}; 12 seeded "
            "runs per disturbed cell, 1 deterministic run without disturbance.", ""] + table(
        ["course"] + NOISES, table_rows) + [
        "", "Median per cell: reactive decision "
        f"{span(medians(ctl['rows'], controller='adaptive'), ms)} ms (adaptive), "
        f"{span(medians(ctl['rows'], controller='paper'), ms)} ms (paper's); MPPC replan "
        f"{span(medians(obs['rows']), ms)} ms."]


def parkour_slip() -> list[str]:
    name = "cpu2-parkour-slip-leg-2026-11.json"
    data = load(name)
    rows, sums = [], dict.fromkeys(NOISES, 0.0)
    for course in COURSES:
        by = {r["noise"]: r for r in data["rows"] if r["course"] == course}
        for n in NOISES:
            sums[n] += by[n]["success_rate"] / len(COURSES)
        nom = by["none"]
        rows.append([course, rate(nom["success_rate"], 2), f"{nom['mean_jumps']:.1f}",
                     f"{nom['replan_ms']['median']:.2f}",
                     f"{nom['recoveries']['mean']:.2f}"] + [
            f"{rate(by[n]['success_rate'], 2)} ({failures(by[n]['failures'])}; "
            f"{by[n]['replan_ms']['median']:.2f} ms)" for n in NOISES[1:]])
    rows.append(["**mean of the nine**"] + [f"**{rate(sums['none'], 2)}**", "", "", ""]
                + [f"**{rate(sums[n], 2)}**" for n in NOISES[1:]])
    eq35 = load("cpu2-parkour-slip-leg-eq35-2026-11.json")["rows"]
    means = ", ".join(
        f"{n} {rate(sum(r['success_rate'] for r in eq35 if r['noise'] == n) / len(COURSES), 2)}"
        for n in NOISES)
    multi = load("cpu2-parkour-slip-2026-11.json")["rows"]
    won = round(sum(r["success_rate"] * r["runs"] for r in multi))
    return ["### SLIP on the parkour courses (`parkour_compare.py --models slip`)",
            f"`results/{name}`: the leg's SLIP templates, a full build at every snapshot, the "
            "table-start deadbeat, decisions' trial strides at rtol = atol = 1e-5, the adaptive "
            "controller with the apex filter alone (no descent measurement, no capture "
            f"strides), 12 seeded runs per cell; {data['device']}. Without disturbance: "
            "success, strides (mean of finished runs), decision ms (median), recoveries "
            "(mean per run); disturbed cells: success (failures; decision median).", ""] + table(
        ["course", "success", "strides", "decision ms", "recoveries"] + NOISES[1:], rows) + [
        "", "Mean success of the same runs on plans without the direction rule "
        f"(`SlipAdjust(keep_direction=False)`, `results/cpu2-parkour-slip-leg-eq35-2026-11.json`): "
        f"{means}. On the BHop plan without the SLIP adjustments, with the multi-start "
        "deadbeat and the paper's controller (`results/cpu2-parkour-slip-2026-11.json`): "
        f"{won} of {sum(r['runs'] for r in multi)} runs reach the goal."]


def parkour_slip_now() -> list[str]:
    name = "cpu2-parkour-slip-leg-2026-12.json"
    data = load(name)
    by = {(r["course"], r["noise"]): r for r in data["rows"]}

    def cell(r):
        strides = f"; {r['mean_jumps']:.1f} strides" if r["mean_jumps"] else ""
        return f"{rate(r['success_rate'], 2)} ({failures(r['failures'])}{strides})"

    rows = [[course] + [cell(by[course, n]) for n in NOISES] for course in COURSES]
    rows.append(["**mean of the nine**"] + [
        f"**{rate(sum(by[c, n]['success_rate'] for c in COURSES) / len(COURSES), 2)}**"
        for n in NOISES])
    return ["### SLIP on the parkour courses, the controller as it is",
            f"`results/{name}`: `{data['command']}`, {data['controller']}; "
            f"{data['device']}; {data['recorded']}. Success (failures; strides, mean of the "
            "finished runs).",
            ""] + table(["course"] + NOISES, rows)


def updates() -> list[str]:
    name = "cpu2-parkour-update-2026-12.json"
    data = load(name)
    rows, all_upd, all_cpu, equal = [], [], [], []
    wall_r, cpu_r, est_wall, est_cpu = [], [], [], []
    for c in data["courses"]:
        all_upd += c["update_s"]
        all_cpu += c["update_cpu_s"]
        for j, snap in enumerate(c["rebuilt"]):
            k = snap - 1
            equal.append(c["rebuild_equal"][j])
            wall_r.append(c["ratio"][j])
            cpu_r.append(c["ratio_cpu"][j])
            rows.append([c["course"], snap,
                         f"{c['update_s'][k]:.2f} / {c['update_cpu_s'][k]:.2f}",
                         f"{c['rebuild_s'][j]:.1f} / {c['rebuild_cpu_s'][j]:.1f}",
                         f"{ratio(c['ratio'][j])} / **{ratio(c['ratio_cpu'][j])}**",
                         "yes" if c["rebuild_equal"][j] else "**no**",
                         f"{c['recomputed_pairs'][k]:,}".replace(",", " "),
                         c["new_situated"][k],
                         f"{c['recomputed_robustness'][k]:,} ({c['recomputed_probes'][k]:,})"
                         .replace(",", " ")])
        rest = [k for k in range(len(c["update_s"])) if k + 1 not in c["rebuilt"]]
        if rest:
            est_wall.append(min(c["rebuild_s"]) / max(c["update_s"][k] for k in rest))
            est_cpu.append(min(c["rebuild_cpu_s"]) / max(c["update_cpu_s"][k] for k in rest))
    n_snap = sum(c["n_snapshots"] for c in data["courses"])
    ten = sum(r >= 10 for r in wall_r)
    return ["### Incremental updates against full rebuilds (`parkour_compare.py --timing`)",
            f"`results/{name}`: {data['device']}, the leg's "
            f"{ {'bhop': 'BHop', 'slip': 'SLIP'}[data.get('model', 'bhop')]} "
            "templates, lattice segments. An update is the median "
            "of three passes over the course's update chain, a rebuild one full build, "
            "compilation untimed; the two slowest updates (CPU) of each course rebuilt and "
            "compared bit for bit.", ""] + table(
        ["course", "snapshot", "update wall / CPU s", "rebuild wall / CPU s",
         "ratio wall / CPU", "identical", "recomputed pairs", "new situated",
         "recomputed robustness (probes)"], rows) + [
        "", f"{sum(equal)} of {len(equal)} rebuilds identical; ratios {span(cpu_r, ratio)} by "
        f"CPU time, {span(wall_r, ratio)} by wall time ({ten} of {len(wall_r)} at 10× or "
        f"more). Over all {n_snap} snapshots updates take {span(all_upd, lambda x: f'{x:.2f}')}"
        f" s wall ({span(all_cpu, lambda x: f'{x:.2f}')} s CPU). Estimate for the snapshots "
        f"not rebuilt (the course's fastest rebuild over its slowest other update): "
        f"{span(est_wall, ratio)} wall, {span(est_cpu, ratio)} CPU."]


def gpu() -> list[str]:
    h100 = load("h100-slip-sweep-2026-11.json")
    runs = h100["runs"]
    first = [r for r in runs if r["process"].startswith("first")]
    warm = [r for r in runs if not r["process"].startswith("first")]

    def timed(r):
        wall = f" ({r['wall_s']:.1f} wall)" if "wall_s" in r else ""
        return f"{r['sweep_s']:.1f}{wall}"

    s = h100["summary"]
    same = h100["same_json_second_and_third"] and h100["same_json_as_cpu2"]
    name = "h200-gpu-2026-11.json"
    bench = load(name)
    rows = [["plan build, BHop, `reference`", seconds(bench["plan_build_s"]["gpu"][1]),
             seconds(bench["plan_build_s"]["cpu2"][1]),
             ratio(bench["plan_build_s"]["cpu2"][1] / bench["plan_build_s"]["gpu"][1]),
             f"{bench['plan_build_s']['gpu'][0]:.1f} / {bench['plan_build_s']['cpu2'][0]:.1f}",
             ""]]
    for model, label in (("bhop", "BHop sweep"), ("slip", "SLIP model on the BHop plan")):
        m = bench["sweeps"][model]
        rows.append([f"{label} ({m['summary_gpu']['n_initial_conditions']} runs, success "
                     f"{rate(m['summary_gpu']['success_rate'])})",
                     seconds(m["gpu"]["warm_s"]), seconds(m["cpu2"]["warm_s"]),
                     ratio(m["speedup_warm"]),
                     f"{m['gpu']['cold_s']:.1f} / {m['cpu2']['cold_s']:.1f}",
                     "yes" if m["same_outcomes"] else "no"])
    return (["### GPUs",
             f"`gpu.sh` (`results/{name}`): one {bench['device']} against 2 cores of the same "
             f"machine's CPU, in one run, jax {bench['host']['jax']}; first calls compile "
             f"(256 runs for a sweep). {bench['plans']}."]
            + [""] + table(["", "GPU warm (s)", "2 CPU cores warm (s)", "ratio", "first call (s)",
                            "same outcomes"], rows)
            + ["", f"The reference SLIP sweep, `{h100['command']}`, on one {h100['device']} "
               f"(`results/h100-slip-sweep-2026-11.json`; {h100['software']}), trial strides at "
               f"rtol = atol = 1e-8, a fresh process each: first process "
               + "; ".join(f"{r['n']} runs: {timed(r)} s" for r in first)
               + ", warm " + ", ".join(f"{timed(r)} s" for r in warm)
               + f". {s['n_initial_conditions']} runs, success {rate(s['success_rate'])}"
               + ("; the warm runs' JSON equal each other's and the 2-core CPU's."
                  if same else "; the JSON differs between runs.")])


def goals() -> list[str]:
    name = "cpu2-goals-anywhere-2026-11.json"
    data = load(name)
    s, rows = data["summary"], data["rows"]
    planned = [r for r in rows if r["outcome"] == "planned"]
    refused = [r for r in rows if r["outcome"] == "refused"]
    boundary = [r["n_goal_policies"] for r in planned if r["where"] == "boundary"]
    apexes = [r["n_initial"] for r in planned]
    return ["### Goals anywhere (`goals_anywhere.py`)",
            f"`results/{name}`: {s['n_terrains']} seeded `random_terrain` maps of "
            f"{s['length']:g} m, jax {s['jax']}, nominal sweeps on a {s['dy']:g} m grid. "
            f"{s['planned']} planned, every one with success "
            f"{span([r['success_rate'] for r in planned], rate)} "
            f"({min(apexes)}-{max(apexes)} initial apexes each); goals on a segment boundary "
            f"have {span(boundary, str)} goal policies. {s['refused']} refused: "
            + "; ".join(f"\"{r['reason']}\"" for r in refused) + "."]


def floor_ms(x: float) -> str:
    """Milliseconds to 0.1, truncated (never rounded up)."""
    return f"{math.floor(x * 1e4 + 1e-9) / 10:.1f} ms"


def loads(triple) -> str:
    return ", ".join(f"{x:.2f}" for x in triple)


def explorers() -> list[str]:
    name = "cpu2-explore-2026-11.json"
    d = load(name)
    rows = []
    for key, what in (("bhop_run", "BHop run (`explore`: apex; disturbance, seed, controller)"),
                      ("policy", "policy picker (`explore`)"),
                      ("slip_stride", "SLIP stride (`explore_stride`: `th_td`)"),
                      ("slip_deadbeat", "SLIP deadbeat (`explore_stride`: target, button)")):
        r = d["redraw"][key]
        rows.append([what, r["n"], floor_ms(r["min_s"]), floor_ms(r["median_s"]),
                     f"**{floor_ms(r['max_s'])}**", floor_ms(r["bound_s"])])
    b, s, errors = d["build_s"], d["bhop_run_strides"], d["deadbeat_errors"]
    return ["### Notebook explorers (`explore.py`)",
            f"`results/{name}`: {d['device']}, jax {d['jax']}, "
            f"load average {loads(d['load_before'])} before and {loads(d['load_after'])} "
            f"after (1, 5 and 15 min, `uptime`), the "
            f"`{d['plan']}` plan. A redraw: from the widget change to the new PNG, computation "
            f"included, warm. Build (compilation included, an empty compilation cache): "
            f"`explore` {sig3(b['explore'])} s, `explore_stride` {sig3(b['explore_stride'])} "
            f"s; traces and compilations over all changes: "
            f"{d['traces_and_compiles']['on_changes']}.", ""] + table(
        ["redraw", "changes", "min", "median", "max", "bound"], rows) + [
        "", f"The BHop runs took {s['min']}-{s['max']} strides. The deadbeat's targets are "
        f"random (seed 0); its controls were within the limits for "
        f"{d['deadbeat_within_limits']} of {len(errors)}, and the next apex lay within 1 mm "
        f"of the target for {sum(e < 1e-3 for e in errors)} (largest error "
        f"{max(errors):.1e})."]


PAGES = {README: [twin, robustness_bhop, robustness_slip, gpu, goals, explorers],
         PARKOUR: [parkour_bhop, parkour_slip, parkour_slip_now, updates]}


def render(sections) -> str:
    lines = ["<!-- Generated by `python benchmarks/tables.py --write`; edit that script or "
             "the results files, not this part. -->"]
    for section in sections:
        lines += [""] + section()
    return "\n".join(lines) + "\n"


def write(text: str, path: pathlib.Path) -> None:
    doc = path.read_text()
    if doc.count(START) != 1 or doc.count(END) != 1 or doc.index(START) > doc.index(END):
        raise SystemExit(f"{path}: needs one {START} followed by one {END}")
    head, rest = doc.split(START)
    tail = rest.split(END)[1]
    path.write_text(f"{head}{START}\n{text}{END}{tail}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true",
                        help=f"replace the tables between the markers of {README.name} and "
                             f"{PARKOUR.name}")
    args = parser.parse_args(argv)
    for path, sections in PAGES.items():
        text = render(sections)
        if args.write:
            write(text, path)
        else:
            sys.stdout.write(f"<!-- {path.name} -->\n{text}")


if __name__ == "__main__":
    main()
