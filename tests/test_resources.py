"""Resources are built in one place (issue 43): `BlobStore(...)` only in `store.factory`
(`default_store`) and `Renderer(...)` only in `render.factory` (`default_renderer`).

Stages take their store and renderer from the stage context, or from their caller; functions that
are also called directly default to the factory. Read with `ast` (nothing is imported), so a new
construction site anywhere in the package fails here.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "photoshape_flow"

# constructor -> the one module (relative to ROOT) allowed to call it
FACTORIES = {"BlobStore": "store/factory.py", "Renderer": "render/factory.py"}


def constructor_calls(tree: ast.AST) -> list[tuple[str, int]]:
    """(class name, line) for every call of a name in FACTORIES, bare (`Renderer()`) or as an
    attribute (`render.Renderer()`, `store.BlobStore(...)`)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else None
            if name in FACTORIES:
                found.append((name, node.lineno))
    return found


def test_the_scan_finds_both_spellings() -> None:
    tree = ast.parse("a = Renderer()\nb = render_module.Renderer(resolve=f)\nc = BlobStore(root)\n"
                     "d = FrameRenderer(r, 1, 2)\ne = default_store(s)\n")
    assert constructor_calls(tree) == [("Renderer", 1), ("Renderer", 2), ("BlobStore", 3)]


def test_resources_are_constructed_only_in_their_factory() -> None:
    paths = sorted(ROOT.rglob("*.py"))
    assert len(paths) > 150  # the scan reads the package
    offenders = []
    seen = set()
    for path in paths:
        rel = path.relative_to(ROOT).as_posix()
        for name, line in constructor_calls(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            seen.add((name, rel))
            if FACTORIES[name] != rel:
                offenders.append(f"  {rel}:{line} builds a {name}")
    assert not offenders, (
        "build stores and renderers with store.default_store / render.factory.default_renderer, or take "
        "them from the stage context or the caller:\n" + "\n".join(offenders))
    assert seen == set(FACTORIES.items())  # each factory builds its resource
