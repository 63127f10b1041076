"""The Python API as a user meets it: the README's examples run as written, the library's
defaults are the command line's, and the settings objects reject bad values."""

import json
import pathlib
import re

import jax
import numpy as np
import pytest

import jaxhop
from jaxhop._cli.main import main

README = pathlib.Path(__file__).parent.parent / "README.md"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_block_finder_finds_python_blocks_only():
    text = "x\n```python\na = 1\n```\n```bash\nls\n```\n```python\nb = a + 1\n```\n"
    assert _python_blocks(text) == ["a = 1\n", "b = a + 1\n"]


@pytest.mark.slow
def test_every_python_block_of_the_readme_runs_as_written():
    blocks = _python_blocks(README.read_text())
    assert blocks, "the README has a Python quickstart"
    namespace = {"__name__": "readme"}
    for block in blocks:  # one namespace: later blocks may use what earlier ones define
        exec(compile(block, str(README), "exec"), namespace)


@pytest.mark.slow
def test_the_library_sweeps_with_the_command_lines_controller(tmp_path):
    # The same wind sweep from Python with every default and from `jaxhop sweep`: the same
    # runs, so the same outcome for every initial apex.
    plan = jaxhop.get_plan(jaxhop.builtin_terrain("reference"), progress=False)
    summary, initial, result = jaxhop.sweep(plan, disturbance=jaxhop.disturbance_for("wind"),
                                            key=jax.random.key(5))
    assert summary["success_rate"] >= 0.99
    path = tmp_path / "wind.json"
    assert main(["sweep", "--terrain", "reference", "--noise", "wind", "--seed", "5",
                 "--json", str(path)]) == 0
    cli = json.loads(path.read_text())
    assert cli["controller"] == "adaptive"
    for k in ("n_initial_conditions", "success_rate", "mean_steps", "failures"):
        assert cli[k] == summary[k], k


def test_settings_reject_an_unknown_controller():
    with pytest.raises(jaxhop.InputError, match="controller"):
        jaxhop.RunSettings(controller="pid")


def test_a_sweep_grid_picks_evenly_spaced_states_of_the_domain():
    plan = jaxhop.get_plan(jaxhop.builtin_terrain("flat"), progress=False)
    every = jaxhop.sweep_initial(plan, jaxhop.SweepGrid(dy=0.2, dz=0.2))
    grid = jaxhop.sweep_grid(plan.terrain, dy=0.2, dz=0.2)
    inside = jaxhop.in_global_domain(grid, plan.tables(), plan.hopper)
    np.testing.assert_array_equal(every, grid[inside])  # brute force: filter the grid
    four = jaxhop.sweep_initial(plan, jaxhop.SweepGrid(dy=0.2, dz=0.2, runs=4))
    np.testing.assert_array_equal(four[[0, -1]], every[[0, -1]])
    assert four.shape == (4, 3)


def _tables_module():
    import importlib.util

    path = README.parent / "benchmarks" / "tables.py"
    spec = importlib.util.spec_from_file_location("benchmark_tables", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("page", ["README.md", "benchmarks/README.md"])
def test_landing_pages_are_at_most_150_lines_without_history(page):
    text = (README.parent / page).read_text()
    assert len(text.splitlines()) <= 150
    for word in ("session", "issue ", "earlier build", "before the "):
        assert word not in text.lower(), word


def test_benchmark_tables_are_generated_from_the_results_files():
    # Every number in the tables comes from its results file: the pages hold exactly what
    # `benchmarks/tables.py` renders from `benchmarks/results/`, and nothing written by hand
    # between the markers.
    tables = _tables_module()
    for path, sections in tables.PAGES.items():
        doc = path.read_text()
        inside = doc.split(tables.START)[1].split(tables.END)[0]
        assert inside == "\n" + tables.render(sections), path.name
