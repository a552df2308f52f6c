"""Grouping components into material parts, as real model files do (section 4.2 of the paper).

Usually one group per role, sometimes over-segmented (each leg or cushion its own material group)
or under-segmented (frame and legs, or seat and back, in one group), on purpose.
"""

from __future__ import annotations

import numpy as np

from photoshape_flow.demo.furniture.model import Component, FurniturePart

SEGMENTATIONS: tuple[str, ...] = ("semantic", "over", "under")

_MERGES: tuple[tuple[tuple[str, ...], str], ...] = (
    (("legs", "frame"), "frame"),
    (("legs", "seat"), "body"),
    (("seat", "back"), "shell"),
    (("base", "casters"), "base"),
    (("frame", "back", "arms"), "body"),
    (("cushion", "back"), "upholstery"),
    (("legs", "base"), "base"),
)


def segment(components: list[Component], style: str, rng: np.random.Generator) -> tuple[list[FurniturePart], str]:
    """Group components into material parts: one per role (semantic), split (over), merged (under).

    Returns the parts and the style actually applied ("semantic" when the shape has nothing to
    split or merge). The part order is shuffled: real files list material groups in arbitrary
    order, and ingest numbers parts by first appearance.
    """
    by_role: dict[str, list[Component]] = {}
    for c in components:
        by_role.setdefault(c.role, []).append(c)
    groups: dict[str, list[Component]] = {}
    if style == "over":

        def units(role: str) -> dict[str, list[Component]]:
            out: dict[str, list[Component]] = {}
            for c in by_role.get(role, []):
                out.setdefault(c.unit, []).append(c)
            return out

        splittable = [r for r in ("legs", "cushion", "arms", "casters") if len(units(r)) > 1]
        if not splittable:
            style = "semantic"
        split = set(splittable[:1]) | ({splittable[1]} if len(splittable) > 1 and rng.random() < 0.5 else set())
        for role, comps in by_role.items():
            if role in split:
                for k, unit_comps in enumerate(units(role).values(), start=1):
                    groups[f"{role}_{k}"] = unit_comps
            else:
                groups[role] = list(comps)
    elif style == "under":
        applicable = [(roles, name) for roles, name in _MERGES if sum(r in by_role for r in roles) >= 2]
        roles, name = applicable[int(rng.integers(len(applicable)))] if applicable else ((), "")
        if not applicable:
            style = "semantic"
        for role, comps in by_role.items():
            key = name if role in roles else role
            groups.setdefault(key, []).extend(comps)
    elif style == "semantic":
        groups = {role: list(comps) for role, comps in by_role.items()}
    else:
        raise ValueError(f"unknown segmentation style {style!r}; expected one of {SEGMENTATIONS}")
    names = list(groups)
    order = rng.permutation(len(names))
    return [FurniturePart(names[i], groups[names[i]]) for i in order], style
