"""notebooks/05_parkour_compare.ipynb is what its generator writes (`tests/test_notebooks.py`
executes it with the other notebooks)."""

import pathlib

import pytest

PATH = pathlib.Path(__file__).parent.parent / "notebooks" / "05_parkour_compare.ipynb"


def test_notebook_matches_its_generator():
    nbformat = pytest.importorskip("nbformat")
    import importlib.util

    spec = importlib.util.spec_from_file_location("_make_parkour", PATH.parent /
                                                  "_make_parkour.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    stored = nbformat.read(PATH, as_version=4)
    assert [c.source for c in stored.cells] == [c.source for c in mod.build().cells]
    assert all(not c.get("outputs") for c in stored.cells if c.cell_type == "code")
