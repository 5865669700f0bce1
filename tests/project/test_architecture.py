"""The import graph follows the pipeline: no cycles, no import from a lower layer to a higher one.

Every ``import`` of every module is read from the source (module level *and* inside functions:
a lazy import is still a dependency, and so is the string given to ``importlib.import_module`` or
``__import__``), so a hidden cycle such as "the viewer imports the demo, which imports the
viewer" fails here. Every module must be declared in :data:`LAYERS` (a name, or ``pkg.*`` for a
package and everything in it): a new module whose layer nobody chose fails. The engine
(``arsurf``) never imports the viewer (``arsurf_viewer``), except in the commands that open a
view, named in :data:`VIEW_COMMANDS`.
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {"arsurf": ROOT / "arsurf", "arsurf_viewer": ROOT / "viewer"}

#: the pipeline, lowest first (docs/design.rst, "The pipeline"): a module may import its own package and lower layers.
#: An entry is one module, or ``pkg.*``: the package ``pkg`` and every module under it.
LAYERS = [
    ("foundation", ["arsurf", "arsurf.errors", "arsurf.config", "arsurf._validation", "arsurf.status", "arsurf.data.*",
                    "arsurf._logging", "arsurf.units", "arsurf._display", "arsurf._layout", "arsurf._files",
                    "arsurf._h5safe", "arsurf._figure_style", "arsurf._structs"]),
    ("scan", ["arsurf.scan.*"]),
    ("spline", ["arsurf.spline.*"]),
    ("meshes", ["arsurf.export", "arsurf.meshes"]),
    ("contact", ["arsurf.contact.*"]),
    ("force", ["arsurf.force.*"]),
    ("model", ["arsurf.model"]),
    ("devices and objects", ["arsurf.haptics.*", "arsurf.instrument.*", "arsurf.manipulation.*"]),
    ("assembly", ["arsurf.assembly"]),
    ("viewer", ["arsurf_viewer.*"]),
    ("sessions", ["arsurf.sessions.*", "arsurf.feel_scenarios"]),  # record and read session files
    ("replay", ["arsurf.replay.*"]),  # re-run the model over a recorded session
    ("verification", ["arsurf.verify.*"]),  # the model against the scan after a session (arsurf verify)
    ("batch runs", ["arsurf.batch.*"]),  # runs the session pipelines (replay) over many files
    ("live sessions", ["arsurf.live"]),  # the loop on a device and an instrument, recorded (arsurf live)
    ("applications", ["arsurf.demo.*", "arsurf.cli.*", "arsurf.devices"]),
    ("install-time warm-up", ["arsurf.warmup"]),  # runs the demo once to build numba's cache
    ("entry point", ["arsurf.__main__"]),
]

#: the only places of the engine that import the viewer: the commands that open a view or render
#: one, as (module, function). Anywhere else, ``arsurf_viewer`` is out of bounds: ``arsurf live``
#: and ``arsurf demo --no-images`` run on a machine without pyvista (test below).
VIEW_COMMANDS = {
    ("arsurf.cli.view", "_view"),  # arsurf view SCAN: the interactive window / offscreen frames
    ("arsurf.cli.view", "_bridge_view"),  # arsurf view --bridge-port: the window following the live loop
    ("arsurf.cli.view", "_serve_headless"),  # the same without a display: frames of the live loop
    ("arsurf.demo.scripted", "viewer_or_none"),  # arsurf demo (both demos): the PNG views (not with --no-images)
    ("arsurf.replay.replay", "_viewer"),  # arsurf replay --frames N: the replayed frames
}
VIEWER = "arsurf_viewer"


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg, root in PACKAGES.items():
        for path in root.rglob("*.py"):
            parts = [pkg, *path.relative_to(root).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _dynamic_target(node: ast.Call) -> str | None:
    """The module named by ``importlib.import_module("x")`` / ``import_module("x")`` / ``__import__("x")``."""
    f = node.func
    name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None
    if name not in ("import_module", "__import__") or not node.args:
        return None
    arg = node.args[0]
    return arg.value if isinstance(arg, ast.Constant) and isinstance(arg.value, str) else None


@functools.lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), str(path))


def _import_sites(name: str, path: Path):
    """Every (target module, enclosing top-level function or None) an import in ``path`` names."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = _tree(path)
    owners = [(None, tree)]
    for top in tree.body:
        if isinstance(top, (ast.FunctionDef, ast.AsyncFunctionDef)):
            owners.append((top.name, top))
        elif isinstance(top, ast.ClassDef):
            owners += [(f"{top.name}.{f.name}", f) for f in top.body
                       if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))]
    inner = {id(n) for _, o in owners[1:] for n in ast.walk(o)}
    for owner, root in owners:
        for node in ast.walk(root):
            if owner is None and id(node) in inner:
                continue
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                candidates = [target] + [f"{target}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                candidates = [a.name for a in node.names]
            elif isinstance(node, ast.Call) and _dynamic_target(node) is not None:
                candidates = [_dynamic_target(node)]
            else:
                continue
            for c in candidates:
                yield c, owner


def _imports(name: str, path: Path, known) -> set[str]:
    return {c for c, _ in _import_sites(name, path) if c in known and c != name}


def _matches(module: str, entry: str) -> bool:
    if entry.endswith(".*"):
        package = entry[:-2]
        return module == package or module.startswith(package + ".")
    return module == entry


def _layer(module: str) -> tuple[int, str]:
    best = None
    for rank, (_, entries) in enumerate(LAYERS):
        for entry in entries:
            if _matches(module, entry) and (best is None or len(entry) > len(best[1])):
                best = (rank, entry)
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


def test_a_module_nobody_placed_belongs_to_no_layer():
    """A new module under a package declared module by module (``arsurf`` itself) is refused."""
    with pytest.raises(AssertionError, match="belongs to no layer"):
        _layer("arsurf.brand_new_module")
    assert _layer("arsurf.scan.brand_new_reader")[1] == "arsurf.scan.*"
    assert _layer("arsurf") == (0, "arsurf")


def test_the_checker_sees_import_module_and_dunder_import_targets(tmp_path):
    low = tmp_path / "low.py"
    low.write_text("import importlib\n\ndef f():\n    return importlib.import_module('arsurf.demo')\n\n"
                   "def g():\n    return __import__('arsurf_viewer')\n")
    sites = set(_import_sites("arsurf.scan.low", low))
    assert {("arsurf.demo", "f"), ("arsurf_viewer", "g"), ("importlib", None)} <= sites


def _viewer_imports() -> dict:
    """(module, function) -> the arsurf_viewer modules it imports, for every module of the engine."""
    found = {}
    for module, path in MODULES.items():
        if module.split(".")[0] != "arsurf":
            continue
        for target, owner in _import_sites(module, path):
            if target == VIEWER or target.startswith(VIEWER + "."):
                found.setdefault((module, owner), set()).add(target)
    return found


def test_the_engine_imports_the_viewer_only_in_the_commands_that_open_a_view():
    found = _viewer_imports()
    stray = {f"{m}:{f or '<module level>'}": sorted(t) for (m, f), t in found.items() if (m, f) not in VIEW_COMMANDS}
    assert not stray, (f"the engine imports arsurf_viewer outside the view commands: {stray}; move the code to "
                       "the viewer, or (a command that opens a view) add it to VIEW_COMMANDS")
    stale = VIEW_COMMANDS - set(found)
    assert not stale, f"VIEW_COMMANDS names functions that import no viewer (renamed or gone?): {sorted(stale)}"


_NO_VTK = r"""
import runpy, sys
from importlib.abc import MetaPathFinder

class NoViewer(MetaPathFinder):  # pyvista and vtk refused, as on a machine without them, and the viewer
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in REFUSED:
            raise ModuleNotFoundError(f"No module named {name!r} (refused: headless test)", name=name)
        return None

REFUSED = ("pyvista", "vtk", "vtkmodules", "arsurf_viewer")
sys.meta_path.insert(0, NoViewer())
sys.argv = ["arsurf", *sys.argv[1:]]
try:
    runpy.run_module("arsurf", run_name="__main__")
finally:
    leaked = sorted(m for m in sys.modules if m.split(".")[0] in REFUSED)
    assert not leaked, leaked
"""


@pytest.mark.slow
@pytest.mark.parametrize("argv", [["live", "--seconds", "2"], ["demo", "--no-images", "--out", "{tmp}"]],
                         ids=["live", "demo"])
def test_headless_commands_run_where_pyvista_and_vtk_cannot_be_imported(argv, tmp_path):
    """``arsurf live`` (the virtual device) and ``arsurf demo --no-images`` on a lab PC without the viewer
    extra: neither pyvista/vtk nor the viewer package is imported."""
    import subprocess
    import sys

    args = [a.replace("{tmp}", str(tmp_path / "demo")) for a in argv]
    proc = subprocess.run([sys.executable, "-c", _NO_VTK, *args], capture_output=True, text=True, timeout=600,
                          cwd=tmp_path)
    assert proc.returncode == 0, f"arsurf {' '.join(args)} failed without the viewer:\n{proc.stderr[-3000:]}"


def test_tests_import_shared_helpers_from_tests_support_never_another_test_module():
    """The test tree mirrors the packages; what several tests share lives in ``tests/support``: a
    test module never imports another test module, nor ``conftest`` (its fixtures come by name)."""
    bad = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        for node in ast.walk(_tree(path)):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                last = name.split(".")[-1]
                if last == "conftest" or last.startswith("test_"):
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {name}")
    assert not bad, f"move what they share to tests/support: {bad}"
