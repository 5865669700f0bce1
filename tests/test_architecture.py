"""The import graph follows the pipeline: no cycles, no import from a lower layer to a higher one.

Every ``import`` of every module is read from the source (module level *and* inside functions:
a lazy import is still a dependency), so a hidden cycle such as "the viewer imports the demo,
which imports the viewer" fails here.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"arsurf": ROOT / "arsurf", "arsurf_viewer": ROOT / "viewer"}

#: the pipeline, lowest first (DESIGN.md): a module may import its own package and lower layers
LAYERS = [
    ("foundation", ["arsurf", "arsurf.errors", "arsurf._validation", "arsurf.status", "arsurf.data", "arsurf._logging",
                    "arsurf.units", "arsurf._display"]),
    ("scan", ["arsurf.scan"]),
    ("spline", ["arsurf.spline"]),
    ("meshes", ["arsurf.export", "arsurf.meshes"]),
    ("contact", ["arsurf.contact"]),
    ("force", ["arsurf.force"]),
    ("model", ["arsurf.model"]),
    ("devices and objects", ["arsurf.haptics", "arsurf.instrument", "arsurf.manipulation"]),
    ("assembly", ["arsurf.assembly"]),
    ("viewer", ["arsurf_viewer"]),
    ("sessions", ["arsurf.sessions", "arsurf.feel_scenarios"]),  # record and read session files
    ("replay", ["arsurf.replay"]),  # re-run the model over a recorded session
    ("batch runs", ["arsurf.batch"]),  # runs the session pipelines (replay) over many files
    ("live sessions", ["arsurf.live"]),  # the loop on a device and an instrument, recorded (arsurf live)
    ("applications", ["arsurf.demo", "arsurf.cli", "arsurf.devices", "arsurf.warmup"]),
    ("entry point", ["arsurf.__main__"]),
]


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg, root in PACKAGES.items():
        for path in root.rglob("*.py"):
            parts = [pkg, *path.relative_to(root).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _imports(name: str, path: Path, known) -> set[str]:
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            candidates = [target] + [f"{target}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            candidates = [a.name for a in node.names]
        else:
            continue
        found.update(c for c in candidates if c in known and c != name)
    return found


def _layer(module: str) -> tuple[int, str]:
    best = None
    for rank, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if module == prefix or module.startswith(prefix + "."):
                if best is None or len(prefix) > len(best[1]):
                    best = (rank, prefix)
    if best is None:
        raise AssertionError(f"module {module} belongs to no layer: add it to LAYERS in {__file__}")
    return best


MODULES = _modules()
GRAPH = {m: _imports(m, p, MODULES) for m, p in MODULES.items()}


def test_every_module_has_a_layer():
    for m in MODULES:
        _layer(m)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_upward_or_sideways_import(module):
    rank, group = _layer(module)
    for target in sorted(GRAPH[module]):
        t_rank, t_group = _layer(target)
        if target == "arsurf":  # the package itself: lazy re-exports only
            continue
        assert t_rank <= rank, (f"{module} ({LAYERS[rank][0]}) imports {target} ({LAYERS[t_rank][0]}), "
                                "a higher layer of the pipeline")
        if t_rank == rank and t_rank > 0:
            assert t_group == group, f"{module} imports {target}: sibling packages of one layer stay independent"


def test_no_import_cycles():
    """Tarjan's strongly connected components of the import graph are all single modules."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v] - {"arsurf"}:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_the_checker_sees_a_cycle_and_an_upward_import(tmp_path):
    """The graph reader itself: a lazy upward import inside a function is found."""
    low = tmp_path / "low.py"
    low.write_text("def f():\n    from arsurf.demo import run_demo\n")
    found = _imports("arsurf.scan.low", low, {"arsurf.demo", "arsurf.scan.low"})
    assert found == {"arsurf.demo"}
    assert _layer("arsurf.demo")[0] > _layer("arsurf.scan.low")[0]
