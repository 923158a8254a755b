"""The packages form one-way layers with no circles (docs/ARCHITECTURE.md).

Read from the source with ``ast``, imports inside functions included (a lazy import still runs
up the layers when it runs):

    assetpipe.core                       errors, digests, KTX2, atomic writes, rows: imports only itself
    assetpipe.cache, assetpipe.pipelines the store; the pure steps: import core (and themselves)
    assetpipe.renderer                   loader, renderer, validator: imports core and cache
    assetpipe (its own modules)          orchestration and the CLI: may import everything
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = {"assetpipe.core": ROOT / "assetpipe" / "core", "assetpipe.cache": ROOT / "cache",
            "assetpipe.pipelines": ROOT / "pipelines", "assetpipe.renderer": ROOT / "renderer",
            "assetpipe": ROOT / "assetpipe"}
LAYER = {"assetpipe.core": 0, "assetpipe.cache": 1, "assetpipe.pipelines": 1, "assetpipe.renderer": 2,
         "assetpipe": 3}
# what each package may import besides itself
ALLOWED = {"assetpipe.core": set(), "assetpipe.cache": {"assetpipe.core"},
           "assetpipe.pipelines": {"assetpipe.core"},
           "assetpipe.renderer": {"assetpipe.core", "assetpipe.cache"},
           "assetpipe": {"assetpipe.core", "assetpipe.cache", "assetpipe.pipelines", "assetpipe.renderer"}}


def _modules() -> dict[str, Path]:
    """Every module of every package, subpackages included (``renderer/checks/*.py`` is
    ``assetpipe.renderer.checks.*``); a folder that is another package's (``assetpipe/core``
    under ``assetpipe``) belongs to that package, not twice."""
    mods = {}
    others = {f.resolve() for f in PACKAGES.values()}
    for pkg, folder in PACKAGES.items():
        for f in sorted(folder.rglob("*.py")):
            rel = f.relative_to(folder)
            inner = [folder.joinpath(*rel.parts[:i]).resolve() for i in range(1, len(rel.parts))]
            if any(d in others for d in inner) or not all((d / "__init__.py").is_file() for d in inner):
                continue  # another package's folder, or not a package (no __init__.py)
            parts = list(rel.parts[:-1]) + ([] if f.stem == "__init__" else [f.stem])
            mods.setdefault(".".join([pkg, *parts]), f)
    return mods


def _package_of(module: str) -> str:
    for pkg in sorted(PACKAGES, key=len, reverse=True):
        if module == pkg or module.startswith(pkg + "."):
            return pkg
    raise AssertionError(module)


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """Our modules that ``name`` imports (absolute and relative, anywhere in the file)."""
    is_pkg = path.stem == "__init__"
    base = name if is_pkg else name.rsplit(".", 1)[0]
    out = set()
    tree = ast.parse(path.read_text(), str(path))
    if name == "assetpipe":  # the root's lazy API hooks: checked by their own test below
        tree = _root_top_level(tree)
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = base.split(".")
                parent = ".".join(parts[: len(parts) - (node.level - 1)])
                mod = f"{parent}.{node.module}" if node.module else parent
            else:
                mod = node.module or ""
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        for t in targets:
            # the longest known module that t names (``from x import y``: y may be a module)
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    return {name: _imports(name, path, known) for name, path in mods.items()}


def test_the_graph_reader_sees_imports():
    graph = _graph()
    assert "assetpipe.core.errors" in graph["assetpipe.pipelines.import_gltf"]
    assert "assetpipe.renderer.validate" in graph["assetpipe.renderer.batch"]  # a relative import
    assert "assetpipe.pipelines.lod" in graph["assetpipe.steps"]  # a lazy import inside a function
    # subpackages are scanned, their relative imports resolved from the subpackage
    assert "assetpipe.renderer.checks.base" in graph["assetpipe.renderer.checks.textures"]
    assert "assetpipe.renderer.loader" in graph["assetpipe.renderer.checks.textures"]  # ``from ..loader``
    assert "assetpipe.renderer.checks" in graph["assetpipe.renderer.validate"]
    assert "assetpipe.renderer.checks.ktx2_levels" in graph["assetpipe.renderer.checks.roles"]


def test_no_import_runs_up_the_layers():
    bad = []
    for mod, deps in _graph().items():
        pkg = _package_of(mod)
        for d in deps:
            dpkg = _package_of(d)
            if dpkg != pkg and dpkg not in ALLOWED[pkg]:
                bad.append(f"{mod} (layer {LAYER[pkg]}) imports {d} (layer {LAYER[dpkg]})")
    assert bad == []


def _root_top_level(tree: ast.Module) -> ast.Module:
    """The package root without its functions and classes (the lazy API hooks: PEP 562
    ``__getattr__`` and the callable ``assetpipe.build``), which import only when an API name is
    first used, long after ``import assetpipe`` finished."""
    return ast.Module(body=[n for n in tree.body if not isinstance(n, (ast.FunctionDef, ast.ClassDef))],
                      type_ignores=[])


def _names_imported(tree: ast.AST) -> set[str]:
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    return imported | {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}


def test_the_package_root_imports_only_the_standard_library():
    """``import assetpipe`` (which every ``assetpipe.*`` import runs first) stays light and
    pulls no layer in: at import time only ``os`` and ``sys``; the API is imported lazily, by
    the PEP 562 ``__getattr__`` and the callable ``assetpipe.build``, and nothing else is."""
    tree = ast.parse((ROOT / "assetpipe" / "__init__.py").read_text())
    assert _names_imported(_root_top_level(tree)) == {"os", "sys"}
    lazy = {n.name: _names_imported(n) for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    assert {k: v for k, v in lazy.items() if v} == {"__getattr__": {"assetpipe", "assetpipe.build"},
                                                     "_BuildModule": {"assetpipe.api"}}
    top_imports = [n for n in ast.walk(_root_top_level(tree)) if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert all(n in tree.body for n in top_imports)  # no import hidden in a top-level if/try either


def test_import_assetpipe_loads_no_layer_and_no_numpy():
    code = ("import sys, assetpipe; assetpipe.__version__; "
            "print(sorted(m for m in sys.modules if m.startswith('assetpipe') or m == 'numpy'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}).stdout
    assert out.strip() == "['assetpipe']"


def test_no_circles_between_modules():
    graph = _graph()
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert cycles == []


def test_nothing_imports_the_old_top_level_names():
    """``pipelines``, ``cache`` and ``renderer`` install as ``assetpipe.*``: importing the bare
    names would load a second copy of each module (two classes of one name)."""
    bad = []
    for folder in [*PACKAGES.values(), ROOT / "tests", ROOT / "benchmarks", ROOT / "examples"]:
        for f in folder.rglob("*.py"):
            for node in ast.walk(ast.parse(f.read_text(), str(f))):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                         else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
                bad += [f"{f.relative_to(ROOT)}: {n}" for n in names
                        if n.split(".")[0] in ("pipelines", "cache", "renderer")]
    assert bad == []
