"""The package keeps its shape: data flows one way, modules stay small, shared helpers work."""

import ast
import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop._batching import bucket, chunked_map, pad_to, pow2_at_least
from jaxhop._progress import Progress

PACKAGE = pathlib.Path(__file__).parent.parent / "jaxhop"

# The pipeline, in order: a module may import from its own stage or an earlier one.
STAGES = [
    ["__init__"],  # re-exports only; checked separately below
    ["_errors", "_params", "_paths", "_validate", "_result"],
    ["_terrain", "_batching", "_progress", "_programs"],
    ["_bhop", "_flight", "_slip", "_slip_deadbeat", "_slip_bracket", "_slip_table"],
    ["_templates"],
    ["_regions", "_policies"],
    ["_graph", "_deploy", "_stages", "_plan"],
    ["_cache"],
    ["_models", "_observer", "_foothold", "_runloop", "_pool", "_checkpoint", "_execute",
     "_replay"],
    ["_draw", "_plot", "_animate"],
    ["mppc"],
    ["parkour"],
    ["mujoco"],
    ["_cli_args", "_cli", "_demo"],
]
RANK = {name: i for i, names in enumerate(STAGES) for name in names}


def _stage(module: str) -> int:
    """Rank of a dotted module path relative to the package (`_plan`, `mppc._run`)."""
    head = module.split(".")[0]
    return RANK[head]


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        if rel.parts[0] == "reference":
            continue  # the NumPy twin is independent of the pipeline
        yield path, ".".join(rel.parts)


def _imports(path: pathlib.Path, module: str):
    """Package-internal modules imported by `module`, as dotted paths from the package."""
    package = module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = package[: len(package) - (node.level - 1)]
            target = ".".join(base + ([node.module] if node.module else []))
            if node.module:
                yield target
            else:
                for alias in node.names:  # `from . import _stages`
                    yield ".".join(base + [alias.name])


@pytest.mark.parametrize("path,module", list(_modules()), ids=lambda x: str(x))
def test_no_module_imports_from_a_later_stage(path, module):
    if module.split(".")[-1] == "__init__" or module.endswith("__version__"):
        pytest.skip("package files re-export")
    mine = _stage(module)
    for target in _imports(path, module):
        if target.split(".")[-1] in ("__version__", ""):
            continue
        if target.split(".")[0] == "reference":
            continue
        assert _stage(target) <= mine, f"{module} imports {target}, a later stage"


def test_every_module_has_a_stage_and_stays_small():
    for path, module in _modules():
        assert module.split(".")[0] in RANK, f"{module} is in no stage of the pipeline"
        lines = len(path.read_text().splitlines())
        assert lines <= 450, f"{module} has {lines} lines"


def test_chunked_map_equals_one_call_over_all_items():
    x = np.arange(37.0)
    y = np.arange(37.0) ** 2

    def fn(a, b, c):
        return a * c + b, jnp.sin(a)

    for size, tail in ((8, None), (16, 4), (64, 64), (37, 37)):
        out = chunked_map(fn, 37, size, (x, y), (2.0,), tail=tail)
        np.testing.assert_array_equal(out[0], x * 2.0 + y)
        np.testing.assert_array_equal(out[1], np.sin(x))
    with pytest.raises(ValueError):
        chunked_map(fn, 0, 8, (x, y), (2.0,))


def test_bucket_and_pad_to():
    assert [bucket(n, 8) for n in (0, 1, 8, 9, 16)] == [8, 8, 8, 16, 16]
    # Brute force: the first power of two at least n.
    for n in range(0, 70):
        assert pow2_at_least(n) == next(2**k for k in range(10) if 2**k >= max(n, 1))
    padded = pad_to(jnp.ones((2, 3)), 5, [7.0, 8.0, 9.0])
    assert padded.shape == (5, 3)
    np.testing.assert_array_equal(np.asarray(padded[2:]), np.tile([7.0, 8.0, 9.0], (3, 1)))
    with pytest.raises(ValueError):
        pad_to(jnp.ones((6, 3)), 5, 0.0)


def test_progress_prints_one_line_when_stderr_is_not_a_terminal(capsys):
    with Progress(10, "runs", "run") as bar:
        for _ in range(10):
            bar.update(1)
    err = capsys.readouterr().err
    assert "\r" not in err and err.count("\n") == 1 and err.startswith("runs: 10 run in ")
    with Progress(10, "runs", "run", enabled=False) as bar:
        bar.update(10)
    assert capsys.readouterr().err == ""
