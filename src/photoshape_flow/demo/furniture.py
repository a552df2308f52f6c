"""Seeded procedural seating: chairs, armchairs, office chairs, stools, benches and sofas.

A design is a flat dict of numbers and style choices (`sample_design`), built into named object
components with a semantic role (`build_components`), then grouped into *material parts* the way
real model files are (`segment`): usually one group per role, sometimes over-segmented (each leg or
cushion its own material group) or under-segmented (frame and legs, or seat and back, in one group),
on purpose, as section 4.2 of the paper describes for ShapeNet. Shapes are normalised into the unit
cube of the mesh contract (centred, longest side 1, +y up, front towards +z).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from photoshape_flow.demo.primitives import (
    Piece,
    box,
    cylinder,
    merge_pieces,
    rotation_x,
    rotation_y,
    rounded_box,
    rounded_path,
    tapered_box,
    tube,
)
from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh

KINDS: tuple[str, ...] = ("chair", "armchair", "office_chair", "stool", "bench", "sofa")
KIND_WEIGHTS: tuple[float, ...] = (0.28, 0.16, 0.16, 0.14, 0.1, 0.16)
ROLES: tuple[str, ...] = ("legs", "seat", "back", "arms", "cushion", "frame", "base", "casters")
SEGMENTATIONS: tuple[str, ...] = ("semantic", "over", "under")

# Which substances a part of each role plausibly has (hard / upholstered), for built-in colours here
# and for the exemplar material prior in `exemplars`.
SUBSTANCE_PRIOR: dict[str, dict[str, float]] = {
    "legs": {"wood": 0.5, "metal": 0.4, "plastic": 0.1},
    "frame": {"wood": 0.55, "metal": 0.35, "plastic": 0.1},
    "seat": {"wood": 0.6, "plastic": 0.4},
    "back": {"wood": 0.6, "plastic": 0.4},
    "arms": {"wood": 0.6, "metal": 0.2, "plastic": 0.2},
    "base": {"metal": 0.6, "plastic": 0.4},
    "casters": {"plastic": 1.0},
    "soft": {"fabric": 0.55, "leather": 0.45},
}


@dataclass
class Component:
    """One object group (`g` in OBJ): a named piece with a semantic role."""

    name: str
    role: str
    piece: Piece
    soft: bool = False  # upholstered (fabric or leather in real life)
    unit: str = ""  # components with the same unit (a caster's wheel and fork) stay together when split


@dataclass
class FurniturePart:
    """One material part (`usemtl` group) made of one or more components."""

    name: str
    components: list[Component]
    builtin: dict[str, Any] = field(default_factory=dict)

    @property
    def roles(self) -> list[str]:
        return sorted({c.role for c in self.components})

    @property
    def soft(self) -> bool:
        return any(c.soft for c in self.components)

    @property
    def prior_key(self) -> str:
        """The key of SUBSTANCE_PRIOR that describes this part's plausible substances."""
        if self.soft:
            return "soft"
        counts: dict[str, float] = {}
        for c in self.components:
            counts[c.role] = counts.get(c.role, 0.0) + float(len(c.piece.faces))
        role = max(sorted(counts), key=lambda r: counts[r])
        return role if role in SUBSTANCE_PRIOR else "frame"


@dataclass
class Furniture:
    """A generated shape: parts in file order, already in the unit cube."""

    source_id: str
    kind: str
    segmentation: str
    parts: list[FurniturePart]
    design: dict[str, Any]

    def to_shape_mesh(self) -> ShapeMesh:
        """The in-memory ShapeMesh that ingest will produce from the OBJ (same part numbering)."""
        parts = []
        for i, part in enumerate(self.parts, start=1):
            piece = merge_pieces([c.piece for c in part.components])
            parts.append(
                PartMesh(
                    index=i,
                    name=part.name,
                    vertices=piece.vertices.astype(np.float32),
                    faces=piece.faces.astype(np.int32),
                    normals=piece.normals.astype(np.float32),
                    uvs=piece.uvs.astype(np.float32),
                    builtin_material=dict(part.builtin),
                    meta={"roles": part.roles, "groups": [c.name for c in part.components]},
                )
            )
        return ShapeMesh(
            parts=parts,
            meta={"source_id": self.source_id, "kind": self.kind, "segmentation": self.segmentation, "source": "demo"},
        )


# -- design sampling ------------------------------------------------------------------------------


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _pick(rng: np.random.Generator, options, p=None):
    options = list(options)
    return options[int(rng.choice(len(options), p=p))]


def sample_design(rng: np.random.Generator, kind: str) -> dict[str, Any]:
    """Random dimensions (metres) and style choices for one piece of seating of `kind`."""
    d: dict[str, Any] = {"kind": kind}
    if kind == "chair":
        d.update(
            seat_w=_u(rng, 0.40, 0.50),
            seat_d=_u(rng, 0.38, 0.48),
            seat_h=_u(rng, 0.43, 0.48),
            back_h=_u(rng, 0.32, 0.50),
            back_tilt=_u(rng, 0.03, 0.22),
            leg_w=_u(rng, 0.025, 0.045),
            leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "sled"], [0.25, 0.25, 0.2, 0.2, 0.1]),
            back_style=_pick(rng, ["slats_v", "slats_h", "spindles", "panel", "upholstered"]),
            n_slats=int(rng.integers(2, 6)),
            soft_seat=bool(rng.random() < 0.4),
            seat_t=_u(rng, 0.025, 0.045),
            apron=bool(rng.random() < 0.6),
            stretchers=bool(rng.random() < 0.35),
            arms=_pick(rng, ["none", "post"], [0.8, 0.2]),
            arm_h=_u(rng, 0.18, 0.25),
        )
    elif kind == "armchair":
        d.update(
            style=_pick(rng, ["club", "framed"]),
            seat_w=_u(rng, 0.55, 0.72),
            seat_d=_u(rng, 0.5, 0.62),
            seat_h=_u(rng, 0.38, 0.45),
            back_h=_u(rng, 0.38, 0.58),
            back_tilt=_u(rng, 0.08, 0.28),
            leg_w=_u(rng, 0.03, 0.05),
            leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "sled"]),
            arm_w=_u(rng, 0.08, 0.2),
            arm_h=_u(rng, 0.18, 0.26),
            leg_h=_u(rng, 0.08, 0.2),
            seat_t=_u(rng, 0.08, 0.14),
            arms=_pick(rng, ["post", "panel"]),
            back_style=_pick(rng, ["upholstered", "panel", "spindles"], [0.7, 0.15, 0.15]),
            n_slats=int(rng.integers(3, 7)),
            apron=bool(rng.random() < 0.5),
            stretchers=False,
        )
    elif kind == "office_chair":
        d.update(
            seat_w=_u(rng, 0.44, 0.54),
            seat_d=_u(rng, 0.42, 0.5),
            seat_h=_u(rng, 0.44, 0.52),
            seat_t=_u(rng, 0.06, 0.1),
            back_h=_u(rng, 0.38, 0.62),
            back_w_ratio=_u(rng, 0.8, 1.0),
            back_tilt=_u(rng, 0.08, 0.25),
            back_gap=_u(rng, 0.04, 0.1),
            n_star=int(rng.choice([4, 5, 5, 5, 6])),
            star_r=_u(rng, 0.26, 0.34),
            caster_r=_u(rng, 0.022, 0.032),
            arms=_pick(rng, ["none", "t"], [0.35, 0.65]),
            arm_h=_u(rng, 0.18, 0.25),
            column_r=_u(rng, 0.022, 0.035),
            headrest=bool(rng.random() < 0.2),
        )
    elif kind == "stool":
        d.update(
            seat_h=_u(rng, 0.45, 0.78),
            seat_r=_u(rng, 0.15, 0.21),
            seat_t=_u(rng, 0.025, 0.06),
            seat_shape=_pick(rng, ["round", "square"], [0.65, 0.35]),
            soft_seat=bool(rng.random() < 0.35),
            leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "pedestal"], [0.15, 0.2, 0.2, 0.3, 0.15]),
            n_legs=int(rng.choice([3, 4, 4])),
            leg_w=_u(rng, 0.022, 0.04),
            footrest=bool(rng.random() < 0.6),
            low_back=bool(rng.random() < 0.15),
            back_h=_u(rng, 0.12, 0.2),
            back_tilt=_u(rng, 0.05, 0.15),
            base_r=_u(rng, 0.16, 0.22),
        )
    elif kind == "bench":
        d.update(
            seat_w=_u(rng, 0.9, 1.6),
            seat_d=_u(rng, 0.32, 0.45),
            seat_h=_u(rng, 0.42, 0.47),
            seat_t=_u(rng, 0.03, 0.06),
            leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "slab", "sled"]),
            leg_w=_u(rng, 0.03, 0.05),
            seat_style=_pick(rng, ["solid", "slatted", "cushioned"]),
            n_slats=int(rng.integers(3, 6)),
            back=bool(rng.random() < 0.35),
            back_h=_u(rng, 0.3, 0.42),
            back_tilt=_u(rng, 0.05, 0.2),
            apron=bool(rng.random() < 0.6),
            six_legs=bool(rng.random() < 0.3),
        )
    elif kind == "sofa":
        n = int(rng.choice([2, 3, 3, 4]))
        d.update(
            n_seats=n,
            seat_w=n * _u(rng, 0.5, 0.62),
            seat_d=_u(rng, 0.75, 0.95),
            leg_h=_u(rng, 0.05, 0.16),
            base_t=_u(rng, 0.12, 0.2),
            cushion_t=_u(rng, 0.1, 0.16),
            back_h=_u(rng, 0.35, 0.5),
            back_t=_u(rng, 0.15, 0.25),
            back_tilt=_u(rng, 0.05, 0.2),
            arm_w=_u(rng, 0.1, 0.24),
            arm_h=_u(rng, 0.15, 0.28),
            arm_style=_pick(rng, ["box", "rolled", "none"], [0.5, 0.35, 0.15]),
            back_cushions=bool(rng.random() < 0.65),
            leg_style=_pick(rng, ["round", "tapered", "straight", "plinth"]),
            leg_w=_u(rng, 0.03, 0.05),
            radius=_u(rng, 0.015, 0.05),
        )
    else:
        raise ValueError(f"unknown furniture kind {kind!r}; expected one of {KINDS}")
    return d


# Continuous keys that a "similar" design may perturb; style keys it may change.
_STYLE_KEYS = ("leg_style", "back_style", "arms", "seat_shape", "seat_style", "arm_style", "n_slats")


def perturb_design(rng: np.random.Generator, design: dict[str, Any], amount: float = 0.12) -> dict[str, Any]:
    """A similar but different design: dimensions jittered by ~amount, sometimes one style changed."""
    new = copy.deepcopy(design)
    for key, value in design.items():
        if isinstance(value, float):
            new[key] = float(value * (1.0 + rng.uniform(-amount, amount)))
    styles = [k for k in _STYLE_KEYS if k in design]
    if styles and rng.random() < 0.5:
        fresh = sample_design(rng, design["kind"])
        key = styles[int(rng.integers(len(styles)))]
        new[key] = fresh[key]
    return new


# -- building blocks ------------------------------------------------------------------------------


class _Builder:
    def __init__(self) -> None:
        self.components: list[Component] = []

    def add(self, name: str, role: str, piece: Piece, soft: bool = False, unit: str = "") -> None:
        self.components.append(Component(name, role, piece, soft, unit or name))


def _leg_positions(w: float, d: float, inset: float, n: int = 4) -> list[tuple[str, float, float]]:
    """(name, x, z) of leg tops under a rectangular seat: front (+z) first."""
    x, z = w / 2 - inset, d / 2 - inset
    legs = [("front_left", -x, z), ("front_right", x, z), ("back_left", -x, -z), ("back_right", x, -z)]
    if n == 6:
        legs += [("middle_front", 0.0, z), ("middle_back", 0.0, -z)]
    return legs


def _add_legs(b: _Builder, style: str, positions, top: float, w: float, splay: float = 0.06) -> None:
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


def _add_apron(b: _Builder, w: float, d: float, y_top: float, inset: float, leg_w: float, h: float = 0.06) -> None:
    t = leg_w * 0.6
    x, z = w / 2 - inset, d / 2 - inset
    b.add("apron_front", "frame", box([0, y_top - h / 2, z], [2 * x, h, t]))
    b.add("apron_back", "frame", box([0, y_top - h / 2, -z], [2 * x, h, t]))
    b.add("apron_left", "frame", box([-x, y_top - h / 2, 0], [t, h, 2 * z]))
    b.add("apron_right", "frame", box([x, y_top - h / 2, 0], [t, h, 2 * z]))


def _add_stretchers(b: _Builder, w: float, d: float, y: float, inset: float, leg_w: float) -> None:
    r = leg_w * 0.3
    x, z = w / 2 - inset, d / 2 - inset
    b.add("stretcher_left", "frame", cylinder([-x, y, -z], [-x, y, z], r, segments=10))
    b.add("stretcher_right", "frame", cylinder([x, y, -z], [x, y, z], r, segments=10))
    b.add("stretcher_middle", "frame", cylinder([-x, y + 0.02, 0], [x, y + 0.02, 0], r, segments=10))


def _tilted(piece: Piece, pivot, tilt: float) -> Piece:
    """Lean a back piece backwards (towards -z) by `tilt` radians about a horizontal x-axis at pivot."""
    p = np.asarray(pivot, np.float64)
    return piece.transformed(None, -p).transformed(rotation_x(-tilt), p)


def _add_back(
    b: _Builder, style: str, w: float, z_back: float, y0: float, h: float, tilt: float, post_w: float, n_slats: int
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
        b.add(name, role, _tilted(piece, pivot, tilt), soft)


def _add_post_arms(
    b: _Builder, w: float, d: float, y_seat: float, arm_h: float, t: float, inset: float, soft: bool = False
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


# -- kinds ----------------------------------------------------------------------------------------


def _chair(d: dict[str, Any], b: _Builder) -> None:
    w, dd, h, t, lw = d["seat_w"], d["seat_d"], d["seat_h"], d["seat_t"], d["leg_w"]
    inset = lw / 2 + 0.01
    top = h - t
    _add_legs(b, d["leg_style"], _leg_positions(w, dd, inset), top, lw)
    if d["apron"] and d["leg_style"] not in ("sled",):
        _add_apron(b, w, dd, top, inset, lw)
    if d["stretchers"] and d["leg_style"] in ("straight", "tapered", "round"):
        _add_stretchers(b, w, dd, top * 0.3, inset, lw)
    if d["soft_seat"]:
        b.add(
            "seat_cushion",
            "seat",
            rounded_box([0, h - t / 2 + 0.01, 0.01], [w + 0.01, t + 0.02, dd + 0.01], 0.015),
            True,
        )
    else:
        b.add("seat_board", "seat", box([0, h - t / 2, 0], [w, t, dd]))
    _add_back(b, d["back_style"], w, -dd / 2 + lw / 2, h, d["back_h"], d["back_tilt"], lw, d["n_slats"])
    if d["arms"] == "post":
        _add_post_arms(b, w, dd, h, d["arm_h"], lw, inset)


def _armchair(d: dict[str, Any], b: _Builder) -> None:
    w, dd, h, lw = d["seat_w"], d["seat_d"], d["seat_h"], d["leg_w"]
    aw, ah = d["arm_w"], d["arm_h"]
    if d["style"] == "club":
        lh = d["leg_h"]
        body_t = max(h - lh - 0.06, 0.1)
        leg_style = "straight" if d["leg_style"] in ("sled", "splayed") else d["leg_style"]
        total_w = w + 2 * aw
        _add_legs(b, leg_style, _leg_positions(total_w, dd, lw), lh, lw)
        b.add("base_body", "frame", rounded_box([0, lh + body_t / 2, 0], [total_w, body_t, dd], 0.02), True)
        b.add("seat_cushion", "cushion", rounded_box([0, lh + body_t + 0.04, 0.02], [w, 0.1, dd - 0.1], 0.035), True)
        y_top = lh + body_t + ah + 0.08
        for side, sx in (("left", -(w + aw) / 2), ("right", (w + aw) / 2)):
            b.add(f"arm_{side}", "arms", rounded_box([sx, (lh + y_top) / 2, 0], [aw, y_top - lh, dd], 0.03), True)
        bh = d["back_h"] + ah
        back = rounded_box([0, lh + body_t + bh / 2, -dd / 2 + 0.09], [w, bh, 0.18], 0.04)
        b.add("back_body", "back", _tilted(back, [0, lh + body_t, -dd / 2 + 0.09], d["back_tilt"] * 0.5), True)
        return
    # framed: a wooden/metal chair frame with an upholstered seat cushion and back
    t = d["seat_t"]
    inset = lw / 2 + 0.01
    top = h - t
    _add_legs(b, d["leg_style"], _leg_positions(w, dd, inset), top, lw)
    if d["apron"] and d["leg_style"] != "sled":
        _add_apron(b, w, dd, top, inset, lw, h=0.05)
    b.add("seat_cushion", "cushion", rounded_box([0, h - t / 2, 0.01], [w - 0.02, t, dd], 0.03), True)
    _add_back(b, d["back_style"], w, -dd / 2 + lw / 2, h, d["back_h"], d["back_tilt"], lw, d["n_slats"])
    if d["arms"] == "post":
        _add_post_arms(b, w + 0.02, dd, h - t, ah + t, lw * 1.1, inset, soft=False)
    else:
        x = w / 2 + 0.025
        for side, sx in (("left", -x), ("right", x)):
            b.add(
                f"arm_{side}",
                "arms",
                rounded_box([sx, (top + h + ah) / 2, 0], [0.05, h + ah - top, dd * 0.9], 0.02),
                True,
            )


def _office_chair(d: dict[str, Any], b: _Builder) -> None:
    w, dd, h, t = d["seat_w"], d["seat_d"], d["seat_h"], d["seat_t"]
    n, sr, cr = d["n_star"], d["star_r"], d["caster_r"]
    hub_y = 2 * cr + 0.05
    # swivel base: caster wheels, star legs, hub, gas-lift column, mechanism
    for k in range(n):
        a = 2 * np.pi * k / n + np.pi / n
        direction = np.array([np.sin(a), 0.0, np.cos(a)])
        end = direction * sr + np.array([0.0, 2 * cr + 0.015, 0.0])
        start = np.array([0.0, hub_y, 0.0])
        b.add(f"star_leg_{k + 1}", "base", tube(np.array([start, end]), [0.022, 0.014], segments=10))
        axle = np.cross(direction, [0.0, 1.0, 0.0])
        wheel_c = end + np.array([0.0, -(cr + 0.012), 0.0]) + direction * 0.012
        b.add(
            f"caster_wheel_{k + 1}",
            "casters",
            cylinder(wheel_c - axle * 0.012, wheel_c + axle * 0.012, cr, segments=14),
            unit=f"caster_{k + 1}",
        )
        b.add(
            f"caster_fork_{k + 1}",
            "casters",
            box(end + np.array([0, -0.01, 0]), [0.03, 0.025, 0.03], rotation_y(a)),
            unit=f"caster_{k + 1}",
        )
    b.add("hub", "base", cylinder([0, hub_y - 0.03, 0], [0, hub_y + 0.03, 0], 0.045, 0.04, segments=16))
    b.add("column", "base", cylinder([0, hub_y, 0], [0, h - t - 0.04, 0], d["column_r"], segments=14))
    b.add("mechanism", "base", box([0, h - t - 0.03, 0], [0.18, 0.04, 0.2]))
    b.add("seat_cushion", "seat", rounded_box([0, h - t / 2, 0.0], [w, t, dd], min(0.03, t / 2.2)), True)
    bw = w * d["back_w_ratio"]
    y0 = h + d["back_gap"]
    z_back = -dd / 2 - 0.02
    bh = d["back_h"]
    pivot = [0, h, z_back]
    spine = box([0, h - t / 2 + (y0 + 0.1 - h) / 2, z_back - 0.02], [0.06, y0 + 0.1 - (h - t), 0.025])
    b.add("back_support", "frame", _tilted(spine, pivot, d["back_tilt"]))
    b.add(
        "back_cushion",
        "back",
        _tilted(rounded_box([0, y0 + bh / 2, z_back], [bw, bh, 0.06], 0.025), pivot, d["back_tilt"]),
        True,
    )
    if d["headrest"]:
        head = rounded_box([0, y0 + bh + 0.1, z_back - 0.01], [bw * 0.55, 0.12, 0.05], 0.02)
        b.add("headrest", "back", _tilted(head, pivot, d["back_tilt"]), True)
    if d["arms"] == "t":
        x = w / 2 + 0.03
        for side, sx in (("left", -x), ("right", x)):
            b.add(
                f"arm_post_{side}",
                "arms",
                box([sx, h + d["arm_h"] / 2 - 0.03, -0.03], [0.03, d["arm_h"] + 0.06, 0.05]),
                unit=f"arm_{side}",
            )
            b.add(
                f"armrest_{side}",
                "arms",
                rounded_box([sx, h + d["arm_h"] + 0.01, 0.0], [0.07, 0.03, 0.25], 0.012),
                unit=f"arm_{side}",
            )


def _stool(d: dict[str, Any], b: _Builder) -> None:
    h, r, t, lw = d["seat_h"], d["seat_r"], d["seat_t"], d["leg_w"]
    top = h - t
    soft = d["soft_seat"]
    if d["seat_shape"] == "round":
        seat = cylinder([0, top, 0], [0, h, 0], r, segments=32)
    else:
        seat = rounded_box([0, h - t / 2, 0], [2 * r, t, 2 * r], 0.012 if not soft else t / 2.5)
    b.add("seat_top", "seat", seat, soft)
    if d["leg_style"] == "pedestal":
        b.add("base_disc", "base", cylinder([0, 0, 0], [0, 0.025, 0], d["base_r"], d["base_r"] * 0.95, segments=32))
        b.add("column", "base", cylinder([0, 0.025, 0], [0, top, 0], 0.025, segments=16))
        if d["footrest"] and h > 0.6:
            ring_r = d["base_r"] * 0.9
            a = np.linspace(0, 2 * np.pi, 33)
            path = np.stack([ring_r * np.cos(a), np.full_like(a, top * 0.45), ring_r * np.sin(a)], 1)
            b.add("footrest", "frame", tube(path, 0.008, segments=10))
            for k in range(3):
                ang = 2 * np.pi * k / 3
                end = [ring_r * np.cos(ang), top * 0.45, ring_r * np.sin(ang)]
                b.add(f"footrest_spoke_{k + 1}", "frame", cylinder([0, top * 0.45, 0], end, 0.006, segments=8))
    else:
        n = d["n_legs"]
        rr = r * 0.75
        angles = 2 * np.pi * np.arange(n) / n + (np.pi / n if n == 4 else 0.0)
        positions = [(f"{k + 1}", rr * np.sin(a), rr * np.cos(a)) for k, a in enumerate(angles)]
        _add_legs(b, d["leg_style"], positions, top, lw, splay=0.05 + 0.08 * (h - 0.45))
        if d["footrest"]:
            y = top * 0.35
            for k in range(n):
                (_, x0, z0), (_, x1, z1) = positions[k], positions[(k + 1) % n]
                s = 1.0 + (0.05 + 0.08 * (h - 0.45)) / rr * 0.65 if d["leg_style"] == "splayed" else 1.0
                b.add(
                    f"footrest_{k + 1}",
                    "frame",
                    cylinder([x0 * s, y, z0 * s], [x1 * s, y, z1 * s], lw * 0.3, segments=8),
                )
    if d["low_back"]:
        bh = d["back_h"]
        back = rounded_box([0, h + bh / 2 + 0.05, -r * 0.85], [r * 1.4, bh, 0.03], 0.01)
        b.add("back_rest", "back", _tilted(back, [0, h, -r * 0.85], d["back_tilt"]), soft)
        for side, sx in (("left", -r * 0.5), ("right", r * 0.5)):
            b.add(
                f"back_post_{side}",
                "back",
                _tilted(box([sx, h + 0.04, -r * 0.85], [0.02, 0.1, 0.02]), [0, h, -r * 0.85], d["back_tilt"]),
            )


def _bench(d: dict[str, Any], b: _Builder) -> None:
    w, dd, h, t, lw = d["seat_w"], d["seat_d"], d["seat_h"], d["seat_t"], d["leg_w"]
    inset = lw / 2 + 0.03
    style = d["leg_style"]
    top = h - t
    if style == "slab":
        for side, sx in (("left", -(w / 2 - 0.08)), ("right", w / 2 - 0.08)):
            b.add(f"leg_{side}", "legs", box([sx, top / 2, 0], [0.04, top, dd * 0.9]))
    else:
        _add_legs(b, style, _leg_positions(w, dd, inset, 6 if d["six_legs"] and style != "sled" else 4), top, lw)
        if d["apron"] and style != "sled":
            _add_apron(b, w, dd, top, inset, lw)
    if d["seat_style"] == "slatted":
        n = d["n_slats"]
        gap = 0.01
        sd = (dd - gap * (n - 1)) / n
        for k in range(n):
            z = -dd / 2 + sd / 2 + k * (sd + gap)
            b.add(f"seat_slat_{k + 1}", "seat", box([0, h - t / 2, z], [w, t, sd]))
    else:
        b.add("seat_board", "seat", box([0, h - t / 2, 0], [w, t, dd]))
        if d["seat_style"] == "cushioned":
            b.add("seat_pad", "cushion", rounded_box([0, h + 0.03, 0], [w - 0.04, 0.06, dd - 0.03], 0.02), True)
    if d["back"]:
        _add_back(b, "slats_h", w, -dd / 2 + lw / 2, h, d["back_h"], d["back_tilt"], lw, 3)


def _sofa(d: dict[str, Any], b: _Builder) -> None:
    n, w, dd = d["n_seats"], d["seat_w"], d["seat_d"]
    lh, bt, ct = d["leg_h"], d["base_t"], d["cushion_t"]
    aw = d["arm_w"] if d["arm_style"] != "none" else 0.0
    rad = d["radius"]
    total_w = w + 2 * aw
    if d["leg_style"] == "plinth":
        b.add("plinth", "legs", box([0, lh / 2, 0], [total_w - 0.06, lh, dd - 0.06]))
    else:
        inset = d["leg_w"] / 2 + 0.04
        _add_legs(b, d["leg_style"], _leg_positions(total_w, dd, inset, 6 if n >= 3 else 4), lh, d["leg_w"])
    y_base = lh
    b.add("base_body", "frame", rounded_box([0, y_base + bt / 2, 0], [total_w, bt, dd], rad), True)
    y_cush = y_base + bt
    back_t = d["back_t"]
    cw = w / n
    for k in range(n):
        x = -w / 2 + cw * (k + 0.5)
        b.add(
            f"seat_cushion_{k + 1}",
            "cushion",
            rounded_box([x, y_cush + ct / 2, back_t / 2], [cw - 0.01, ct, dd - back_t], min(rad * 1.5, ct / 2.2)),
            True,
        )
    bh = d["back_h"] + ct
    zb = -dd / 2 + back_t / 2
    back = rounded_box([0, y_cush + bh / 2, zb], [w + 0.001, bh, back_t], rad)
    b.add("back_frame", "back", _tilted(back, [0, y_cush, zb], d["back_tilt"] * 0.4), True)
    if d["back_cushions"]:
        for k in range(n):
            x = -w / 2 + cw * (k + 0.5)
            cush = rounded_box(
                [x, y_cush + ct + d["back_h"] * 0.45, zb + back_t / 2 + 0.06],
                [cw - 0.02, d["back_h"] * 0.8, 0.12],
                min(0.05, rad * 2),
            )
            b.add(f"back_cushion_{k + 1}", "cushion", _tilted(cush, [0, y_cush + ct, zb], d["back_tilt"]), True)
    if aw > 0:
        ah = d["arm_h"] + ct
        for side, sx in (("left", -(w + aw) / 2), ("right", (w + aw) / 2)):
            centre = [sx, y_cush + ah / 2, 0]
            b.add(f"arm_{side}", "arms", rounded_box(centre, [aw, ah, dd], rad), True)
            if d["arm_style"] == "rolled":
                b.add(
                    f"arm_roll_{side}",
                    "arms",
                    cylinder([sx, y_cush + ah, -dd / 2], [sx, y_cush + ah, dd / 2 + 0.01], aw * 0.6, segments=20),
                    True,
                    unit=f"arm_{side}",
                )


_BUILDERS = {
    "chair": _chair,
    "armchair": _armchair,
    "office_chair": _office_chair,
    "stool": _stool,
    "bench": _bench,
    "sofa": _sofa,
}


def build_components(design: dict[str, Any]) -> list[Component]:
    """The named object components of a design, in metres (floor at y = 0, front towards +z)."""
    b = _Builder()
    _BUILDERS[design["kind"]](design, b)
    return b.components


# -- segmentation into material parts -------------------------------------------------------------

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


# -- built-in materials ---------------------------------------------------------------------------

_BUILTIN_COLOURS: dict[str, list[tuple[float, float, float]]] = {
    "wood": [(0.55, 0.38, 0.22), (0.36, 0.22, 0.13), (0.72, 0.56, 0.38), (0.47, 0.27, 0.17)],
    "metal": [(0.62, 0.62, 0.64), (0.25, 0.25, 0.27), (0.8, 0.8, 0.82)],
    "plastic": [(0.92, 0.92, 0.9), (0.1, 0.1, 0.1), (0.6, 0.1, 0.1), (0.2, 0.3, 0.55)],
    "fabric": [(0.5, 0.5, 0.52), (0.22, 0.28, 0.45), (0.7, 0.64, 0.55), (0.3, 0.42, 0.3), (0.55, 0.18, 0.16)],
    "leather": [(0.32, 0.18, 0.1), (0.08, 0.07, 0.07), (0.6, 0.38, 0.2), (0.88, 0.85, 0.8)],
}
_BUILTIN_BRDF = {
    "wood": (0.6, 0.0),
    "metal": (0.3, 1.0),
    "plastic": (0.35, 0.0),
    "fabric": (0.9, 0.0),
    "leather": (0.5, 0.0),
}


def _builtin_material(rng: np.random.Generator, part: FurniturePart) -> dict[str, Any]:
    """A plausible flat material as a modeller would have left it (Kd colour, no texture)."""
    prior = SUBSTANCE_PRIOR[part.prior_key]
    subs = sorted(prior)
    substance = subs[int(rng.choice(len(subs), p=np.array([prior[s] for s in subs]) / sum(prior.values())))]
    colours = _BUILTIN_COLOURS[substance]
    base = np.array(colours[int(rng.integers(len(colours)))])
    colour = np.clip(base * rng.uniform(0.9, 1.1, 3), 0.0, 1.0)
    roughness, metallic = _BUILTIN_BRDF[substance]
    return {
        "albedo": [round(float(c), 4) for c in colour],
        "roughness": roughness,
        "metallic": metallic,
        "name": part.name,
    }


# -- whole shapes ---------------------------------------------------------------------------------


def normalise(parts: list[FurniturePart]) -> None:
    """Move and scale all parts into the unit cube (centred, longest side 1), in place; UVs too."""
    allv = np.concatenate([c.piece.vertices for p in parts for c in p.components])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    centre = (lo + hi) / 2
    factor = 1.0 / float((hi - lo).max())
    for p in parts:
        for c in p.components:
            c.piece = c.piece.scaled(factor, centre)


def generate_furniture(
    rng: np.random.Generator,
    source_id: str,
    kind: str | None = None,
    design: dict[str, Any] | None = None,
    segmentation: str | None = None,
) -> Furniture:
    """One random shape (or the shape of a given design), segmented and normalised."""
    if design is None:
        if kind is None:
            kind = KINDS[int(rng.choice(len(KINDS), p=np.array(KIND_WEIGHTS) / sum(KIND_WEIGHTS)))]
        design = sample_design(rng, kind)
    if segmentation is None:
        segmentation = SEGMENTATIONS[int(rng.choice(3, p=[0.6, 0.2, 0.2]))]
    components = build_components(design)
    parts, segmentation = segment(components, segmentation, rng)
    for part in parts:
        part.builtin = _builtin_material(rng, part)
    normalise(parts)
    return Furniture(source_id=source_id, kind=design["kind"], segmentation=segmentation, parts=parts, design=design)
