"""The package keeps its shape: data flows one way through its stages, private names stay
in their modules, the public API stays small, and the shared helpers work."""

import ast
import inspect
import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop._core.batching import bucket, chunked_map, pad_to, pow2_at_least
from jaxhop._core.progress import Progress

PACKAGE = pathlib.Path(__file__).parent.parent / "jaxhop"

# The pipeline, in order: a module may import from its own package or an earlier one.
# `reference` (the NumPy twin) is independent of all of them.
ORDER = ["_core", "_models", "_planning", "_control", "_execution", "_viz", "mppc", "parkour",
         "mujoco", "_cli"]
# Files that only re-export (the package root and the public namespace modules).
FACADES = {"jaxhop", "jaxhop.slip", "jaxhop.plot", "jaxhop.__main__"}


def _modules():
    """`(path, dotted module name, is a package's __init__)` of every module of jaxhop."""
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = ("jaxhop",) + path.relative_to(PACKAGE).with_suffix("").parts
        init = parts[-1] == "__init__"
        yield path, ".".join(parts[:-1] if init else parts), init


MODULES = {name: (path, init) for path, name, init in _modules()}


def _imports(name: str):
    """`(target module, imported names)` of every import of jaxhop modules in `name`, at
    any depth (inside functions too); a name that is itself a module is resolved to it."""
    path, init = MODULES[name]
    package = name.split(".") if init else name.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            elif (node.module or "").split(".")[0] == "jaxhop":
                target = node.module
            else:
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                yield (sub, None) if sub in MODULES else (target, alias.name)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "jaxhop":
                    yield alias.name, None


def _rank(name: str) -> int | None:
    parts = name.split(".")
    return ORDER.index(parts[1]) if len(parts) > 1 and parts[1] in ORDER else None


def _graph():
    return {name: {t for t, _ in _imports(name) if t != name} for name in MODULES}


def test_every_module_lies_in_a_stage_or_the_twin():
    for name in MODULES:
        top = name.split(".")[1] if "." in name else None
        assert name in FACADES or top in ORDER or top == "reference", (
            f"{name} is in no stage of the pipeline")


def test_no_module_imports_from_a_later_stage():
    for name in MODULES:
        if name in FACADES:
            continue
        mine = _rank(name)
        for target, _ in _imports(name):
            if name.split(".")[1] == "reference":
                assert target.startswith("jaxhop.reference"), f"the twin {name} imports {target}"
                continue
            assert target not in FACADES, f"{name} imports {target}, which re-exports"
            assert _rank(target) <= mine, f"{name} imports {target}, a later stage"


def test_no_module_imports_a_private_name_of_another():
    for name in MODULES:
        for target, imported in _imports(name):
            if imported is not None and target != name:
                assert not imported.startswith("_"), f"{name} imports {imported} from {target}"


def _find_cycle(graph) -> list | None:
    """A cycle of `graph` (module -> imported modules) by depth-first search, or None."""
    state = {}

    def visit(node, stack):
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt, stack + [nxt])
                if found:
                    return found
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node, [node])
            if found:
                return found
    return None


def test_no_import_cycle():
    """Counting imports inside functions. Importing `jaxhop.x.y` runs `jaxhop.x`'s
    `__init__` too, so a module that reads a name back from the package root closes a
    cycle through it."""
    cycle = _find_cycle(_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_search_finds_cycles():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


PUBLIC = ["jaxhop", "jaxhop.slip", "jaxhop.plot", "jaxhop.mppc", "jaxhop.parkour",
          "jaxhop.mujoco", "jaxhop.reference"]


def _public_callables():
    """Every public function of the public modules, and every method of their public
    classes written by hand (a dataclass's or `equinox.Module`'s generated `__init__` holds
    its fields: data, not a call site)."""
    import importlib

    for modname in PUBLIC:
        module = importlib.import_module(modname)
        for attr in dir(module):
            obj = getattr(module, attr)
            if attr.startswith("_"):
                continue
            if inspect.isfunction(obj):
                yield f"{modname}.{attr}", obj
            elif inspect.isclass(obj):
                for meth, fn in vars(obj).items():
                    fn = getattr(fn, "__func__", fn)
                    written = inspect.isfunction(fn) and fn.__code__.co_filename.endswith(".py")
                    if written and (meth == "__init__" or not meth.startswith("_")):
                        yield f"{modname}.{attr}.{meth}", fn


def test_no_public_function_takes_more_than_8_parameters():
    for name, fn in _public_callables():
        try:
            params = inspect.signature(fn).parameters
        except (TypeError, ValueError):
            continue
        n = len([p for p in params.values() if p.name not in ("self", "cls")
                 and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)])
        assert n <= 8, f"{name} takes {n} parameters"


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
