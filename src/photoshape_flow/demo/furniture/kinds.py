"""One builder per kind of seating: a design dict in, named components (in metres) out.

The floor is at y = 0 and the front faces +z; `furniture.normalise` later moves the shape into the
unit cube.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from photoshape_flow.demo.furniture.blocks import (
    Builder,
    add_apron,
    add_back,
    add_legs,
    add_post_arms,
    add_stretchers,
    leg_positions,
    tilted,
)
from photoshape_flow.demo.furniture.model import Component
from photoshape_flow.demo.primitives import box, cylinder, rotation_y, rounded_box, tube


def _chair(d: dict[str, Any], b: Builder) -> None:
    w, dd, h, t, lw = d["seat_w"], d["seat_d"], d["seat_h"], d["seat_t"], d["leg_w"]
    inset = lw / 2 + 0.01
    top = h - t
    add_legs(b, d["leg_style"], leg_positions(w, dd, inset), top, lw)
    if d["apron"] and d["leg_style"] not in ("sled",):
        add_apron(b, w, dd, top, inset, lw)
    if d["stretchers"] and d["leg_style"] in ("straight", "tapered", "round"):
        add_stretchers(b, w, dd, top * 0.3, inset, lw)
    if d["soft_seat"]:
        b.add(
            "seat_cushion",
            "seat",
            rounded_box([0, h - t / 2 + 0.01, 0.01], [w + 0.01, t + 0.02, dd + 0.01], 0.015),
            True,
        )
    else:
        b.add("seat_board", "seat", box([0, h - t / 2, 0], [w, t, dd]))
    add_back(b, d["back_style"], w, -dd / 2 + lw / 2, h, d["back_h"], d["back_tilt"], lw, d["n_slats"])
    if d["arms"] == "post":
        add_post_arms(b, w, dd, h, d["arm_h"], lw, inset)


def _armchair(d: dict[str, Any], b: Builder) -> None:
    w, dd, h, lw = d["seat_w"], d["seat_d"], d["seat_h"], d["leg_w"]
    aw, ah = d["arm_w"], d["arm_h"]
    if d["style"] == "club":
        lh = d["leg_h"]
        body_t = max(h - lh - 0.06, 0.1)
        leg_style = "straight" if d["leg_style"] in ("sled", "splayed") else d["leg_style"]
        total_w = w + 2 * aw
        add_legs(b, leg_style, leg_positions(total_w, dd, lw), lh, lw)
        b.add("base_body", "frame", rounded_box([0, lh + body_t / 2, 0], [total_w, body_t, dd], 0.02), True)
        b.add("seat_cushion", "cushion", rounded_box([0, lh + body_t + 0.04, 0.02], [w, 0.1, dd - 0.1], 0.035), True)
        y_top = lh + body_t + ah + 0.08
        for side, sx in (("left", -(w + aw) / 2), ("right", (w + aw) / 2)):
            b.add(f"arm_{side}", "arms", rounded_box([sx, (lh + y_top) / 2, 0], [aw, y_top - lh, dd], 0.03), True)
        bh = d["back_h"] + ah
        back = rounded_box([0, lh + body_t + bh / 2, -dd / 2 + 0.09], [w, bh, 0.18], 0.04)
        b.add("back_body", "back", tilted(back, [0, lh + body_t, -dd / 2 + 0.09], d["back_tilt"] * 0.5), True)
        return
    # framed: a wooden/metal chair frame with an upholstered seat cushion and back
    t = d["seat_t"]
    inset = lw / 2 + 0.01
    top = h - t
    add_legs(b, d["leg_style"], leg_positions(w, dd, inset), top, lw)
    if d["apron"] and d["leg_style"] != "sled":
        add_apron(b, w, dd, top, inset, lw, h=0.05)
    b.add("seat_cushion", "cushion", rounded_box([0, h - t / 2, 0.01], [w - 0.02, t, dd], 0.03), True)
    add_back(b, d["back_style"], w, -dd / 2 + lw / 2, h, d["back_h"], d["back_tilt"], lw, d["n_slats"])
    if d["arms"] == "post":
        add_post_arms(b, w + 0.02, dd, h - t, ah + t, lw * 1.1, inset, soft=False)
    else:
        x = w / 2 + 0.025
        for side, sx in (("left", -x), ("right", x)):
            b.add(
                f"arm_{side}",
                "arms",
                rounded_box([sx, (top + h + ah) / 2, 0], [0.05, h + ah - top, dd * 0.9], 0.02),
                True,
            )


def _office_chair(d: dict[str, Any], b: Builder) -> None:
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
    b.add("back_support", "frame", tilted(spine, pivot, d["back_tilt"]))
    b.add(
        "back_cushion",
        "back",
        tilted(rounded_box([0, y0 + bh / 2, z_back], [bw, bh, 0.06], 0.025), pivot, d["back_tilt"]),
        True,
    )
    if d["headrest"]:
        head = rounded_box([0, y0 + bh + 0.1, z_back - 0.01], [bw * 0.55, 0.12, 0.05], 0.02)
        b.add("headrest", "back", tilted(head, pivot, d["back_tilt"]), True)
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


def _stool(d: dict[str, Any], b: Builder) -> None:
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
        add_legs(b, d["leg_style"], positions, top, lw, splay=0.05 + 0.08 * (h - 0.45))
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
        b.add("back_rest", "back", tilted(back, [0, h, -r * 0.85], d["back_tilt"]), soft)
        for side, sx in (("left", -r * 0.5), ("right", r * 0.5)):
            b.add(
                f"back_post_{side}",
                "back",
                tilted(box([sx, h + 0.04, -r * 0.85], [0.02, 0.1, 0.02]), [0, h, -r * 0.85], d["back_tilt"]),
            )


def _bench(d: dict[str, Any], b: Builder) -> None:
    w, dd, h, t, lw = d["seat_w"], d["seat_d"], d["seat_h"], d["seat_t"], d["leg_w"]
    inset = lw / 2 + 0.03
    style = d["leg_style"]
    top = h - t
    if style == "slab":
        for side, sx in (("left", -(w / 2 - 0.08)), ("right", w / 2 - 0.08)):
            b.add(f"leg_{side}", "legs", box([sx, top / 2, 0], [0.04, top, dd * 0.9]))
    else:
        add_legs(b, style, leg_positions(w, dd, inset, 6 if d["six_legs"] and style != "sled" else 4), top, lw)
        if d["apron"] and style != "sled":
            add_apron(b, w, dd, top, inset, lw)
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
        add_back(b, "slats_h", w, -dd / 2 + lw / 2, h, d["back_h"], d["back_tilt"], lw, 3)


def _sofa(d: dict[str, Any], b: Builder) -> None:
    n, w, dd = d["n_seats"], d["seat_w"], d["seat_d"]
    lh, bt, ct = d["leg_h"], d["base_t"], d["cushion_t"]
    aw = d["arm_w"] if d["arm_style"] != "none" else 0.0
    rad = d["radius"]
    total_w = w + 2 * aw
    if d["leg_style"] == "plinth":
        b.add("plinth", "legs", box([0, lh / 2, 0], [total_w - 0.06, lh, dd - 0.06]))
    else:
        inset = d["leg_w"] / 2 + 0.04
        add_legs(b, d["leg_style"], leg_positions(total_w, dd, inset, 6 if n >= 3 else 4), lh, d["leg_w"])
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
    b.add("back_frame", "back", tilted(back, [0, y_cush, zb], d["back_tilt"] * 0.4), True)
    if d["back_cushions"]:
        for k in range(n):
            x = -w / 2 + cw * (k + 0.5)
            cush = rounded_box(
                [x, y_cush + ct + d["back_h"] * 0.45, zb + back_t / 2 + 0.06],
                [cw - 0.02, d["back_h"] * 0.8, 0.12],
                min(0.05, rad * 2),
            )
            b.add(f"back_cushion_{k + 1}", "cushion", tilted(cush, [0, y_cush + ct, zb], d["back_tilt"]), True)
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
    b = Builder()
    _BUILDERS[design["kind"]](design, b)
    return b.components
