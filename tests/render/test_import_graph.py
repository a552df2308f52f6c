"""The render package's modules import each other without a cycle.

A cycle (runtime -> renderer -> pool -> runtime) hid behind a function-local import once; this scan
reads every import statement, local ones included, so it cannot come back unnoticed.
"""

from __future__ import annotations

import ast
from pathlib import Path

import photoshape_flow.render as render

PACKAGE = render.__name__
ROOT = Path(render.__file__).parent


def module_name(path: Path) -> str:
    return PACKAGE if path.name == "__init__.py" else f"{PACKAGE}.{path.stem}"


def imported_modules(path: Path, modules: set[str]) -> set[str]:
    """The package's modules that `path` imports anywhere in its body."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
        else:
            continue
        found.update(t for t in targets if t in modules)
    return found - {name}


def import_graph(root: Path) -> dict[str, set[str]]:
    paths = sorted(root.glob("*.py"))
    modules = {module_name(p) for p in paths}
    return {module_name(p): imported_modules(p, modules) for p in paths}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of modules (first repeated last), or None."""
    done: set[str] = set()

    def visit(node: str, trail: list[str]) -> list[str] | None:
        if node in trail:
            return [*trail[trail.index(node):], node]
        if node in done:
            return None
        for target in sorted(graph.get(node, ())):
            cycle = visit(target, [*trail, node])
            if cycle:
                return cycle
        done.add(node)
        return None

    for start in sorted(graph):
        cycle = visit(start, [])
        if cycle:
            return cycle
    return None


def test_render_modules_import_without_a_cycle() -> None:
    graph = import_graph(ROOT)
    assert {f"{PACKAGE}.runtime", f"{PACKAGE}.renderer", f"{PACKAGE}.selftest"} <= set(graph)
    assert f"{PACKAGE}.runtime" in graph[f"{PACKAGE}.renderer"]  # the scan sees the imports it must
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph) or [])


def test_runtime_imports_no_other_render_module() -> None:
    assert import_graph(ROOT)[f"{PACKAGE}.runtime"] == set()


def test_the_scan_finds_a_function_local_cycle(tmp_path: Path) -> None:
    (tmp_path / "__init__.py").write_text("")
    (tmp_path / "runtime.py").write_text(f"def f():\n    from {PACKAGE}.renderer import Renderer\n")
    (tmp_path / "renderer.py").write_text(f"from {PACKAGE}.runtime import f\n")
    assert find_cycle(import_graph(tmp_path)) == [f"{PACKAGE}.renderer", f"{PACKAGE}.runtime", f"{PACKAGE}.renderer"]
