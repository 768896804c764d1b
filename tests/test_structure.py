"""The shape of the code, read from the source with :mod:`ast` alone (nothing here imports the
packages): no import circle, no long function, no long file and no crowded folder in any of the
four packages, no private module imported across packages, docs/architecture.md naming every
subpackage, and the knowledge that was once copied from place to place (the Des18 effect set,
the photo effect set, the stored normal encoding, the file lock) written in one place."""

from __future__ import annotations

import ast
import re
import tokenize
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: distribution folder -> import name
PACKAGES = {
    "svbrdf-render": "svbrdf_render",
    "svbrdf-models": "svbrdf_models",
    "svbrdf-train": "svbrdf_train",
    "svbrdf-bench": "svbrdf_bench",
}
#: The longest function or method (``def`` line to last line, docstring included): one screen.
MAX_FUNCTION_LINES = 60
#: The longest module under a package's ``src/``: past it a file holds more than one idea.
MAX_FILE_LINES = 500


# -- the module graph -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Module:
    name: str  # dotted: "svbrdf_render.refinement.fit"; a package's __init__ is the package's name
    path: Path

    @property
    def is_package(self) -> bool:
        return self.path.name == "__init__.py"

    @property
    def package(self) -> str:
        """The package relative imports start from: the module's own for an ``__init__``."""
        return self.name if self.is_package else self.name.rpartition(".")[0]


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    line: int


def _modules() -> dict[str, Module]:
    out = {}
    for dist, name in PACKAGES.items():
        root = REPO / "packages" / dist / "src"
        for path in sorted((root / name).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = Module(".".join(parts), path)
    return out


def _resolve_from(module: Module, node: ast.ImportFrom) -> str:
    """The absolute module of a ``from X import ...`` (relative ones resolved by their level)."""
    if node.level == 0:
        return node.module or ""
    base = module.package.split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, *([node.module] if node.module else [])])


def _edges(module: Module, modules: dict[str, Module]) -> list[Edge]:
    """Every import of ``module`` of a module of the workspace, at any depth (an import inside a
    function closes a circle as surely as one at the top). ``from pkg import name`` is an edge to
    the submodule ``pkg.name`` when there is one, else to ``pkg`` (its ``__init__``)."""
    tree = ast.parse(module.path.read_text(), filename=str(module.path))
    out = []
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve_from(module, node)
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                targets.append(sub if sub in modules else base)
        out += [Edge(module.name, t, node.lineno) for t in targets if t in modules and t != module.name]
    return out


def _graph() -> dict[str, list[Edge]]:
    modules = _modules()
    return {name: _edges(m, modules) for name, m in modules.items()}


def _circles(graph: dict[str, list[Edge]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for e in graph[v]:
            if e.target not in index:
                visit(e.target)
                low[v] = min(low[v], low[e.target])
            elif e.target in on_stack:
                low[v] = min(low[v], index[e.target])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _cycle(graph: dict[str, list[Edge]], component: list[str]) -> list[Edge]:
    """One circle through the component's first module, edge by edge (shortest, breadth first)."""
    members = set(component)
    start = component[0]
    came: dict[str, Edge] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for e in graph[v]:
                if e.target not in members or e.target in came:
                    continue
                came[e.target] = e
                if e.target == start:
                    path = [e]
                    while path[0].source != start:
                        path.insert(0, came[path[0].source])
                    return path
                nxt.append(e.target)
        frontier = nxt
    raise AssertionError(f"no circle through {start}")  # a component always has one


def _describe(graph: dict[str, list[Edge]], component: list[str]) -> str:
    path = _cycle(graph, component)
    steps = " -> ".join([path[0].source, *(e.target for e in path)])
    where = "; ".join(f"{e.source} imports {e.target} at line {e.line}" for e in path)
    return f"{steps}\n    ({where}; the whole circle: {', '.join(component)})"


@pytest.fixture(scope="module")
def graph() -> dict[str, list[Edge]]:
    return _graph()


@pytest.mark.parametrize("package", PACKAGES.values())
def test_no_import_circle(graph, package):
    """Modules form a hierarchy: none imports, even lazily, one that imports it back."""
    circles = [c for c in _circles(graph) if any(m.split(".")[0] == package for m in c)]
    assert not circles, f"import circles in {package}:\n" + "\n".join(_describe(graph, c) for c in circles)


def test_the_graph_sees_every_kind_of_import():
    """The graph builder itself: relative imports by level, submodules named in a from-import,
    names of a package's __init__, and imports inside functions."""
    g = _graph()

    def targets(name):
        return {e.target for e in g[name]}

    assert "svbrdf_render.maps" in targets("svbrdf_render.renderer")  # from .maps import SVBRDF
    assert "svbrdf_render.fused" in targets("svbrdf_render.compiled")  # from . import fused
    assert "svbrdf_train.errors" in targets("svbrdf_train.training.checkpoint")  # from ..errors import
    assert "svbrdf_render" in targets("svbrdf_train.data.photos")  # from svbrdf_render import read_image
    assert "svbrdf_train" in targets("svbrdf_bench.runner")  # inside a function
    assert _circles({"a": [Edge("a", "b", 1)], "b": [Edge("b", "a", 2)], "c": []}) == [["a", "b"]]


# -- function length --------------------------------------------------------------------------------


def _long_functions(root: Path, limit: int) -> list[str]:
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > limit:
                    where = path.relative_to(REPO) if path.is_relative_to(REPO) else path
                    out.append(f"{where}:{node.lineno} {node.name} ({lines} lines)")
    return out


@pytest.mark.parametrize("dist", PACKAGES)
def test_no_long_function(dist):
    """A function fits on a screen: at most MAX_FUNCTION_LINES lines from its ``def`` to its end
    (decorators excluded, docstring included)."""
    long = _long_functions(REPO / "packages" / dist / "src", MAX_FUNCTION_LINES)
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


@pytest.mark.parametrize("dist", PACKAGES)
def test_no_long_file(dist):
    """A module holds one idea: at most MAX_FILE_LINES lines."""
    root = REPO / "packages" / dist / "src"
    long = [
        f"{p.relative_to(REPO)} ({n} lines)"
        for p in sorted(root.rglob("*.py"))
        if "egg-info" not in str(p) and (n := len(p.read_text().splitlines())) > MAX_FILE_LINES
    ]
    assert not long, f"files over {MAX_FILE_LINES} lines:\n" + "\n".join(long)


def test_the_long_checks_see_long_code(tmp_path):
    """The two length checks themselves: a 61-line function is found, a 60-line one is not."""
    body = "\n".join(f"    x{i} = {i}" for i in range(59))
    (tmp_path / "a.py").write_text(f"def short():\n{body}\n\n\ndef long():\n{body}\n    y = 0\n")
    found = _long_functions(tmp_path, MAX_FUNCTION_LINES)
    assert len(found) == 1 and " long (61 lines)" in found[0]


# -- knowledge written once ---------------------------------------------------------------------------


def _code_lines(pattern: re.Pattern) -> list[str]:
    """``path:line`` of every source line of the four packages whose code matches ``pattern``:
    the line's tokens with strings (docstrings, messages) and comments left out."""
    out = []
    for dist in PACKAGES:
        for path in sorted((REPO / "packages" / dist / "src").rglob("*.py")):
            code: dict[int, list[str]] = {}
            with path.open("rb") as f:
                for tok in tokenize.tokenize(f.readline):
                    if tok.type not in (tokenize.STRING, tokenize.COMMENT, tokenize.ENCODING):
                        code.setdefault(tok.start[0], []).append(tok.string)
            out += [f"{path.relative_to(REPO)}:{i}" for i, toks in code.items() if pattern.search(" ".join(toks))]
    return out


def _string_lines(word: str) -> list[str]:
    """``path:line`` of every string token that is exactly ``word`` (quoted) in the packages."""
    out = []
    for dist in PACKAGES:
        for path in sorted((REPO / "packages" / dist / "src").rglob("*.py")):
            with path.open("rb") as f:
                out += [
                    f"{path.relative_to(REPO)}:{tok.start[0]}"
                    for tok in tokenize.tokenize(f.readline)
                    if tok.type == tokenize.STRING and tok.string.strip("'\"") == word
                ]
    return out


def test_the_stored_normal_encoding_is_written_once():
    """``(n + 1) / 2`` lives in svbrdf_render.maps.encode_normal; everything else calls it."""
    found = _code_lines(re.compile(r"\+ 1(\.0)? \) / 2"))
    assert found == ["packages/svbrdf-render/src/svbrdf_render/maps.py:" + found[0].rsplit(":", 1)[1]], found


def test_the_des18_effect_set_is_spelled_once():
    """The Des18 effect set is one constant (effects.DES18_EFFECTS); nothing lists it again."""
    found = [f for f in _string_lines("cosine") if f in _string_lines("falloff")]
    assert len(found) == 1 and found[0].startswith("packages/svbrdf-render/src/svbrdf_render/effects.py:"), found


def test_the_photo_effect_set_is_spelled_once():
    """The generator's phone photo is one constant (effects.PHOTO_EFFECTS), which the data
    generator declares and the renderer registers: no other module names its image stages."""
    files = [{line.rsplit(":", 1)[0] for line in _string_lines(w)} for w in ("exposure", "noise", "clip")]
    assert set.intersection(*files) == {"packages/svbrdf-render/src/svbrdf_render/effects.py"}, files


def test_the_file_lock_is_written_once():
    """One inter-process lock, svbrdf_render.plumbing.locked: the photo tool's folder lock,
    the fit's ``--out`` lock and the tracking store's lock call it; none takes ``flock`` or
    ``filelock`` by itself."""
    taken = re.compile(r"\bfcntl \. flock\b|\bFileLock \(|\b(from|import) filelock\b")
    found = {line.rsplit(":", 1)[0] for line in _code_lines(taken)}
    assert found == {"packages/svbrdf-render/src/svbrdf_render/plumbing/processes.py"}, found


# -- rooms: subpackages ----------------------------------------------------------------------------

#: The most modules one package folder holds of its own (``__init__`` and ``__main__`` aside):
#: past it a newcomer cannot tell the rooms apart, and the folder wants subpackages.
MAX_FOLDER_MODULES = 20


def _package_folders() -> list[Path]:
    return [
        init.parent
        for dist, name in PACKAGES.items()
        for init in sorted((REPO / "packages" / dist / "src" / name).rglob("__init__.py"))
    ]


def test_no_package_folder_holds_more_than_20_modules():
    crowded = [
        f"{folder.relative_to(REPO)} ({n} modules)"
        for folder in _package_folders()
        if (n := len([p for p in folder.glob("*.py") if p.name not in ("__init__.py", "__main__.py")]))
        > MAX_FOLDER_MODULES
    ]
    assert not crowded, f"package folders over {MAX_FOLDER_MODULES} modules:\n" + "\n".join(crowded)


def test_no_private_module_is_imported_from_another_package(graph):
    """A module whose name (or a package above it) starts with ``_`` is its package's own: another
    of the four packages imports the public names instead."""
    found = [
        f"{e.source} imports {e.target} at line {e.line}"
        for edges in graph.values()
        for e in edges
        if e.source.split(".")[0] != e.target.split(".")[0] and any(p.startswith("_") for p in e.target.split("."))
    ]
    assert not found, "private modules imported across packages:\n" + "\n".join(found)


def _rooms(source: str, target: str) -> tuple[str, str] | None:
    """The two rooms an import joins: the children of the deepest package holding both modules
    (``svbrdf_train.recipe`` and ``svbrdf_train.training`` for an import between their modules;
    ``svbrdf_train.data.real`` and ``svbrdf_train.data.simulated_photo`` for one of the second by
    ``svbrdf_train.data.real.strips``); None across packages, inside one room, or from or to the
    ``__init__`` of the package holding both."""
    s, t = source.split("."), target.split(".")
    common = 0
    while common < min(len(s), len(t)) and s[common] == t[common]:
        common += 1
    if common == 0 or common >= min(len(s), len(t)):
        return None
    return ".".join(s[: common + 1]), ".".join(t[: common + 1])


def _room_edges(graph: dict[str, list[Edge]]) -> dict[tuple[str, str], Edge]:
    """One import (the first seen) for each ordered pair of different rooms of one package."""
    out: dict[tuple[str, str], Edge] = {}
    for edges in graph.values():
        for e in edges:
            if rooms := _rooms(e.source, e.target):
                out.setdefault(rooms, e)
    return out


def test_no_two_rooms_import_each_other(graph):
    """Issue 48: the rooms of a package (its subpackages and top-level modules, and theirs in
    turn: ``svbrdf_train.data``'s ``procedural``, ``real`` and ``shards``) stand on floors: when
    one imports another, even lazily, the other never imports it back."""
    pairs = _room_edges(graph)
    mutual = [
        f"{a} <-> {b} ({pairs[(a, b)].source} line {pairs[(a, b)].line}; {pairs[(b, a)].source} line "
        f"{pairs[(b, a)].line})"
        for a, b in sorted(pairs)
        if a < b and (b, a) in pairs
    ]
    assert not mutual, "rooms that import each other:\n" + "\n".join(mutual)


def test_the_room_check_sees_a_mutual_import():
    edges = {
        "pkg.a.x": [Edge("pkg.a.x", "pkg.b.y", 3)],
        "pkg.b.y": [Edge("pkg.b.y", "pkg.a", 9)],
        "pkg.c": [Edge("pkg.c", "pkg.a.x", 1)],
        "pkg.d.e.x": [Edge("pkg.d.e.x", "pkg.d.f", 2)],  # rooms of a subpackage
        "pkg.d.f": [Edge("pkg.d.f", "pkg.d.e", 5)],
    }
    pairs = _room_edges(edges)
    assert ("pkg.a", "pkg.b") in pairs and ("pkg.b", "pkg.a") in pairs and ("pkg.a", "pkg.c") not in pairs
    assert ("pkg.d.e", "pkg.d.f") in pairs and ("pkg.d.f", "pkg.d.e") in pairs


def test_docs_architecture_names_every_subpackage():
    """docs/architecture.md draws the house: each subpackage of the four packages has a row in its
    table (``svbrdf_x.sub``), and no row names a subpackage that is gone."""
    real = {".".join(folder.relative_to(REPO / "packages").parts[2:]) for folder in _package_folders()}
    real = {name for name in real if "." in name}  # the four packages themselves aside
    named = set(_architecture_order())
    assert real - named == set(), f"subpackages missing from docs/architecture.md: {sorted(real - named)}"
    assert named - real == set(), f"docs/architecture.md names subpackages that do not exist: {sorted(named - real)}"


def _architecture_order() -> list[str]:
    """The subpackages in the order docs/architecture.md's table lists them (its first column)."""
    text = (REPO / "docs" / "architecture.md").read_text()
    section = text.split("## Subpackages", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `(svbrdf_\w+(?:\.\w+)+)` \|", section, re.M)


def _floor_breaches(graph: dict[str, list[Edge]], order: list[str]) -> list[str]:
    """Imports from a subpackage into one listed after it in its package (nesting aside)."""
    def room(module: str) -> str | None:
        found = [s for s in order if module == s or module.startswith(s + ".")]
        return max(found, key=len, default=None)

    breaches = set()
    for source, edges in graph.items():
        for e in edges:
            a, b = room(source), room(e.target)
            nested = a and b and (a.startswith(b + ".") or b.startswith(a + "."))
            if a and b and a != b and not nested and order.index(b) > order.index(a):
                breaches.add(f"{a} imports {b}, listed after it ({e.source} line {e.line})")
    return sorted(breaches)


def test_the_floors_follow_the_order_docs_architecture_gives(graph):
    """Issue 48: docs/architecture.md lists each package's subpackages from the ground floor up,
    and the code follows that order: a subpackage imports only those listed before it."""
    breaches = _floor_breaches(graph, _architecture_order())
    assert not breaches, "imports against docs/architecture.md's order:\n" + "\n".join(breaches)


def test_the_floor_check_sees_an_upward_import():
    edges = {
        "pkg.low.x": [Edge("pkg.low.x", "pkg.high.y", 4)],
        "pkg.high.y": [Edge("pkg.high.y", "pkg.low", 2)],
        "pkg.low.sub.z": [Edge("pkg.low.sub.z", "pkg.low", 1)],
    }
    assert _floor_breaches(edges, ["pkg.low", "pkg.low.sub", "pkg.high"]) == [
        "pkg.low imports pkg.high, listed after it (pkg.low.x line 4)"
    ]


def _top_level(path: Path) -> tuple[ast.expr | None, set[str]]:
    """The expression a module assigns to ``__all__`` (None without one) and the names its top
    level defines."""
    listed, defined = None, set()
    for node in ast.parse(path.read_text()).body:
        targets = node.targets if isinstance(node, ast.Assign) else []
        targets += [node.target] if isinstance(node, ast.AnnAssign) else []
        for target in targets:
            for name in ast.walk(target):
                if isinstance(name, ast.Name):
                    defined.add(name.id)
                    if name.id == "__all__" and node.value is not None:
                        listed = node.value
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            defined.add(node.name)
    return listed, defined


def _passed_on(path: Path) -> list[str]:
    """The names a module's ``__all__`` lists but the module does not define (imports it passes on)."""
    listed, defined = _top_level(path)
    return [name for name in ast.literal_eval(listed) if name not in defined] if listed else []


def test_an_ordinary_module_lists_only_what_it_defines():
    """Issue 48, one address per name: a module's ``__all__`` names what it defines; a subpackage's
    ``__init__`` states the public names of its modules, and nothing else passes names on."""
    found = {
        str(path.relative_to(REPO)): names
        for path in sorted((REPO / "packages").glob("*/src/*/**/*.py"))
        if path.name != "__init__.py" and (names := _passed_on(path))
    }
    assert not found, f"modules passing on names they do not define: {found}"


def test_the_pass_on_check_sees_an_imported_name(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("from os import sep\nA, B = 1, 2\n__all__ = ['A', 'B', 'sep', 'f']\ndef f(): pass\n")
    assert _passed_on(module) == ["sep"]


def test_every_subpackage_states_its_public_names():
    """Issue 48: each package's and subpackage's ``__init__`` has an ``__all__`` (empty where its
    modules are reached by name and its public names are the package's own)."""
    missing = [
        str(folder.relative_to(REPO))
        for folder in _package_folders()
        if _top_level(folder / "__init__.py")[0] is None
    ]
    assert not missing, f"subpackages whose __init__ states no __all__: {missing}"
