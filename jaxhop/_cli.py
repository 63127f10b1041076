"""The `jaxhop` command line (SPEC section 15)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

from ._errors import InputError


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise InputError(message)


def _floats(text: str, n: int, field: str):
    if not isinstance(text, str):  # argparse turns a bare "--" value into a list
        raise InputError(f"{field}: expected {n} comma-separated numbers, got {text!r}")
    parts = text.split(",")
    if len(parts) != n:
        raise InputError(f"{field}: expected {n} comma-separated numbers, got {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise InputError(f"{field}: expected numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise InputError(f"{field}: numbers must be finite, got {text!r}")
    return values


def _positive(text: str, field: str) -> float:
    (v,) = _floats(text, 1, field)
    if v <= 0:
        raise InputError(f"{field}: must be positive, got {text}")
    return v


def _bounded(values, field: str, limit: float):
    """Raise unless every value has magnitude at most `limit` (absurd sizes are errors)."""
    for v in values:
        if abs(v) > limit:
            raise InputError(f"{field}: |{v:g}| exceeds the limit {limit:g}")
    return values


def _count(text: str, field: str, hi: int) -> int:
    """A whole number in [1, hi] (`--max-steps`, `--chunk`): 2.5 is an error, not 2."""
    if not isinstance(text, str):
        raise InputError(f"{field}: expected a whole number, got {text!r}")
    try:
        v = int(text)
    except ValueError:
        raise InputError(f"{field}: expected a whole number, got {text!r}") from None
    if not 1 <= v <= hi:
        raise InputError(f"{field}: must lie in [1, {hi}], got {v}")
    return v


MAX_CHUNK = 65_536
MAX_SPEED = 100.0  # |ydot| of an apex (m/s)
MAX_POSITION = 1.0e4  # |y|, |z| of an apex (m)


def _check_sweep_args(args):
    """Every sweep number, the terrain and the grid size, before any plan is built."""
    from ._execute import MAX_GRID

    dy, dz = _positive(args.dy, "--dy"), _positive(args.dz, "--dz")
    (ydot0,) = _bounded(_floats(args.ydot0, 1, "--ydot0"), "--ydot0", MAX_SPEED)
    if args.chunk is not None:
        _count(args.chunk, "--chunk", MAX_CHUNK)
    _setting(args)
    terrain, _ = _terrain_and_goal(args)
    (y0, y1), h = terrain.y_range, [b[2] for b in terrain.blocks()]
    n = (math.floor((y1 - y0) / dy) + 1) * (math.floor((max(h) - min(h) + 1.6) / dz) + 1)
    if n > MAX_GRID:
        raise InputError(f"--dy/--dz: the grid would have about {n:.3g} initial states, at "
                         f"most {MAX_GRID} allowed")


def _check_step_args(model: str, apex, u, wind: float, terrain):
    """`jaxhop step`: an apex in the air over the map, controls and wind of sane size."""
    _bounded(apex[:2], "--apex", MAX_POSITION)
    _bounded(apex[2:], "--apex", MAX_SPEED)
    y, z, _ = apex
    y0, y1 = terrain.y_range
    if not y0 <= y <= y1:
        raise InputError(f"--apex: y = {y:g} lies off the map [{y0:g}, {y1:g}]")
    under = [h for s, e, h in terrain.blocks() if s <= y <= e]
    if under and not z > max(under) + 1.0:
        raise InputError(f"--apex: z = {z:g} must exceed the ground under it "
                         f"({max(under):g}) by more than the leg length 1 m")
    _bounded([wind], "--wind", 100.0)
    if model == "slip":
        _bounded(u[1:], "--controls", 1.0e8)
    else:
        if not abs(u[0]) <= 1.0:
            raise InputError(f"--controls: |dy| must be at most the leg length 1 m, got {u[0]}")
        if not abs(u[1]) < math.pi / 2:
            raise InputError(f"--controls: th must lie in (-pi/2, pi/2), got {u[1]}")
        if u[2] > 100:
            raise InputError(f"--controls: k must be at most 100, got {u[2]}")


def _precheck(args):
    """Checks that need no terrain or plan, before any command starts its work."""
    _check_outputs(args)
    if args.command == "run":
        apex = _floats(args.apex, 3, "--apex")
        _bounded(apex[:2], "--apex", MAX_POSITION)
        _bounded(apex[2:], "--apex", MAX_SPEED)


def _check_outputs(args):
    """Output paths that cannot be written fail now, not after minutes of work."""
    for flag in ("json", "plot"):
        path = getattr(args, flag, None)
        if path is None:
            continue
        folder = os.path.dirname(os.path.abspath(path)) if path else ""
        if not path or os.path.isdir(path) or not os.path.isdir(folder):
            raise InputError(f"--{flag}: cannot write {path!r} (no such folder, or a folder)")
    out = getattr(args, "out", None)
    if out is not None and (not out or os.path.exists(out) and not os.path.isdir(out)):
        raise InputError(f"--out: {out!r} is not a folder")
    ck = getattr(args, "checkpoint", None)
    if ck is not None and (not ck or os.path.exists(ck) and not os.path.isdir(ck)):
        raise InputError(f"--checkpoint: {ck!r} is not a folder")


def _init_distributed(args):
    """`jax.distributed.initialize()` from the environment, before JAX starts its backend.

    `JAX_COORDINATOR_ADDRESS` (host:port of process 0), `JAX_NUM_PROCESSES` and
    `JAX_PROCESS_ID`; where the last two are unset JAX detects them (SLURM, Open MPI, ...).
    Only process 0 writes `--json` and `--plot`.
    """
    import jax

    kwargs = {}
    for name, env in (("num_processes", "JAX_NUM_PROCESSES"), ("process_id", "JAX_PROCESS_ID")):
        text = os.environ.get(env)
        if text is not None:
            try:
                kwargs[name] = int(text)
            except ValueError:
                raise InputError(f"{env}: expected a whole number, got {text!r}") from None
    if "num_processes" in kwargs and not 1 <= kwargs["num_processes"] <= 100_000:
        raise InputError(f"JAX_NUM_PROCESSES: must be >= 1, got {kwargs['num_processes']}")
    if "process_id" in kwargs and not 0 <= kwargs["process_id"] < kwargs.get(
            "num_processes", 100_000):
        raise InputError(f"JAX_PROCESS_ID: must lie in [0, JAX_NUM_PROCESSES), got "
                         f"{kwargs['process_id']}")
    try:
        jax.distributed.initialize(**kwargs)
    except (ValueError, TypeError, RuntimeError) as err:
        raise InputError(f"--distributed: cannot initialize jax.distributed "
                         f"({' '.join(str(err).split())[:200]})") from None
    if jax.process_index() != 0:
        args.json = args.plot = None


def _seed(text: str) -> int:
    if not isinstance(text, str):
        raise InputError(f"--seed: expected a non-negative integer, got {text!r}")
    try:
        v = int(text)
    except ValueError:
        raise InputError(f"--seed: expected a non-negative integer, got {text!r}") from None
    if v < 0 or v >= 2**63:
        raise InputError(f"--seed: expected a non-negative integer below 2**63, got {text}")
    return v


def _common(p, model=True, noise=False, models=("bhop",)):
    p.add_argument("--terrain", default="reference", help="built-in name or JSON file")
    p.add_argument("--goal", default=None, help="global goal y,z,ydot (default: the terrain's)")
    p.add_argument("--json", default=None, metavar="PATH", help="write the result as JSON")
    p.add_argument("--no-cache", action="store_true", help="rebuild the plan, do not cache")
    p.add_argument("--pickbest", default="robust", choices=("robust", "depth", "safety"),
                   help="deployment priority")
    if model:
        p.add_argument("--model", default="bhop", choices=models,
                       help="slip: the SLIP model on the BHop plan with the SLIP adjustments "
                       "(eqs 35-37)")
    if noise:
        p.add_argument("--noise", default="none", choices=("none", "wind", "sensor", "ground"))
        p.add_argument("--seed", default="0", help="seed of every random draw")
        p.add_argument("--max-steps", default="60")
        p.add_argument("--tolerance", default="0.05,0.05,0.05",
                       help="goal tolerance per axis y,z,ydot")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="jaxhop", description="Reactive footstep planning for hopping on "
                     "rough terrain (Arslan & Saranli 2012) and MPPC parkour, in JAX.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    p = sub.add_parser("plan", help="build (or load) the plan and report its size")
    _common(p, models=("bhop", "slip"))
    p.set_defaults(func=cmd_plan)
    p = sub.add_parser("sweep", help="domain-of-attraction sweep (SPEC section 12)")
    _common(p, noise=True, models=("bhop", "slip"))
    p.add_argument("--dy", default="0.05")
    p.add_argument("--dz", default="0.05")
    p.add_argument("--ydot0", default="0.5")
    p.add_argument("--plot", default=None, metavar="PATH", help="write the map as PNG")
    p.add_argument("--checkpoint", default=None, metavar="DIR",
                   help="save finished chunks here; a rerun resumes where it stopped")
    p.add_argument("--chunk", default=None, help="runs per chunk (default: one per device)")
    p.add_argument("--distributed", action="store_true",
                   help="one of several processes under jax.distributed (coordinator from "
                   "JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID, or the "
                   "cluster's environment); each runs its share of the chunks")
    p.set_defaults(func=cmd_sweep)
    p = sub.add_parser("run", help="one run from one initial apex")
    _common(p, noise=True, models=("bhop", "slip"))
    p.add_argument("--apex", default="0.6,1.6,0.5", help="initial apex y,z,ydot")
    p.add_argument("--plot", default=None, metavar="PATH", help="write the run as PNG")
    p.add_argument("--animate", default=None, metavar="PATH",
                   help="write an animation of the run: .gif (Pillow) or .mp4 (needs ffmpeg)")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("step", help="one stride of a model from one apex with given controls")
    p.add_argument("--model", default="slip", choices=("slip", "bhop"))
    p.add_argument("--apex", required=True, help="apex y,z,ydot")
    p.add_argument("--controls", required=True,
                   help="slip: th_td,kc,kd (rad, N/m, N/m); bhop: dy,th,k")
    p.add_argument("--terrain", default=None,
                   help="built-in name or JSON file (default: flat ground at height 0)")
    p.add_argument("--wind", default="0", help="horizontal acceleration in flight (m/s^2)")
    p.add_argument("--json", default=None, metavar="PATH")
    p.set_defaults(func=cmd_step)
    p = sub.add_parser("demo", help="the main job: plan, runs, sweeps, figures")
    p.add_argument("--out", default="jaxhop-demo", help="output folder")
    p.add_argument("--json", default=None, metavar="PATH")
    p.add_argument("--no-cache", action="store_true")
    p.set_defaults(func=cmd_demo)
    try:
        from .mppc._cli import add_parser as add_parkour
    except ImportError:
        pass
    else:
        add_parkour(sub)
    return parser


def _use_all_cores():
    """Expose every CPU core as a JAX device (sweeps put one chunk on each).

    Must run before JAX starts its backend; `JAXHOP_CPU_DEVICES` overrides the count.
    """
    import jax

    n = os.environ.get("JAXHOP_CPU_DEVICES") or str(os.cpu_count() or 1)
    try:
        jax.config.update("jax_num_cpu_devices", max(int(n), 1))
    except (RuntimeError, ValueError, AttributeError):
        pass  # backend already started, or an older JAX: keep its default


def main(argv=None) -> int:
    _use_all_cores()
    try:
        args = build_parser().parse_args(argv)
        _precheck(args)
        if getattr(args, "distributed", False):
            _init_distributed(args)
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


def _terrain_and_goal(args):
    from ._terrain import check_goal, load_terrain

    terrain = load_terrain(args.terrain)
    goal = _floats(args.goal, 3, "--goal") if args.goal is not None else None
    if goal is not None:
        goal = list(check_goal(terrain, goal, "--goal"))
    if goal is None and terrain.goal is None:
        raise InputError(f"terrain {terrain.name!r} has no default goal: pass --goal y,z,ydot")
    return terrain, goal


def _plan(args, terrain, goal):
    from ._deploy import PICKBEST
    from ._plan import build_plan, get_plan, templates_for

    templates = templates_for(getattr(args, "model", "bhop"))
    if args.pickbest != "robust" or args.no_cache:
        return build_plan(terrain, goal, templates, pickbest=PICKBEST[args.pickbest])
    return get_plan(terrain, goal, templates, log=_log)


def _perceived(terrain, seed: int):
    """The planner's map under ground noise: heights + U(-0.15, 0.15), one draw per block."""
    import jax
    import numpy as np

    from ._params import GROUND_HALF_WIDTH

    noise = jax.random.uniform(jax.random.fold_in(jax.random.key(seed), 1),
                               (terrain.n_blocks,), minval=-1.0, maxval=1.0)
    return terrain.with_heights(np.asarray(terrain.heights) + GROUND_HALF_WIDTH *
                                np.asarray(noise))


def _setting(args):
    import jax

    from ._params import disturbance_for

    seed = _seed(args.seed)
    max_steps = _count(args.max_steps, "--max-steps", 10_000)
    tol = _bounded(_floats(args.tolerance, 3, "--tolerance"), "--tolerance", 100.0)
    if min(tol) < 0:
        raise InputError("--tolerance: must be non-negative")
    return seed, max_steps, tol, disturbance_for(args.noise), jax.random.key(seed)


def _prepare(args):
    """Terrain, plan (on the perceived map under ground noise) and run settings."""
    seed, max_steps, tol, disturbance, key = _setting(args)
    terrain, goal = _terrain_and_goal(args)
    planner_map = _perceived(terrain, seed) if args.noise == "ground" else terrain
    plan = _plan(args, planner_map, goal)
    return terrain, plan, seed, max_steps, tol, disturbance, key


# --- commands -------------------------------------------------------------------------------


def cmd_plan(args) -> int:
    terrain, goal = _terrain_and_goal(args)
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
    _check_sweep_args(args)
    dy, dz = _positive(args.dy, "--dy"), _positive(args.dz, "--dz")
    args.chunk_size = int(_positive(args.chunk, "--chunk")) if args.chunk is not None else None
    if args.checkpoint is not None:
        try:
            os.makedirs(args.checkpoint, exist_ok=True)
        except OSError as err:
            raise InputError(f"--checkpoint: cannot create {args.checkpoint} "
                             f"({err.strerror})") from None
    (ydot0,) = _floats(args.ydot0, 1, "--ydot0")
    terrain, plan, seed, max_steps, tol, disturbance, key = _prepare(args)
    from ._execute import sweep

    out, initial, result = sweep(plan, key=key, true_terrain=terrain, disturbance=disturbance,
                                 ydot0=ydot0, dy=dy, dz=dz, max_steps=max_steps,
                                 tolerance=tol, chunk=args.chunk_size,
                                 checkpoint=args.checkpoint, model=args.model,
                                 progress=True)
    out.update({"terrain": terrain.name, "model": args.model, "noise": args.noise,
                "seed": seed})
    fails = ", ".join(f"{k} {v}" for k, v in out["failures"].items() if v) or "none"
    print(f"sweep on '{terrain.name}' ({args.model}, noise {args.noise}): "
          f"{out['n_initial_conditions']} initial apexes, success {out['success_rate']:.4f}, "
          f"mean strides {out['mean_steps']:.2f}, max {out['max_steps']}; failures: {fails} "
          f"({out['seconds']} s)")
    if args.plot:
        from ._plot import doa_figure

        fig = doa_figure(terrain, initial, result["code"], result["steps"], plan.goal,
                         f"{args.model}, noise {args.noise}")
        _save(fig, args.plot)
    _write_json(args.json, out)
    return 0


def cmd_run(args) -> int:
    import numpy as np

    from ._execute import run_batch
    from ._flight import RESULT_NAMES

    apex = _floats(args.apex, 3, "--apex")
    if args.animate:
        from ._animate import animation_writer

        try:  # a bad name or a missing encoder fails before any work
            animation_writer(args.animate, 25)
        except InputError as err:
            raise InputError(f"--animate: {err}") from None
        if not os.path.isdir(os.path.dirname(os.path.abspath(args.animate))):
            raise InputError(f"--animate: cannot write {args.animate!r} (no such folder)")
    terrain, plan, seed, max_steps, tol, disturbance, key = _prepare(args)
    r = run_batch(plan, np.asarray([apex]), key=key, true_terrain=terrain,
                  disturbance=disturbance, max_steps=max_steps, tolerance=np.asarray(tol),
                  model=args.model)
    steps = int(r["steps"][0])
    out = {"terrain": terrain.name, "model": args.model, "noise": args.noise, "seed": seed,
           "result": RESULT_NAMES[int(r["code"][0])], "steps": steps,
           "apexes": r["apexes"][0][: steps + 1].tolist(),
           "footholds": r["footholds"][0][:steps].tolist(),
           "policies": r["policies"][0][:steps].tolist()}
    print(f"run on '{terrain.name}' from {apex}: {out['result']} after {steps} strides; "
          f"final apex {np.round(out['apexes'][-1], 3).tolist()}")
    if args.plot:
        from ._plot import runs_figure

        fig = runs_figure(terrain, [{k: v[0] for k, v in r.items()}], plan.goal,
                          perceived=plan.terrain if args.noise == "ground" else None,
                          model=args.model, wind=float(disturbance.wind))
        _save(fig, args.plot)
    if args.animate:
        from ._animate import animate_run

        try:
            animate_run(terrain, {k: v[0] for k, v in r.items()}, args.animate,
                        goal=plan.goal, model=args.model, wind=float(disturbance.wind))
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

    from ._flight import RESULT_NAMES
    from ._params import Hopper
    from ._terrain import load_terrain, make_terrain

    apex = _floats(args.apex, 3, "--apex")
    u = _floats(args.controls, 3, "--controls")
    (wind,) = _floats(args.wind, 1, "--wind")
    if args.model == "slip":
        if not abs(u[0]) < math.pi / 2:
            raise InputError(f"--controls: th_td must lie in (-pi/2, pi/2), got {u[0]}")
        if u[1] <= 0 or u[2] <= 0:
            raise InputError("--controls: stiffnesses kc and kd must be positive")
    elif u[2] <= -1:
        raise InputError(f"--controls: k must be > -1, got {u[2]}")
    _bounded(apex, "--apex", MAX_POSITION)
    if args.terrain is None:
        terrain = make_terrain([(apex[0] - 20.0, apex[0] + 20.0, 0.0)], name="flat-ground")
    else:
        terrain = load_terrain(args.terrain)
    _check_step_args(args.model, apex, u, wind, terrain)
    hopper = Hopper()
    if args.model == "slip":
        from ._slip import slip_stride as stride_fn
    else:
        from ._execute import bhop_stride as stride_fn
    nxt, code, foot = stride_fn(jnp.asarray(apex), jnp.asarray(u), terrain, hopper, wind)
    result = "ok" if int(code) == 0 else RESULT_NAMES[int(code)]
    out = {"model": args.model, "apex": apex, "controls": u, "terrain": terrain.name,
           "apex_next": np.asarray(nxt).tolist(), "result": result,
           "foothold": np.asarray(foot).tolist()}
    print(f"{args.model} stride from {apex} with {u}: {result}; next apex "
          f"{np.round(np.asarray(nxt), 6).tolist()}")
    _write_json(args.json, out)
    return 0


def cmd_demo(args) -> int:
    from ._demo import demo

    summary = demo(args.out, cache=not args.no_cache, log=_log)
    _write_json(args.json, summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
