"""The package's import graph (src/ and the flows it ships), read with `ast` (nothing is imported): no
circle, layers point down, and no function-local import of a package module outside `cli/`.

An import inside a function hides an edge from the reader and from this test's ordinary view; it is
how circles between stages grew unnoticed (issue 43). So both kinds of edge count for the circle
check, and function-local ones are allowed only in `cli/`, where they keep `photoshape --help` fast.
What must load light without them does so by design: the stage registry names each stage's module by
its dotted path and imports it on first use (`stages.registry.Stage.entry`), and the export formats'
table (`export.formats`) stands apart from their writers (`export.writers`).
`if TYPE_CHECKING:` imports are not executed and do not count.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

PACKAGE = "photoshape_flow"
ROOT = Path(__file__).resolve().parents[1] / "src" / PACKAGE
# Shipped in the package from the repository root (pyproject's package-dir), not under src/: the flows
# (the top of the graph beside cli/: they import stages) are read as `photoshape_flow.flows`; the
# migration scripts are not read (each freezes what it needs).
FLOWS = ROOT.parents[1] / "flows"
OUTSIDE_SRC = (f"{PACKAGE}.migrations",)

# Modules that must load without these (statically: their module-level imports, followed through the
# package, reach no module that imports one at its top): `photoshape --help` loads the CLI and the
# profiles (`tests/test_profiles.py`), flows and `photoshape status`/`claims`/`serve` load the stage
# registry, the colour likelihood is the ranking rule's, read without a network, and `photoshape serve`
# loads the flows (their planners read rows: `networks.classifier_rows`, `recognition.material_sets`).
LIGHT: dict[str, tuple[str, ...]] = {
    f"{PACKAGE}.cli": ("torch", "numpy"),
    f"{PACKAGE}.flows.pipeline": ("torch",),
    f"{PACKAGE}.flows.deployments": ("torch",),
    f"{PACKAGE}.profiles": ("torch", "numpy"),
    f"{PACKAGE}.stages": ("torch",),
    f"{PACKAGE}.classify.color_prior": ("torch",),
}


# The layers, top to bottom (docs/architecture.md): a module imports its own layer or lower ones. A
# module belongs to the layer of its longest listed prefix ("" is the package's __init__).
LAYERS: tuple[tuple[str, ...], ...] = (
    ("cli",),
    ("flows",),  # Prefect flows and tasks over the registry
    ("stages",),  # the registry: the composition root
    ("scoring",),
    ("publish",),
    ("fitting",),
    ("recognition",),
    ("networks",),
    ("alignment",),
    ("ingest",),
    ("pipeline",),
    ("profiles",),
    ("db", "store"),
    ("align", "classify", "fit", "synth", "demo", "evaluation", "export", "render", "geometry", "imaging"),
    ("config", "vocab", "events", "method_keys", "inputs", "sidecar", "export.text", "hashing", "faults", "devices",
     "masking", "progress_sink", ""),
)
# Imports that point up, each with its reason: (importer, imported) -> why.
LAYER_EXCEPTIONS: dict[tuple[str, str], str] = {
    (f"{PACKAGE}.render.renderer", f"{PACKAGE}.store"):
        "a Renderer built without `resolve` reads blob refs from the process's blob store",
}


@dataclass(frozen=True)
class Edge:
    importer: str
    imported: str
    line: int
    local: bool  # inside a function body


def module_name(path: Path) -> str:
    base = (ROOT.parent, [])
    if path.is_relative_to(FLOWS):
        base = (FLOWS, [PACKAGE, "flows"])
    parts = [*base[1], *path.relative_to(base[0]).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@cache
def modules() -> dict[str, Path]:
    return {module_name(p): p for p in [*sorted(ROOT.rglob("*.py")), *sorted(FLOWS.glob("*.py"))]}


def _target(name: str) -> str | None:
    """The package module `name` names (a module, or the module that defines the attribute)."""
    mods = modules()
    if any(name == pkg or name.startswith(pkg + ".") for pkg in OUTSIDE_SRC):
        return None
    while name:
        if name in mods:
            return name
        name = name.rpartition(".")[0]
    return None


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST, importer: str, is_package: bool) -> Iterator[tuple[ast.stmt, str, bool]]:
    """(statement, imported module, inside a function) for every runtime import of a package module."""

    def visit(node: ast.AST, local: bool) -> Iterator[tuple[ast.stmt, str, bool]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                yield from (item for stmt in child.orelse for item in visit_stmt(stmt, local))
                continue
            yield from visit_stmt(child, local)

    def visit_stmt(child: ast.AST, local: bool) -> Iterator[tuple[ast.stmt, str, bool]]:
        if isinstance(child, ast.Import):
            for alias in child.names:
                if (target := _target(alias.name)) is not None:
                    yield child, target, local
        elif isinstance(child, ast.ImportFrom):
            base = child.module or ""
            if child.level:
                anchor = importer if is_package else importer.rpartition(".")[0]
                for _ in range(child.level - 1):
                    anchor = anchor.rpartition(".")[0]
                base = f"{anchor}.{base}" if base else anchor
            if base != PACKAGE and not base.startswith(PACKAGE + "."):
                return
            for alias in child.names:
                target = _target(f"{base}.{alias.name}") if alias.name != "*" else _target(base)
                if target is not None:
                    yield child, target, local
        elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            yield from visit(child, True)
        else:
            yield from visit(child, local)

    yield from visit(tree, False)


@cache
def edges() -> tuple[Edge, ...]:
    found: list[Edge] = []
    for name, path in modules().items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for stmt, target, local in _imports(tree, name, path.name == "__init__.py"):
            if target != name:
                found.append(Edge(name, target, stmt.lineno, local))
    return tuple(found)


def _short(module: str) -> str:
    return module.removeprefix(PACKAGE + ".")


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One circle of `graph` as a path that ends where it starts, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def dfs(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            if nxt not in state and (cycle := dfs(nxt)) is not None:
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := dfs(node)) is not None:
            return cycle
    return None


def strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """The circles of `graph` as sets of modules (Tarjan), largest first; single modules left out."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph.get(node, ()):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found, key=len, reverse=True)


def _graph(local: bool | None = None) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {name: set() for name in modules()}
    for edge in edges():
        if local is None or edge.local == local:
            graph[edge.importer].add(edge.imported)
    return graph


def _edge_lines(importer: str, imported: str) -> str:
    lines = sorted({(e.line, e.local) for e in edges() if (e.importer, e.imported) == (importer, imported)})
    return ", ".join(f"{line}{' (in a function)' if local else ''}" for line, local in lines)


def test_the_parser_sees_the_package() -> None:
    """A guard against a test that passes because it reads nothing."""
    mods = modules()
    assert f"{PACKAGE}.fitting.fit" in mods and f"{PACKAGE}.cli" in mods and len(mods) > 150
    assert f"{PACKAGE}.flows.pipeline" in mods and f"{PACKAGE}.flows" in mods
    assert any(e.importer == f"{PACKAGE}.stages.registry" and not e.local for e in edges())
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    tree = ast.parse("from . import fit\nfrom .context import X\nif TYPE_CHECKING:\n    import photoshape_flow.db\n"
                     "def f():\n    from ..store import blobstore\n")
    got = [(t, local) for _, t, local in _imports(tree, f"{PACKAGE}.fitting.refine", False)]
    assert got == [(f"{PACKAGE}.fitting.fit", False), (f"{PACKAGE}.fitting.context", False),
                   (f"{PACKAGE}.store.blobstore", True)]


def test_no_import_circle() -> None:
    """Module-level and function-local imports together form no circle."""
    cycle = find_cycle(_graph())
    if cycle is not None:
        steps = "\n".join(f"  {_short(a)} -> {_short(b)}  (line {_edge_lines(a, b)})"
                          for a, b in zip(cycle, cycle[1:], strict=False))
        components = "; ".join(", ".join(sorted(map(_short, c))) for c in strongly_connected(_graph()))
        raise AssertionError(f"import circle:\n{steps}\nall circles (module sets): {components}")


def test_no_function_local_package_import_outside_cli() -> None:
    cli = f"{PACKAGE}.cli"
    offenders = sorted(
        {(e.importer, e.imported, e.line) for e in edges()
         if e.local and e.importer != cli and not e.importer.startswith(cli + ".")})
    assert not offenders, (
        f"{len(offenders)} function-local imports of package modules outside cli/ (move them to the top; "
        "a heavy module that a light one needs only sometimes is a sign the light one holds two things):\n"
        + "\n".join(f"  {_short(a)}:{line} imports {_short(b)}" for a, b, line in offenders))


# The only modules outside cli/ that import by name at run time, each for a reason an import statement
# cannot serve: the stage registry is the composition root and must not load its stages (torch) to be
# read; the backbone module loads the installed weights package the profile names (not ours); the
# deployments resolve the entrypoints `prefect.yaml` declares as text (Prefect's own form).
IMPORTS_BY_NAME = {f"{PACKAGE}.stages.registry", f"{PACKAGE}.classify.backbone", f"{PACKAGE}.flows.deployments"}


def _imports_by_name(tree: ast.AST) -> list[int]:
    """Lines that call `importlib.import_module` or `__import__` (an edge no import statement shows)."""
    return sorted(node.lineno for node in ast.walk(tree) if isinstance(node, ast.Call)
                  and (getattr(node.func, "attr", None) == "import_module"
                       or getattr(node.func, "id", None) in ("import_module", "__import__")))


def test_the_scan_finds_imports_by_name() -> None:
    tree = ast.parse("import importlib\ndef f(name):\n    return importlib.import_module(name)\n"
                     "g = __import__('x')\n")
    assert _imports_by_name(tree) == [3, 4]


def test_imports_by_name_only_where_they_are_the_design() -> None:
    cli = f"{PACKAGE}.cli"
    offenders = sorted(
        f"{_short(name)}:{line}" for name, path in modules().items()
        if name not in IMPORTS_BY_NAME and name != cli and not name.startswith(cli + ".")
        for line in _imports_by_name(ast.parse(path.read_text(), str(path))))
    assert not offenders, ("imports by name hide an edge from the graph above (import the module, or pass "
                           "the object itself): " + ", ".join(offenders))


def _imports_at_top(path: Path, heavy: tuple[str, ...]) -> bool:
    """Whether a module imports one of `heavy` at its top (outside functions and `if TYPE_CHECKING:`)."""

    def visit(node: ast.AST) -> bool:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) or (
                    isinstance(child, ast.If) and _is_type_checking(child.test)):
                continue
            names = ([a.name for a in child.names] if isinstance(child, ast.Import) else
                     [child.module or ""] if isinstance(child, ast.ImportFrom) and not child.level else [])
            if any(n.split(".")[0] in heavy for n in names) or visit(child):
                return True
        return False

    return visit(ast.parse(path.read_text(encoding="utf-8")))


def test_the_light_entry_points_load_nothing_heavy() -> None:
    """The module-level closure of each LIGHT module reaches no module that imports one of its heavy ones."""
    graph = _graph(local=False)
    for root, heavy in LIGHT.items():
        parents: dict[str, str | None] = {root: None}
        todo = [root]
        while todo:
            node = todo.pop()
            if _imports_at_top(modules()[node], heavy):
                chain = [node]
                while (up := parents[chain[-1]]) is not None:
                    chain.append(up)
                path = " -> ".join(map(_short, reversed(chain)))
                raise AssertionError(f"{_short(root)} imports {' or '.join(heavy)} when loaded: {path}")
            for nxt in sorted(graph[node] - parents.keys()):
                parents[nxt] = node
                todo.append(nxt)


def layer_of(module: str) -> int:
    short = module.removeprefix(PACKAGE).lstrip(".")
    found = [(len(prefix), index) for index, prefixes in enumerate(LAYERS) for prefix in prefixes
             if short == prefix or (prefix and short.startswith(prefix + "."))]
    assert found, f"{module}: in no layer of LAYERS"
    return max(found)[1]


def test_layers_point_down() -> None:
    upward = sorted({(e.importer, e.imported, e.line) for e in edges()
                     if layer_of(e.imported) < layer_of(e.importer)
                     and (e.importer, e.imported) not in LAYER_EXCEPTIONS})
    assert not upward, "imports of a higher layer:\n" + "\n".join(
        f"  {_short(a)}:{line} imports {_short(b)}" for a, b, line in upward)
    stale = sorted(k for k in LAYER_EXCEPTIONS if not any((e.importer, e.imported) == k for e in edges()))
    assert not stale, f"no longer imported: {stale}"
