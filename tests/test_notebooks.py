"""The notebooks execute top to bottom (at reduced sizes)."""

import pathlib

import pytest

NOTEBOOK_DIR = pathlib.Path(__file__).parent.parent / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
GENERATED = ("01_bhop_planning", "02_robustness_sweeps", "03_slip", "04_parkour")


def test_stored_notebooks_match_make(tmp_path):
    """The .ipynb files are what `notebooks/_make.py` writes: up to date, without outputs."""
    import importlib.util

    pytest.importorskip("nbformat")
    spec = importlib.util.spec_from_file_location("_make", NOTEBOOK_DIR / "_make.py")
    make = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make)
    make.build(tmp_path)
    assert set(GENERATED) <= set(make.NOTEBOOKS)
    for name in make.NOTEBOOKS:
        fresh, stored = tmp_path / f"{name}.ipynb", NOTEBOOK_DIR / f"{name}.ipynb"
        assert stored.exists(), f"run python notebooks/_make.py ({name} is missing)"
        assert fresh.read_text() == stored.read_text(), \
            f"{name}.ipynb is stale: run python notebooks/_make.py"


@pytest.mark.slow
# The MuJoCo notebook compiles the SLIP decision in every worker process: minutes.
@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.heavy) if "mujoco" in p.stem
                                  else p for p in NOTEBOOKS], ids=lambda p: p.stem)
def test_notebook_runs(path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("JAXHOP_NB_QUICK", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), \
        "notebooks are stored without outputs"
    # A last cell reports what the kernel saw: the notebook ran at the reduced size.
    nb.cells.append(nbformat.v4.new_code_cell(
        'import os; print(os.environ.get("JAXHOP_NB_QUICK"))'))
    client = nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors
    seen = "".join(o.get("text", "") for o in nb.cells[-1].get("outputs", []))
    assert seen.strip() == "1", f"the kernel ran with JAXHOP_NB_QUICK={seen.strip()!r}"
