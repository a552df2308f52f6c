"""Building blocks that several kinds of seating share: legs, aprons, stretchers, backs and arms.

Each block adds named components with their role to a `Builder`; the kinds in `kinds` compose them.
"""

from __future__ import annotations

import numpy as np

from photoshape_flow.demo.furniture.model import Component
from photoshape_flow.demo.primitives import (
    Piece,
    box,
    cylinder,
    rotation_x,
    rounded_box,
    rounded_path,
    tapered_box,
    tube,
)


class Builder:
    """Collects a shape's components in the order they are added (the order of the OBJ groups)."""

    def __init__(self) -> None:
        self.components: list[Component] = []

    def add(self, name: str, role: str, piece: Piece, soft: bool = False, unit: str = "") -> None:
        self.components.append(Component(name, role, piece, soft, unit or name))


def leg_positions(w: float, d: float, inset: float, n: int = 4) -> list[tuple[str, float, float]]:
    """(name, x, z) of leg tops under a rectangular seat: front (+z) first."""
    x, z = w / 2 - inset, d / 2 - inset
    legs = [("front_left", -x, z), ("front_right", x, z), ("back_left", -x, -z), ("back_right", x, -z)]
    if n == 6:
        legs += [("middle_front", 0.0, z), ("middle_back", 0.0, -z)]
    return legs


def add_legs(b: Builder, style: str, positions, top: float, w: float, splay: float = 0.06) -> None:
    """Four-ish legs from the floor to `top` in one of the leg styles."""
    if style == "sled":
        xs = sorted({x for _, x, _ in positions})
        zs = [z for _, _, z in positions]
        zf, zb = max(zs), min(zs)
        r = w * 0.4
        for side, x in (("left", xs[0]), ("right", xs[-1])):
            path = np.array([[x, top, zf], [x, r, zf + 0.02], [x, r, zb - 0.02], [x, top, zb]])
            b.add(f"leg_{side}", "legs", tube(rounded_path(path, 0.06), r, segments=12))
        return
    for name, x, z in positions:
        if style == "straight":
            piece = box([x, top / 2, z], [w, top, w])
        elif style == "tapered":
            piece = tapered_box([x, 0.0, z], [x, top, z], [0.55 * w, 0.55 * w], [w, w])
        elif style == "round":
            piece = cylinder([x, 0.0, z], [x, top, z], 0.5 * w * 0.8, 0.5 * w, segments=14)
        elif style == "splayed":
            out = np.array([x, z]) / max(np.hypot(x, z), 1e-6) * splay
            piece = cylinder([x + out[0], 0.0, z + out[1]], [x, top, z], 0.5 * w * 0.7, 0.5 * w, segments=14)
        else:
            raise ValueError(f"unknown leg style {style!r}")
        b.add(f"leg_{name}", "legs", piece)


def add_apron(b: Builder, w: float, d: float, y_top: float, inset: float, leg_w: float, h: float = 0.06) -> None:
    t = leg_w * 0.6
    x, z = w / 2 - inset, d / 2 - inset
    b.add("apron_front", "frame", box([0, y_top - h / 2, z], [2 * x, h, t]))
    b.add("apron_back", "frame", box([0, y_top - h / 2, -z], [2 * x, h, t]))
    b.add("apron_left", "frame", box([-x, y_top - h / 2, 0], [t, h, 2 * z]))
    b.add("apron_right", "frame", box([x, y_top - h / 2, 0], [t, h, 2 * z]))


def add_stretchers(b: Builder, w: float, d: float, y: float, inset: float, leg_w: float) -> None:
    r = leg_w * 0.3
    x, z = w / 2 - inset, d / 2 - inset
    b.add("stretcher_left", "frame", cylinder([-x, y, -z], [-x, y, z], r, segments=10))
    b.add("stretcher_right", "frame", cylinder([x, y, -z], [x, y, z], r, segments=10))
    b.add("stretcher_middle", "frame", cylinder([-x, y + 0.02, 0], [x, y + 0.02, 0], r, segments=10))


def tilted(piece: Piece, pivot, tilt: float) -> Piece:
    """Lean a back piece backwards (towards -z) by `tilt` radians about a horizontal x-axis at pivot."""
    p = np.asarray(pivot, np.float64)
    return piece.transformed(None, -p).transformed(rotation_x(-tilt), p)


def add_back(
    b: Builder, style: str, w: float, z_back: float, y0: float, h: float, tilt: float, post_w: float, n_slats: int
) -> None:
    """A chair back from seat level y0 up h, leaning back by tilt, in one of the back styles."""
    pivot = [0.0, y0, z_back]
    t = post_w * 0.8
    parts: list[tuple[str, str, Piece, bool]] = []
    if style == "upholstered":
        parts.append(("back_cushion", "back", rounded_box([0, y0 + h / 2 + 0.02, z_back], [w, h, 0.07], 0.025), True))
    else:
        x = w / 2 - post_w / 2
        for side, sx in (("left", -x), ("right", x)):
            parts.append((f"back_post_{side}", "back", box([sx, y0 + h / 2, z_back], [post_w, h, post_w]), False))
        inner = w - 2 * post_w
        if style == "slats_v":
            parts.append(("top_rail", "back", box([0, y0 + h - 0.04, z_back], [inner, 0.08, t]), False))
            xs = np.linspace(-inner / 2, inner / 2, n_slats + 2)[1:-1]
            for k, sx in enumerate(xs):
                sw = min(0.05, inner / (n_slats + 1) * 0.6)
                parts.append(
                    (
                        f"slat_{k + 1}",
                        "back",
                        box([sx, y0 + 0.06 + (h - 0.14) / 2, z_back], [sw, h - 0.14, t * 0.7]),
                        False,
                    )
                )
        elif style == "slats_h":
            ys = np.linspace(y0 + h * 0.35, y0 + h - 0.04, max(2, n_slats - 1))
            for k, sy in enumerate(ys):
                parts.append((f"slat_{k + 1}", "back", box([0, sy, z_back], [inner, min(0.07, h / 6), t * 0.8]), False))
        elif style == "spindles":
            parts.append(
                ("top_rail", "back", rounded_box([0, y0 + h - 0.035, z_back], [w + 0.02, 0.07, t * 1.2], 0.012), False)
            )
            n = n_slats + 2
            for k, sx in enumerate(np.linspace(-inner / 2, inner / 2, n + 2)[1:-1]):
                parts.append(
                    (
                        f"spindle_{k + 1}",
                        "back",
                        cylinder([sx, y0 + 0.02, z_back], [sx, y0 + h - 0.06, z_back], 0.009, 0.007, segments=10),
                        False,
                    )
                )
        elif style == "panel":
            ph = h * 0.55
            parts.append(
                ("back_panel", "back", box([0, y0 + h - ph / 2 - 0.02, z_back], [inner + 0.01, ph, t * 0.7]), False)
            )
        else:
            raise ValueError(f"unknown back style {style!r}")
    for name, role, piece, soft in parts:
        b.add(name, role, tilted(piece, pivot, tilt), soft)


def add_post_arms(
    b: Builder, w: float, d: float, y_seat: float, arm_h: float, t: float, inset: float, soft: bool = False
) -> None:
    x = w / 2 - inset
    for side, sx in (("left", -x), ("right", x)):
        b.add(
            f"arm_post_{side}",
            "arms",
            box([sx, y_seat + arm_h / 2, d / 2 - inset - 0.03], [t, arm_h, t]),
            unit=f"arm_{side}",
        )
        pad = [t * 1.6, 0.03, d * 0.85]
        centre = [sx, y_seat + arm_h + 0.015, -d * 0.05]
        piece = rounded_box(centre, pad, 0.01) if soft else box(centre, pad)
        b.add(f"armrest_{side}", "arms", piece, soft, unit=f"arm_{side}")
