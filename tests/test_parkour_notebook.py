"""notebooks/05_parkour_compare.ipynb executes top to bottom (JAXHOP_NB_QUICK=1)."""

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


@pytest.mark.slow
def test_parkour_notebook_runs(monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("JAXHOP_NB_QUICK", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(PATH, as_version=4)
    # A last cell reports what the kernel saw: the notebook ran at the reduced size.
    nb.cells.append(nbformat.v4.new_code_cell(
        'import os; print(os.environ.get("JAXHOP_NB_QUICK"))'))
    client = nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                                     resources={"metadata": {"path": str(PATH.parent)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors
    seen = "".join(o.get("text", "") for o in nb.cells[-1].get("outputs", []))
    assert seen.strip() == "1", f"the kernel ran with JAXHOP_NB_QUICK={seen.strip()!r}"
