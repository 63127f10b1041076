"""Regenerate the figures of `docs/gallery/`: `python docs/make_gallery.py` (about two
minutes with the plan cached)."""

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
    explorers(plan)


def explorers(plan):
    """The explorers as a notebook shows them (`docs/explore.md`): the run from an apex with
    its first policy picked, and a stride after its deadbeat (half a minute to compile)."""
    ex = jaxhop.explore(plan, [0.6, 1.6, 0.5])
    first = int(ex.result["policies"][0])
    ex.set(noise="wind", policy=int(np.nonzero(plan.order == first)[0][0]))
    OUT.mkdir(exist_ok=True)
    (OUT / "explore.png").write_bytes(ex.image.value)
    st = jaxhop.explore_stride()
    st.set(target_y=0.8, target_z=1.35, target_ydot=0.9)
    st.controls["deadbeat"].click()
    (OUT / "explore_stride.png").write_bytes(st.image.value)


if __name__ == "__main__":
    main()
