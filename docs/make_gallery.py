"""Regenerate the figures of `docs/gallery/`: `python docs/make_gallery.py` (about a minute
with the plan cached)."""

import pathlib

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxhop  # noqa: E402
from jaxhop import plot as _plot  # noqa: E402

OUT = pathlib.Path(__file__).parent / "gallery"


def save(fig, name):
    OUT.mkdir(exist_ok=True)
    fig.savefig(OUT / name, dpi=90)
    plt.close(fig)


def main():
    terrain = jaxhop.builtin_terrain("reference")
    plan = jaxhop.get_plan(terrain, progress=False)
    save(_plot.template_regions_figure(plan.templates, plan.hopper), "template_regions.png")
    runs = jaxhop.run_batch(plan, np.array([[0.6, 1.6, 0.5], [3.6, 1.5, 0.5]]),
                            jaxhop.RunSettings(controller="paper"))
    examples = [{k: v[i] for k, v in runs.items()} for i in range(2)]
    save(_plot.runs_figure(terrain, examples, plan.goal, "Two reactive BHop runs"),
         "example_runs.png")
    for noise, controller in (("sensor", "adaptive"), ("wind", "adaptive"), ("wind", "paper")):
        summary, initial, result = jaxhop.sweep(plan, jaxhop.RunSettings(controller=controller),
                                                disturbance=jaxhop.disturbance_for(noise),
                                                key=jax.random.key(0))
        save(_plot.doa_figure(terrain, initial, result["code"], result["steps"], plan.goal,
                              f"BHop, {noise} noise, {controller} controller"),
             f"doa_{noise}{'' if controller == 'adaptive' else '_paper'}.png")
    from jaxhop.mppc import MPPC, load_course, plot_run, run_course

    course = load_course("mppc-sim-1")
    save(plot_run(course, run_course(course, MPPC())), "mppc_sim1.png")


if __name__ == "__main__":
    main()
