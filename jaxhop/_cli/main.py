"""The `jaxhop` command line: `plan`, `sweep`, `run`, `step`, `demo` and `parkour`.

Options and outputs are described in `docs/` (README "Command line"); argument checks live
in `jaxhop._cli.args`.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys

from .._core.errors import InputError
from . import args as A


def _common(p, model=True, noise=False, models=("bhop",)):
    p.add_argument("--terrain", default="reference", help="built-in name or JSON file")
    p.add_argument("--goal", default=None, type=A.GOAL,
                   help="global goal y,z,ydot (default: the terrain's)")
    p.add_argument("--json", default=None, metavar="PATH", help="write the result as JSON")
    p.add_argument("--no-cache", action="store_true", help="rebuild the plan, do not cache")
    p.add_argument("--pickbest", default="robust", choices=("robust", "depth", "safety"),
                   help="deployment priority")
    if model:
        p.add_argument("--model", default=None, choices=models,
                       help="slip: the SLIP model on the BHop plan with the SLIP adjustments "
                       "(eqs 35-37); default bhop (slip with --sim mujoco)")
    if noise:
        p.add_argument("--noise", default="none", type=A.NOISE,
                       help="none, wind, sensor or ground, or several joined by '+' "
                       "(wind+sensor+ground)")
        p.add_argument("--seed", default="0", type=A.SEED, help="seed of every random draw")
        p.add_argument("--max-steps", default="60", type=A.MAX_STEPS_ARG)
        p.add_argument("--tolerance", default="0.05,0.05,0.05", type=A.TOLERANCE,
                       help="goal tolerance per axis y,z,ydot")
        p.add_argument("--controller", default="adaptive", choices=("paper", "adaptive"),
                       help="paper: the paper's controller; adaptive: wind observer, "
                       "wind-aware deadbeat, recovery outside the domains (docs/decisions.md)")
        p.add_argument("--sim", default="jaxhop", choices=("jaxhop", "mujoco"),
                       help="mujoco: the runs in the MuJoCo hopper (the extra jaxhop[mujoco], "
                       "SLIP controller, docs/mujoco.md); jaxhop: jaxhop's own model")


def build_parser() -> argparse.ArgumentParser:
    parser = A.Parser(prog="jaxhop", description="Reactive footstep planning for hopping on "
                     "rough terrain (Arslan & Saranli 2012) and MPPC parkour, in JAX.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=A.Parser)
    p = sub.add_parser("plan", help="build (or load) the plan and report its size")
    _common(p, models=("bhop", "slip"))
    p.set_defaults(func=cmd_plan)
    p = sub.add_parser("sweep", help="domain-of-attraction sweep over a grid of initial apexes")
    _common(p, noise=True, models=("bhop", "slip"))
    p.add_argument("--dy", default="0.05", type=A.DY)
    p.add_argument("--dz", default="0.05", type=A.DZ)
    p.add_argument("--ydot0", default="0.5", type=A.YDOT0)
    p.add_argument("--plot", default=None, metavar="PATH", help="write the map as PNG")
    p.add_argument("--runs", default=None, type=A.RUNS,
                   help="run only N of the grid's states in the global domain, evenly spaced")
    p.add_argument("--domain", default=None, choices=("plan", "verified"),
                   help="initial states: every grid state in the plan's global domain "
                   "(plan; the default for BHop and MuJoCo), or only those whose first SLIP "
                   "stride, predicted on the plan's map, ends in it again (verified; the "
                   "default for --model slip)")
    p.add_argument("--checkpoint", default=None, metavar="DIR",
                   help="save finished chunks here; a rerun resumes where it stopped")
    p.add_argument("--chunk", default=None, type=A.CHUNK,
                   help="runs per chunk (default: one per device)")
    p.add_argument("--distributed", action="store_true",
                   help="one of several processes under jax.distributed (coordinator from "
                   "JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID, or the "
                   "cluster's environment); each runs its share of the chunks")
    p.set_defaults(func=cmd_sweep)
    p = sub.add_parser("run", help="one run from one initial apex")
    _common(p, noise=True, models=("bhop", "slip"))
    p.add_argument("--apex", default="0.6,1.6,0.5", type=A.APEX, help="initial apex y,z,ydot")
    p.add_argument("--plot", default=None, metavar="PATH", help="write the run as PNG")
    p.add_argument("--animate", default=None, metavar="PATH",
                   help="write an animation of the run: .gif (Pillow) or .mp4 (needs ffmpeg)")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("step", help="one stride of a model from one apex with given controls")
    p.add_argument("--model", default="slip", choices=("slip", "bhop"))
    p.add_argument("--apex", required=True, type=A.APEX, help="apex y,z,ydot")
    p.add_argument("--controls", required=True, type=A.CONTROLS,
                   help="slip: th_td,kc,kd (rad, N/m, N/m); bhop: dy,th,k")
    p.add_argument("--terrain", default=None,
                   help="built-in name or JSON file (default: flat ground at height 0)")
    p.add_argument("--wind", default="0", type=A.WIND,
                   help="horizontal acceleration in flight (m/s^2)")
    p.add_argument("--json", default=None, metavar="PATH")
    p.set_defaults(func=cmd_step)
    p = sub.add_parser("demo", help="the main job: plan, runs, sweeps, figures")
    p.add_argument("--out", default="jaxhop-demo", help="output folder")
    p.add_argument("--json", default=None, metavar="PATH")
    p.add_argument("--no-cache", action="store_true")
    p.set_defaults(func=cmd_demo)
    from ..parkour._cli import add_parser as add_parkour

    add_parkour(sub)
    return parser


def command() -> int:
    """The `jaxhop` command (and `python -m jaxhop`): `main` on `sys.argv`, in a process
    that ends with it.

    Before the process exits, every object is moved out of reach of Python's cycle
    collector (`gc.freeze`), whose last pass over the objects of JAX, diffrax and jaxhop
    took 0.3 s of every command's wall time (2-core CPU); the operating system frees their
    memory. Exit handlers still run and every file jaxhop writes is closed already.
    """
    code = main()
    gc.freeze()
    return code


def main(argv=None) -> int:
    A.use_all_cores()
    try:
        args = build_parser().parse_args(argv)
        A.check_outputs(args)
        A.check_sim(args)
        if getattr(args, "distributed", False):
            A.init_distributed(args)
        return int(args.func(args) or 0)
    except InputError as err:
        print(f"jaxhop: error: {' '.join(str(err).split(chr(10)))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxhop: interrupted", file=sys.stderr)
        return 130


# --- shared pieces ------------------------------------------------------------------------


def _log(msg):
    print(f"jaxhop: {msg}", file=sys.stderr)


def _write_json(path, data):
    if path is None:
        return
    try:
        with open(path, "w") as f:
            json.dump(data, f, indent=1)
    except OSError as err:
        raise InputError(f"--json: cannot write {path} ({err.strerror})") from None


def _plan(args, terrain, goal):
    from .._planning.cache import get_plan
    from .._planning.deploy import PICKBEST
    from .._planning.plan import build_plan, templates_for

    templates = templates_for(getattr(args, "model", "bhop"))
    if args.pickbest != "robust" or args.no_cache:
        return build_plan(terrain, goal, templates, pickbest=PICKBEST[args.pickbest])
    return get_plan(terrain, goal, templates, log=_log)


def _perceived(terrain, seed: int):
    """The planner's map under ground noise: heights + U(-0.15, 0.15), one draw per block."""
    import jax
    import numpy as np

    from .._core.params import GROUND_HALF_WIDTH

    noise = jax.random.uniform(jax.random.fold_in(jax.random.key(seed), 1),
                               (terrain.n_blocks,), minval=-1.0, maxval=1.0)
    return terrain.with_heights(np.asarray(terrain.heights) + GROUND_HALF_WIDTH *
                                np.asarray(noise))


def _setting(args):
    import jax

    from .._core.params import disturbance_for

    return (args.seed, args.max_steps, args.tolerance, disturbance_for(args.noise),
            jax.random.key(args.seed))


def _prepare(args):
    """Terrain, plan (on the perceived map under ground noise) and run settings."""
    from .._core.params import has_ground

    seed, max_steps, tol, disturbance, key = _setting(args)
    terrain, goal = A.terrain_and_goal(args)
    planner_map = _perceived(terrain, seed) if has_ground(args.noise) else terrain
    plan = _plan(args, planner_map, goal)
    return terrain, plan, seed, max_steps, tol, disturbance, key


# --- commands -------------------------------------------------------------------------------


def cmd_plan(args) -> int:
    terrain, goal = A.terrain_and_goal(args)
    plan = _plan(args, terrain, goal)
    out = plan.summary()
    print(f"plan on '{terrain.name}': {out['n_segments']} segments, {out['n_situated']} "
          f"situated, {out['n_candidate_pairs']} candidate pairs, {out['n_instantiated']} "
          f"instantiated, {out['n_goal_policies']} goal policies, {out['n_deployed']} "
          f"deployed, {out['n_edges']} edges ({out['seconds']} s"
          f"{', from cache' if plan.stats.get('from_cache') else ''})")
    _write_json(args.json, out)
    return 0


def cmd_sweep(args) -> int:
    A.check_sweep_args(args)
    if args.checkpoint is not None:
        try:
            os.makedirs(args.checkpoint, exist_ok=True)
        except OSError as err:
            raise InputError(f"--checkpoint: cannot create {args.checkpoint} "
                             f"({err.strerror})") from None
    terrain, plan, seed, max_steps, tol, disturbance, key = _prepare(args)
    if args.sim == "mujoco":
        out, initial, result = _sweep_mujoco(args, terrain, plan, seed, max_steps, tol,
                                             disturbance)
    else:
        from .._execution.batches import sweep
        from .._execution.settings import ExecSettings

        out, initial, result = sweep(
            plan, _run_settings(args, max_steps, tol), initial=_sweep_grid(args), key=key,
            true_terrain=terrain, disturbance=disturbance,
            execution=ExecSettings(chunk=args.chunk, checkpoint=args.checkpoint,
                                   progress=True))
    out.update({"terrain": terrain.name, "model": args.model, "noise": args.noise,
                "seed": seed, "controller": args.controller, "sim": args.sim,
                "domain": "verified" if _verify(args) else "plan"})
    fails = ", ".join(f"{k} {v}" for k, v in out["failures"].items() if v) or "none"
    print(f"sweep on '{terrain.name}' ({args.model}{', mujoco' * (args.sim == 'mujoco')}, "
          f"noise {args.noise}): "
          f"{out['n_initial_conditions']} initial apexes, success {out['success_rate']:.4f}, "
          f"mean strides {out['mean_steps']:.2f}, max {out['max_steps']}; failures: {fails} "
          f"({out['seconds']} s)")
    if args.plot:
        from .._viz.plot import doa_figure

        fig = doa_figure(terrain, initial, result["code"], result["steps"], plan.goal,
                         f"{args.model}{' in MuJoCo' * (args.sim == 'mujoco')}, "
                         f"noise {args.noise}")
        _save(fig, args.plot)
    _write_json(args.json, out)
    return 0


def _run_settings(args, max_steps, tol):
    from .._execution.settings import RunSettings

    return RunSettings(model=args.model, controller=args.controller, tolerance=tol,
                       max_steps=max_steps)


def _sweep_grid(args):
    from .._execution.settings import SweepGrid

    return SweepGrid(ydot0=args.ydot0, dy=args.dy, dz=args.dz, runs=args.runs,
                     verify=_verify(args))


def _verify(args) -> bool:
    """`--domain`: its default is `verified` for the jaxhop SLIP, `plan` otherwise."""
    if args.domain is None:
        return args.model == "slip" and args.sim != "mujoco"
    return args.domain == "verified"


def _sweep_mujoco(args, terrain, plan, seed, max_steps, tol, disturbance):
    import dataclasses
    import time

    from .._execution.batches import sweep_initial
    from ..mujoco import DEFAULT, job_for, run_many, summarize_runs

    t0 = time.perf_counter()
    initial = sweep_initial(plan, _sweep_grid(args), true_terrain=terrain,
                            settings=_run_settings(args, max_steps, tol))
    job = job_for(terrain, plan, DEFAULT, args.controller, disturbance, tol, max_steps, seed)
    result = run_many(job, initial, progress=True)
    out = summarize_runs(result, time.perf_counter() - t0)
    out["mechanics"] = dataclasses.asdict(DEFAULT)
    return out, initial, result


def cmd_run(args) -> int:
    import numpy as np

    from .._core.params import has_ground
    from .._execution.batches import run_batch
    from .._models.flight import RESULT_NAMES

    apex = args.apex
    if args.animate:
        A.check_animate(args.animate)
    terrain, plan, seed, max_steps, tol, disturbance, key = _prepare(args)
    if args.sim == "mujoco":
        return _run_mujoco(args, terrain, plan, seed, max_steps, tol, disturbance)
    r = run_batch(plan, np.asarray([apex]), _run_settings(args, max_steps, np.asarray(tol)),
                  key=key, true_terrain=terrain, disturbance=disturbance)
    steps = int(r["steps"][0])
    out = {"terrain": terrain.name, "model": args.model, "noise": args.noise, "seed": seed,
           "result": RESULT_NAMES[int(r["code"][0])], "steps": steps,
           "apexes": r["apexes"][0][: steps + 1].tolist(),
           "footholds": r["footholds"][0][:steps].tolist(),
           "policies": r["policies"][0][:steps].tolist(), "controller": args.controller,
           "recoveries": int(r["recoveries"][0])}
    print(f"run on '{terrain.name}' from {apex}: {out['result']} after {steps} strides; "
          f"final apex {np.round(out['apexes'][-1], 3).tolist()}")
    if args.plot:
        from .._viz.draw import RunStyle
        from .._viz.plot import runs_figure

        fig = runs_figure(terrain, [{k: v[0] for k, v in r.items()}], plan.goal,
                          perceived=plan.terrain if has_ground(args.noise) else None,
                          style=RunStyle(args.model, wind=float(disturbance.wind)))
        _save(fig, args.plot)
    if args.animate:
        from .._viz.animate import animate_run
        from .._viz.draw import RunStyle

        try:
            animate_run(terrain, {k: v[0] for k, v in r.items()}, args.animate,
                        goal=plan.goal, style=RunStyle(args.model, wind=float(disturbance.wind)))
        except OSError as err:
            raise InputError(f"--animate: cannot write {args.animate} "
                             f"({err.strerror or err})") from None
    _write_json(args.json, out)
    return 0


def _run_mujoco(args, terrain, plan, seed, max_steps, tol, disturbance) -> int:
    import numpy as np

    from .._core.params import has_ground
    from .._core.result import result_name
    from ..mujoco import DEFAULT, job_for, run_recorded

    job = job_for(terrain, plan, DEFAULT, args.controller, disturbance, tol, max_steps, seed)
    r, trajectory = run_recorded(job, np.asarray(args.apex, float))
    steps = r["steps"]
    apexes = r["apexes"][np.all(np.isfinite(r["apexes"]), axis=1)]
    out = {"terrain": terrain.name, "model": args.model, "sim": "mujoco", "noise": args.noise,
           "seed": seed, "result": result_name(r["code"]), "why": r["why"], "steps": steps,
           "apexes": apexes.tolist(), "footholds": r["footholds"][:steps].tolist(),
           "policies": r["policies"][:steps].tolist(), "controller": args.controller,
           "recoveries": r["recoveries"], "trajectory": np.round(trajectory, 6).tolist()}
    why = f" ({r['why']})" if r["why"] else ""
    print(f"mujoco run on '{terrain.name}' from {args.apex}: {out['result']}{why} after "
          f"{steps} strides; last apex {np.round(apexes[-1], 3).tolist()}")
    if args.plot:
        from ..mujoco import trajectory_figure

        _save(trajectory_figure(terrain, r, trajectory, plan.goal,
                                plan.terrain if has_ground(args.noise) else None), args.plot)
    if args.animate:
        from ..mujoco import animate_trajectory

        try:
            animate_trajectory(terrain, r, trajectory, args.animate, goal=plan.goal)
        except OSError as err:
            raise InputError(f"--animate: cannot write {args.animate} "
                             f"({err.strerror or err})") from None
    _write_json(args.json, out)
    return 0


def _save(fig, path):
    import matplotlib.pyplot as plt

    try:
        fig.savefig(path, dpi=130)
    except OSError as err:
        raise InputError(f"cannot write figure {path} ({err.strerror})") from None
    finally:
        plt.close(fig)


def cmd_step(args) -> int:
    import jax.numpy as jnp
    import numpy as np

    from .._control.decisions import model_for
    from .._core.params import Hopper
    from .._core.result import RESULT_NAMES

    apex, u, wind = args.apex, args.controls, args.wind
    terrain = A.check_step_args(args)
    hopper = Hopper()
    model = model_for(args.model)
    nxt, code, foot = model.stride(jnp.asarray(apex), jnp.asarray(u), terrain, hopper, wind)
    result = "ok" if int(code) == 0 else RESULT_NAMES[int(code)]
    out = {"model": args.model, "apex": apex, "controls": u, "terrain": terrain.name,
           "apex_next": np.asarray(nxt).tolist(), "result": result,
           "foothold": np.asarray(foot).tolist()}
    print(f"{args.model} stride from {apex} with {u}: {result}; next apex "
          f"{np.round(np.asarray(nxt), 6).tolist()}")
    _write_json(args.json, out)
    return 0


def cmd_demo(args) -> int:
    from .demo import demo

    summary = demo(args.out, cache=not args.no_cache, log=_log)
    _write_json(args.json, summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
