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
                       help="slip runs the SLIP model on the BHop plan (run only, so far)")
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
    _common(p)
    p.set_defaults(func=cmd_plan)
    p = sub.add_parser("sweep", help="domain-of-attraction sweep (SPEC section 12)")
    _common(p, noise=True)
    p.add_argument("--dy", default="0.05")
    p.add_argument("--dz", default="0.05")
    p.add_argument("--ydot0", default="0.5")
    p.add_argument("--plot", default=None, metavar="PATH", help="write the map as PNG")
    p.add_argument("--checkpoint", default=None, metavar="DIR",
                   help="save finished chunks here; a rerun resumes where it stopped")
    p.add_argument("--chunk", default=None, help="runs per chunk (default: one per device)")
    p.set_defaults(func=cmd_sweep)
    p = sub.add_parser("run", help="one run from one initial apex")
    _common(p, noise=True, models=("bhop", "slip"))
    p.add_argument("--apex", default="0.6,1.6,0.5", help="initial apex y,z,ydot")
    p.add_argument("--plot", default=None, metavar="PATH", help="write the run as PNG")
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
        return int(args.func(args) or 0)
    except InputError as err:
        print(f"jaxhop: error: {err}", file=sys.stderr)
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
    from ._terrain import load_terrain

    terrain = load_terrain(args.terrain)
    goal = _floats(args.goal, 3, "--goal") if args.goal is not None else None
    if goal is None and terrain.goal is None:
        raise InputError(f"terrain {terrain.name!r} has no default goal: pass --goal y,z,ydot")
    return terrain, goal


def _plan(args, terrain, goal):
    from ._deploy import PICKBEST
    from ._plan import build_plan, get_plan

    if args.pickbest != "robust" or args.no_cache:
        return build_plan(terrain, goal, pickbest=PICKBEST[args.pickbest])
    return get_plan(terrain, goal, log=_log)


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
    max_steps = int(_positive(args.max_steps, "--max-steps"))
    if max_steps > 10_000:
        raise InputError("--max-steps: at most 10000")
    tol = _floats(args.tolerance, 3, "--tolerance")
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
                                 checkpoint=args.checkpoint, progress=True)
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
                          perceived=plan.terrain if args.noise == "ground" else None)
        _save(fig, args.plot)
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
    if args.terrain is None:
        terrain = make_terrain([(apex[0] - 20.0, apex[0] + 20.0, 0.0)], name="flat-ground")
    else:
        terrain = load_terrain(args.terrain)
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
