"""Pin the import structure of ``gltrack``: no import circles, no import by string, and layering.

The layers, lowest first (a module imports only from layers below its own, and of those only
the ones that ``LAYERS`` lists for it):

* leaves: ``npz`` (arrays on disk), ``spawn`` (child processes);
* model: ``body``, ``camera``, then ``motion`` (mocap, priors) and ``export`` (file writers);
* GPU: ``gl`` (context, programs) -> ``render`` (draw a body) -> ``observe`` (likelihoods);
* ``sample`` (samplers and weights; they never import GL), ``evidence`` (bottom-up detectors);
* ``data`` (datasets, simulators), ``eval`` (metrics, overlays);
* ``track`` (trackers), then ``demo`` and ``bench``, and ``cli`` on top, which may import anything.

Everything here reads the source with :mod:`ast`; nothing of ``gltrack`` is imported, no GL is
needed. Imports inside functions count like module-level ones (a lazy import is still a
dependency); only imports under ``if TYPE_CHECKING:`` are left out of the circle check, since they
never run.
"""
from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "gltrack"

# ---------------------------------------------------------------------------------------------
# The layering: unit -> the other units of gltrack it may import. A unit is the first component
# below ``gltrack`` (a sub-package or a top-level module); a unit may always import itself.
# ---------------------------------------------------------------------------------------------
_BELOW_TRACK = {"npz", "spawn", "body", "camera", "motion", "export", "gl", "render", "observe",
                "sample", "evidence", "data", "eval"}

LAYERS: dict[str, set[str]] = {
    # The root ``__init__`` runs before every ``gltrack.*`` import: it imports nothing of ours.
    # (Anyone may ``import gltrack`` itself, e.g. for ``__version__``.)
    "": set(),
    "npz": set(),
    "spawn": set(),
    "body": {"npz"},
    "camera": {"npz"},
    "motion": {"body", "camera", "npz"},
    # Writers of tracked motion (BVH, glTF, TRC, JSON): the skeleton, its DOFs, motion's BVH.
    "export": {"body", "camera", "motion", "npz"},
    "gl": {"npz"},
    "render": {"gl", "body", "camera", "npz", "spawn"},
    # Likelihoods render the body model. Motion priors (VLMM, behaviour models) are combined
    # with likelihoods by the trackers, so observe never imports motion.
    "observe": {"render", "gl", "body", "camera", "npz", "spawn"},
    # "Samplers never import GL": they see a cost function and the body's DOFs only.
    "sample": {"body", "npz"},
    # Bottom-up part detection: features on depth images, IK on the body (UT sigma points may
    # come from sample); synthetic training frames are rendered with render's reference
    # renderer, which may run in a spawned child. No GL context of its own (gl).
    "evidence": {"body", "camera", "sample", "observe", "render", "npz", "spawn"},
    # Datasets and their simulators: the simulator poses the body (motion capture through
    # motion) and renders it with render's reference renderer in a spawned child (its own GL
    # platform), so gl's moderngl context is not needed; its masks come from observe's
    # background subtraction (observe.background: numpy and OpenCV, no GL).
    "data": {"body", "camera", "render", "observe", "motion", "npz", "spawn"},
    # Metrics over results and datasets; overlays drawn with render (gl for a GL context),
    # tracked motion as written by export.
    "eval": {"data", "body", "camera", "render", "gl", "motion", "npz", "export", "spawn"},
    "track": set(_BELOW_TRACK),
    "demo": _BELOW_TRACK | {"track"},
    "bench": _BELOW_TRACK | {"track", "demo"},
    "cli": _BELOW_TRACK | {"track", "demo", "bench"},
    # ``python -m gltrack`` is the command line.
    "__main__": {"cli"},
}

#: Units that may ``import moderngl`` directly; everyone else gets GL through ``gl``/``render``.
#: ``observe`` builds its environment (background) textures and programs on the shared context;
#: ``bench`` times the engine against raw-moderngl baselines. (eval's overlays use render.)
MODERNGL_UNITS = {"gl", "render", "observe", "bench"}

#: ``importlib`` parts that may be imported: data files, package metadata, and ``util`` for
#: ``find_spec`` of optional third-party packages (pyrender, ray, ...).
_ALLOWED_IMPORTLIB = {"importlib.resources", "importlib.metadata", "importlib.util"}
#: ``"gltrack.a.b:attr"`` specs that a registry resolves with ``importlib`` at runtime.
_SPEC_RE = re.compile(r"^gltrack(\.[A-Za-z_]\w*)*:[A-Za-z_][\w.]*$")


# ---------------------------------------------------------------------------------------------
# Reading the source.
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Import:
    """One dependency ``source -> target`` (both dotted module names) found at ``where``."""
    source: str
    target: str
    where: str  # "gltrack/sub/file.py:LINE"
    type_checking: bool = False


def _relpath(module: str, path: Path) -> str:
    """``path`` relative to the folder that holds the top package (``gltrack/sample/sir.py``)."""
    depth = len(module.split(".")) - (0 if path.name == "__init__.py" else 1)
    return path.relative_to(path.parents[depth]).as_posix()


def collect_modules(src_root: Path, package: str = PACKAGE) -> dict[str, Path]:
    """Dotted module name -> source file for every ``.py`` under ``src_root/package``.

    A package's ``__init__.py`` is its own node, named like the package (``gltrack.sample``).
    """
    mods = {}
    for path in sorted((Path(src_root) / package).rglob("*.py")):
        parts = list(path.relative_to(src_root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        mods[".".join(parts)] = path
    return mods


def _walk(tree: ast.AST) -> list[ast.AST]:
    """All nodes of ``tree`` (``ast.walk``, computed once per tree: the checks share it)."""
    nodes = getattr(tree, "_all_nodes", None)
    if nodes is None:
        nodes = tree._all_nodes = list(ast.walk(tree))
    return nodes


def _is_package(name: str, modules: dict[str, Path]) -> bool:
    return name in modules and modules[name].name == "__init__.py"


def _resolve_base(source: str, node: ast.ImportFrom, modules: dict[str, Path]) -> str | None:
    """The absolute module named by ``from <base> import ...`` in ``source`` (None: not ours)."""
    if not node.level:
        return node.module
    # Relative: ``from . import x`` in gltrack/a/b.py is gltrack.a; in gltrack/a/__init__.py too.
    pkg = source if _is_package(source, modules) else source.rpartition(".")[0]
    parts = pkg.split(".")
    if node.level - 1 > len(parts) - 1:
        return None
    base = ".".join(parts[: len(parts) - (node.level - 1)])
    return f"{base}.{node.module}" if node.module else base


def _nearest_module(name: str, modules: dict[str, Path]) -> str | None:
    """``name`` or its nearest enclosing module that exists in ``modules``."""
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


def _type_checking_lines(tree: ast.AST) -> set[int]:
    """Line numbers of statements under ``if TYPE_CHECKING:`` (imports that never run)."""
    lines = set()
    for node in _walk(tree):
        if isinstance(node, ast.If):
            test = node.test
            name = test.id if isinstance(test, ast.Name) else getattr(test, "attr", None)
            if name == "TYPE_CHECKING":
                for stmt in node.body:
                    for sub in ast.walk(stmt):
                        if hasattr(sub, "lineno"):
                            lines.add(sub.lineno)
    return lines


def _reexports(init: str, modules: dict[str, Path], trees: dict[str, ast.AST]) -> dict[str, str]:
    """Names that the package ``init`` takes from its own submodules -> that submodule."""
    out = {}
    for node in _walk(trees[init]):
        if isinstance(node, ast.ImportFrom):
            base = _resolve_base(init, node, modules)
            if base and base != init and base.startswith(init + ".") and base in modules:
                for alias in node.names:
                    out[alias.asname or alias.name] = base
    return out


def parse_trees(modules: dict[str, Path]) -> dict[str, ast.AST]:
    """Module name -> parsed syntax tree."""
    return {name: ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for name, path in modules.items()}


def find_imports(modules: dict[str, Path], trees: dict[str, ast.AST] | None = None,
                 package: str = PACKAGE) -> list[Import]:
    """Every import of a module of ``package`` by a module of ``package``, functions included.

    ``from pkg import name`` goes to ``pkg.name`` when that is a module. Otherwise the name lives
    in ``pkg/__init__.py``; when the importer sits inside ``pkg`` itself and ``__init__`` only
    re-exports ``name`` from a sibling, the edge goes to that sibling (the importer needs the
    sibling, not the package namespace), else to ``pkg``.
    """
    trees = trees if trees is not None else parse_trees(modules)
    found: dict[Import, None] = {}  # ordered set
    reexports = {name: _reexports(name, modules, trees) for name in modules
                 if _is_package(name, modules)}
    for source, tree in trees.items():
        tc_lines = _type_checking_lines(tree)
        rel = _relpath(source, modules[source])

        def add(target: str | None, node: ast.AST) -> None:
            if target and target != source and (target == package
                                                 or target.startswith(package + ".")):
                target = _nearest_module(target, modules)
                if target and target != source:
                    found[Import(source, target, f"{rel}:{node.lineno}",
                                 node.lineno in tc_lines)] = None

        for node in _walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    add(alias.name, node)
            elif isinstance(node, ast.ImportFrom):
                base = _resolve_base(source, node, modules)
                if base is None or not (base == package or base.startswith(package + ".")):
                    continue
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    if sub in modules:
                        add(sub, node)
                    elif _is_package(base, modules) and source.startswith(base + "."):
                        add(reexports[base].get(alias.name, base), node)
                    else:
                        add(base, node)
    return list(found)


def _top_level_names(tree: ast.AST) -> set[str] | None:
    """Names a module binds at import time (None: it has ``import *`` or ``__getattr__``)."""
    names: set[str] = set()
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            for alias in node.names:
                if alias.name == "*":
                    return None
                names.add(alias.asname or alias.name.partition(".")[0])
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                names.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.If, ast.Try, ast.With, ast.For, ast.While)):
            for field in ("body", "orelse", "finalbody", "handlers"):
                stack.extend(getattr(node, field, []))
        elif isinstance(node, ast.ExceptHandler):
            stack.extend(node.body)
    return None if "__getattr__" in names else names


def unresolved_imports(modules: dict[str, Path], trees: dict[str, ast.AST],
                       package: str = PACKAGE) -> list[str]:
    """``path:line: what`` for imports of ``package`` modules or names that do not exist.

    The graph maps a missing module to its nearest existing parent, which would hide edges; a
    stale import after a move (``from gltrack.old.place import thing``) shows up here.
    """
    bound = {name: _top_level_names(tree) for name, tree in trees.items()}
    bad = []
    for source, tree in trees.items():
        rel = _relpath(source, modules[source])
        for node in _walk(tree):
            if isinstance(node, ast.Import):
                bad += [f"{rel}:{node.lineno}: no module {a.name}" for a in node.names
                        if a.name.split(".")[0] == package and a.name not in modules]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve_base(source, node, modules)
                if base is None or base.split(".")[0] != package:
                    continue
                if base not in modules:
                    bad.append(f"{rel}:{node.lineno}: no module {base}")
                    continue
                names = bound[base]
                for alias in node.names:
                    if (names is not None and alias.name != "*" and alias.name not in names
                            and f"{base}.{alias.name}" not in modules):
                        bad.append(f"{rel}:{node.lineno}: {base} has no {alias.name}")
    return sorted(set(bad))


# ---------------------------------------------------------------------------------------------
# Import by string.
# ---------------------------------------------------------------------------------------------
def _dotted(node: ast.AST) -> str:
    """``a.b.c`` for a Name/Attribute chain, else ''."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        head = _dotted(node.value)
        return f"{head}.{node.attr}" if head else ""
    return ""


def _string_value(node: ast.AST) -> str | None:
    """The text of a string constant, or the literal head of an f-string."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value for v in node.values
                       if isinstance(v, ast.Constant) and isinstance(v.value, str))
    return None


def _docstring_nodes(tree: ast.AST) -> set[int]:
    """``id()`` of the docstring constants of the module, classes and functions."""
    out = set()
    for node in _walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def string_imports(modules: dict[str, Path], trees: dict[str, ast.AST] | None = None,
                   package: str = PACKAGE) -> list[str]:
    """``path:line: what`` for every import by string in ``modules``.

    Flagged: ``import_module``/``__import__``/``importlib.reload``/``spec_from_file_location``/
    ``module_from_spec``/``runpy``/``pkgutil`` loading; ``find_spec`` of a ``package`` module
    (checking an optional third-party package such as ``pyrender`` is fine); and ``"pkg.mod:attr"``
    strings that name a ``package`` module (specs resolved at runtime). A bare ``"pkg.mod"``
    string is fine by itself (a logger or provenance name); loading it needs one of the calls.
    ``importlib.resources`` and ``importlib.metadata`` are fine.
    """
    trees = trees if trees is not None else parse_trees(modules)
    bad = []
    loaders = {"import_module", "__import__", "importlib.reload", "spec_from_file_location",
               "module_from_spec", "exec_module", "run_module", "run_path", "iter_modules",
               "walk_packages"}
    for name, tree in trees.items():
        where = _relpath(name, modules[name])
        docs = _docstring_nodes(tree)
        for node in _walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in ("pkgutil", "runpy"):
                        bad.append(f"{where}:{node.lineno}: import {alias.name}")
                    elif (alias.name.startswith("importlib.")
                          and alias.name not in _ALLOWED_IMPORTLIB):
                        bad.append(f"{where}:{node.lineno}: import {alias.name}")
            elif isinstance(node, ast.ImportFrom) and node.module in ("importlib", "importlib.util",
                                                                       "pkgutil", "runpy"):
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    if full not in _ALLOWED_IMPORTLIB and alias.name != "find_spec":
                        bad.append(f"{where}:{node.lineno}: from {node.module} import {alias.name}")
            elif isinstance(node, ast.Call):
                func = _dotted(node.func)
                last = func.rpartition(".")[2]
                if last in loaders or func in loaders:
                    bad.append(f"{where}:{node.lineno}: {func}(...)")
                elif last == "find_spec" and node.args:
                    arg = _string_value(node.args[0])
                    if arg is None or arg == package or arg.startswith(package + "."):
                        bad.append(f"{where}:{node.lineno}: {func}({arg!r})")
            elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
                  and id(node) not in docs and _SPEC_RE.match(node.value)):
                bad.append(f"{where}:{node.lineno}: spec string {node.value!r}")
    return sorted(set(bad))


# ---------------------------------------------------------------------------------------------
# Circles.
# ---------------------------------------------------------------------------------------------
def import_graph(imports: list[Import]) -> dict[str, set[str]]:
    """Module -> the modules it imports at runtime (``TYPE_CHECKING`` imports left out)."""
    graph: dict[str, set[str]] = {}
    for imp in imports:
        graph.setdefault(imp.target, set())
        if not imp.type_checking:
            graph.setdefault(imp.source, set()).add(imp.target)
    return graph


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (iterative Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    comps = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        top = stack.pop()
                        on_stack.discard(top)
                        comp.append(top)
                        if top == node:
                            break
                    if len(comp) > 1:
                        comps.append(sorted(comp))
    return sorted(comps)


def _cycle_in(comp: list[str], graph: dict[str, set[str]]) -> list[str]:
    """One concrete circle through the first node of ``comp`` (breadth-first, shortest)."""
    members = set(comp)
    start = comp[0]
    prev = {start: None}
    queue = [start]
    while queue:
        node = queue.pop(0)
        for nxt in sorted(graph[node] & members):
            if nxt == start:
                path = [node]
                while prev[path[-1]] is not None:
                    path.append(prev[path[-1]])
                return list(reversed(path)) + [start]
            if nxt not in prev:
                prev[nxt] = node
                queue.append(nxt)
    return comp


def describe_cycles(imports: list[Import]) -> list[str]:
    """Per strongly connected component: its members, one circle, and every edge inside it."""
    graph = import_graph(imports)
    where = {}
    for imp in imports:
        if not imp.type_checking:
            where.setdefault((imp.source, imp.target), imp.where)
    out = []
    for comp in strongly_connected(graph):
        circle = _cycle_in(comp, graph)
        steps = " -> ".join(f"{a} ({where[a, b]})" for a, b in zip(circle, circle[1:]))
        inside = sorted(f"{where[a, b]}: {a} -> {b}" for a in comp for b in graph[a] if b in comp)
        out.append(f"{{{', '.join(comp)}}}: {steps} -> {circle[-1]}\n    edges inside: "
                   + "\n                  ".join(inside))
    return out


# ---------------------------------------------------------------------------------------------
# Layers.
# ---------------------------------------------------------------------------------------------
def unit_of(module: str, package: str = PACKAGE) -> str:
    """The layering unit of a module: ``gltrack.sample.sir`` -> ``sample``; the root -> ''."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == package else ""


def layer_violations(imports: list[Import], layers: dict[str, set[str]],
                     package: str = PACKAGE) -> list[str]:
    """``path:line: a -> b`` for every import that ``layers`` does not allow.

    Every unit found must appear in ``layers`` (a new sub-package needs a place in the table);
    the root ``__init__`` is the unit ''. Importing the bare root package (``import gltrack`` for
    ``__version__``) is always allowed.
    """
    bad = []
    for imp in imports:
        src, dst = unit_of(imp.source, package), unit_of(imp.target, package)
        if imp.target == package or src == dst:
            continue
        if src not in layers:
            bad.append(f"{imp.where}: unit {src!r} has no place in the layer table")
        elif dst not in layers[src]:
            bad.append(f"{imp.where}: {imp.source} -> {imp.target} ({src} may not import {dst})")
    return sorted(set(bad))


def third_party_imports(modules: dict[str, Path], trees: dict[str, ast.AST], top: str) -> set[str]:
    """The modules of ``modules`` that import the third-party package ``top`` (any depth)."""
    users = set()
    for name, tree in trees.items():
        for node in _walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                     else [])
            if any(n == top or n.startswith(top + ".") for n in names):
                users.add(name)
    return users


# ---------------------------------------------------------------------------------------------
# The tests over gltrack/.
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tree():
    modules = collect_modules(REPO)
    trees = parse_trees(modules)
    return modules, trees, find_imports(modules, trees)


def test_no_import_by_string(tree):
    modules, trees, _ = tree
    bad = string_imports(modules, trees)
    assert not bad, "imports by string in gltrack/ (use a plain import):\n" + "\n".join(bad)


def test_imports_resolve(tree):
    modules, trees, _ = tree
    bad = unresolved_imports(modules, trees)
    assert not bad, "imports of gltrack names that do not exist:\n" + "\n".join(bad)


def test_no_import_cycles(tree):
    _, _, imports = tree
    cycles = describe_cycles(imports)
    assert not cycles, "import circles in gltrack/:\n" + "\n".join(cycles)


def test_layers(tree):
    _, _, imports = tree
    bad = layer_violations(imports, LAYERS)
    assert not bad, "imports against the layering:\n" + "\n".join(bad)


def test_samplers_never_import_gl(tree):
    _, _, imports = tree
    gl_side = {"gl", "render", "observe"}
    bad = sorted(f"{i.where}: {i.source} -> {i.target}" for i in imports
                 if unit_of(i.source) == "sample" and unit_of(i.target) in gl_side)
    assert not bad, "samplers import GL:\n" + "\n".join(bad)


def test_moderngl_only_in_gpu_layers(tree):
    modules, trees, _ = tree
    users = third_party_imports(modules, trees, "moderngl")
    bad = sorted(u for u in users if unit_of(u) not in MODERNGL_UNITS)
    assert not bad, "moderngl imported outside " + ", ".join(sorted(MODERNGL_UNITS)) + f": {bad}"


def test_table_covers_the_package(tree):
    modules, _, _ = tree
    units = {unit_of(m) for m in modules}
    assert units <= set(LAYERS), f"units without a place in LAYERS: {sorted(units - set(LAYERS))}"
    for unit, allowed in LAYERS.items():
        assert unit not in allowed
        assert "cli" not in allowed or unit == "__main__", f"{unit} may not import cli"
        assert "bench" not in allowed or unit == "cli", f"{unit} may not import bench"


# ---------------------------------------------------------------------------------------------
# The checker finds what it should (so the tests above can fail).
# ---------------------------------------------------------------------------------------------
_FAKE = {
    "gltrack/__init__.py": "",
    "gltrack/npz.py": "import numpy\n",
    "gltrack/sample/__init__.py": "from .sir import SIR\nLIMIT = 3\n",
    "gltrack/sample/sir.py": (
        "from gltrack.sample import base\n"      # a submodule through the package: -> base
        "from gltrack.sample import SIR as S2\n"  # a re-export of a sibling: -> sir (itself)
        "class SIR:\n    pass\n"),
    "gltrack/sample/base.py": (
        '"""Docstring naming gltrack.sample.sir:SIR is fine."""\n'
        "from gltrack import npz\n"
        "def f():\n    from gltrack.render.engine import Engine\n"),  # layer violation
    "gltrack/render/__init__.py": "",
    "gltrack/render/engine.py": "import moderngl\nfrom gltrack.render import scene\nEngine = 1\n",
    "gltrack/render/scene.py": "def g():\n    from . import engine\n",  # circle engine <-> scene
    "gltrack/track/__init__.py": "",
    "gltrack/track/runner.py": (
        "import importlib\nimport importlib.util\nfrom importlib import resources\n"
        "M = {'hc': 'gltrack.track.depth:Tracker'}\n"
        "def load(name):\n"
        "    importlib.util.find_spec('pyrender')\n"  # third-party check: fine
        "    importlib.util.find_spec('gltrack.cli.synth')\n"
        "    return importlib.import_module(f'gltrack.track.{name}')\n"
        "from gltrack.track import depth\n"),  # depth imports runner only for type checking
    "gltrack/track/depth.py": (
        "from typing import TYPE_CHECKING\n"
        "from gltrack.sample import LIMIT, NOPE\n"  # NOPE: a stale name
        "if TYPE_CHECKING:\n    from gltrack.track import runner\n"
        "def h():\n    import gltrack.gone.away\n"),  # a stale module
    "gltrack/bench/__init__.py": "",
    "gltrack/bench/run.py": "import moderngl\n",
    "gltrack/cli/__init__.py": "import gltrack.bench.run\n",
    "gltrack/eval/__init__.py": "import moderngl.context\nimport gltrack.cli\n",
}


@pytest.fixture
def fake(tmp_path):
    for rel, text in _FAKE.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    modules = collect_modules(tmp_path)
    trees = parse_trees(modules)
    return modules, trees, find_imports(modules, trees)


def test_checker_resolves_imports(fake):
    _, _, imports = fake
    edges = {(i.source, i.target) for i in imports}
    assert ("gltrack.sample.sir", "gltrack.sample.base") in edges
    assert ("gltrack.sample.sir", "gltrack.sample") not in edges
    assert ("gltrack.sample", "gltrack.sample.sir") in edges
    assert ("gltrack.sample.base", "gltrack.npz") in edges
    assert ("gltrack.sample.base", "gltrack.render.engine") in edges  # inside a function
    assert ("gltrack.render.scene", "gltrack.render.engine") in edges  # relative, in a function
    assert ("gltrack.track.depth", "gltrack.sample") in edges  # a name of the package __init__
    assert ("gltrack.cli", "gltrack.bench.run") in edges
    assert ("gltrack.track.runner", "gltrack.track.depth") in edges
    assert [i.type_checking for i in imports if i.source == "gltrack.track.depth"
            and i.target == "gltrack.track.runner"] == [True]


def test_checker_finds_circles(fake):
    _, _, imports = fake
    cycles = describe_cycles(imports)
    assert len(cycles) == 1, cycles
    assert cycles[0].startswith("{gltrack.render.engine, gltrack.render.scene}")
    # runner -> depth -> runner is no circle: depth imports runner only under TYPE_CHECKING.
    # A runtime import would make it one.
    graph = import_graph(imports)
    graph["gltrack.track.depth"].add("gltrack.track.runner")
    assert ["gltrack.track.depth", "gltrack.track.runner"] in strongly_connected(graph)


def test_checker_finds_string_imports(fake):
    modules, trees, _ = fake
    bad = "\n".join(string_imports(modules, trees))
    assert "runner.py:4: spec string 'gltrack.track.depth:Tracker'" in bad
    assert "runner.py:7: importlib.util.find_spec('gltrack.cli.synth')" in bad
    assert "runner.py:8: importlib.import_module(...)" in bad
    assert "pyrender" not in bad and "resources" not in bad and "base.py" not in bad
    assert len(bad.splitlines()) == 3, bad


def test_checker_finds_unresolved_imports(fake):
    modules, trees, _ = fake
    assert unresolved_imports(modules, trees) == [
        "gltrack/track/depth.py:2: gltrack.sample has no NOPE",
        "gltrack/track/depth.py:6: no module gltrack.gone.away"]


def test_checker_finds_layer_violations(fake):
    modules, trees, imports = fake
    bad = "\n".join(layer_violations(imports, LAYERS))
    assert "gltrack.sample.base -> gltrack.render.engine (sample may not import render)" in bad
    assert "gltrack.eval -> gltrack.cli (eval may not import cli)" in bad
    assert "cli" not in bad.replace("eval may not import cli", "").replace("gltrack.cli", "")
    assert len(bad.splitlines()) == 2, bad
    users = third_party_imports(modules, trees, "moderngl")
    assert users == {"gltrack.render.engine", "gltrack.bench.run", "gltrack.eval"}
    with_layers = {**LAYERS, "sample": LAYERS["sample"] | {"render"}, "eval": {"cli"}}
    assert not layer_violations(imports, with_layers)
    assert "has no place" in "".join(layer_violations(imports, {"sample": set()}))
