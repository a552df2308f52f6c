"""Seeded designs: the dimensions (metres) and style choices of one piece of seating of a kind.

A design is a flat dict, so a "similar" shape is the same dict with its numbers jittered
(`perturb_design`); the random draws happen in a fixed order, so a seed always gives one design.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np

KINDS: tuple[str, ...] = ("chair", "armchair", "office_chair", "stool", "bench", "sofa")
KIND_WEIGHTS: tuple[float, ...] = (0.28, 0.16, 0.16, 0.14, 0.1, 0.16)


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _pick(rng: np.random.Generator, options: Sequence[Any], p: Sequence[float] | None = None) -> Any:
    options = list(options)
    return options[int(rng.choice(len(options), p=p))]


def sample_design(rng: np.random.Generator, kind: str) -> dict[str, Any]:
    """Random dimensions (metres) and style choices for one piece of seating of `kind`.

    The keyword order is the draw order: reordering a kind's entries changes every design of it.
    """
    d: dict[str, Any] = {"kind": kind}
    if kind == "chair":
        d.update(
            seat_w=_u(rng, 0.40, 0.50), seat_d=_u(rng, 0.38, 0.48), seat_h=_u(rng, 0.43, 0.48),
            back_h=_u(rng, 0.32, 0.50), back_tilt=_u(rng, 0.03, 0.22), leg_w=_u(rng, 0.025, 0.045),
            leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "sled"], [0.25, 0.25, 0.2, 0.2, 0.1]),
            back_style=_pick(rng, ["slats_v", "slats_h", "spindles", "panel", "upholstered"]),
            n_slats=int(rng.integers(2, 6)), soft_seat=bool(rng.random() < 0.4), seat_t=_u(rng, 0.025, 0.045),
            apron=bool(rng.random() < 0.6), stretchers=bool(rng.random() < 0.35),
            arms=_pick(rng, ["none", "post"], [0.8, 0.2]), arm_h=_u(rng, 0.18, 0.25),
        )
    elif kind == "armchair":
        d.update(
            style=_pick(rng, ["club", "framed"]), seat_w=_u(rng, 0.55, 0.72), seat_d=_u(rng, 0.5, 0.62),
            seat_h=_u(rng, 0.38, 0.45), back_h=_u(rng, 0.38, 0.58), back_tilt=_u(rng, 0.08, 0.28),
            leg_w=_u(rng, 0.03, 0.05), leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "sled"]),
            arm_w=_u(rng, 0.08, 0.2), arm_h=_u(rng, 0.18, 0.26), leg_h=_u(rng, 0.08, 0.2), seat_t=_u(rng, 0.08, 0.14),
            arms=_pick(rng, ["post", "panel"]),
            back_style=_pick(rng, ["upholstered", "panel", "spindles"], [0.7, 0.15, 0.15]),
            n_slats=int(rng.integers(3, 7)), apron=bool(rng.random() < 0.5), stretchers=False,
        )
    elif kind == "office_chair":
        d.update(
            seat_w=_u(rng, 0.44, 0.54), seat_d=_u(rng, 0.42, 0.5), seat_h=_u(rng, 0.44, 0.52),
            seat_t=_u(rng, 0.06, 0.1), back_h=_u(rng, 0.38, 0.62), back_w_ratio=_u(rng, 0.8, 1.0),
            back_tilt=_u(rng, 0.08, 0.25), back_gap=_u(rng, 0.04, 0.1), n_star=int(rng.choice([4, 5, 5, 5, 6])),
            star_r=_u(rng, 0.26, 0.34), caster_r=_u(rng, 0.022, 0.032), arms=_pick(rng, ["none", "t"], [0.35, 0.65]),
            arm_h=_u(rng, 0.18, 0.25), column_r=_u(rng, 0.022, 0.035), headrest=bool(rng.random() < 0.2),
        )
    elif kind == "stool":
        d.update(
            seat_h=_u(rng, 0.45, 0.78), seat_r=_u(rng, 0.15, 0.21), seat_t=_u(rng, 0.025, 0.06),
            seat_shape=_pick(rng, ["round", "square"], [0.65, 0.35]), soft_seat=bool(rng.random() < 0.35),
            leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "pedestal"], [0.15, 0.2, 0.2, 0.3, 0.15]),
            n_legs=int(rng.choice([3, 4, 4])), leg_w=_u(rng, 0.022, 0.04), footrest=bool(rng.random() < 0.6),
            low_back=bool(rng.random() < 0.15), back_h=_u(rng, 0.12, 0.2), back_tilt=_u(rng, 0.05, 0.15),
            base_r=_u(rng, 0.16, 0.22),
        )
    elif kind == "bench":
        d.update(
            seat_w=_u(rng, 0.9, 1.6), seat_d=_u(rng, 0.32, 0.45), seat_h=_u(rng, 0.42, 0.47),
            seat_t=_u(rng, 0.03, 0.06),
            leg_style=_pick(rng, ["straight", "tapered", "round", "splayed", "slab", "sled"]),
            leg_w=_u(rng, 0.03, 0.05), seat_style=_pick(rng, ["solid", "slatted", "cushioned"]),
            n_slats=int(rng.integers(3, 6)), back=bool(rng.random() < 0.35), back_h=_u(rng, 0.3, 0.42),
            back_tilt=_u(rng, 0.05, 0.2), apron=bool(rng.random() < 0.6), six_legs=bool(rng.random() < 0.3),
        )
    elif kind == "sofa":
        n = int(rng.choice([2, 3, 3, 4]))
        d.update(
            n_seats=n, seat_w=n * _u(rng, 0.5, 0.62), seat_d=_u(rng, 0.75, 0.95), leg_h=_u(rng, 0.05, 0.16),
            base_t=_u(rng, 0.12, 0.2), cushion_t=_u(rng, 0.1, 0.16), back_h=_u(rng, 0.35, 0.5),
            back_t=_u(rng, 0.15, 0.25), back_tilt=_u(rng, 0.05, 0.2), arm_w=_u(rng, 0.1, 0.24),
            arm_h=_u(rng, 0.15, 0.28), arm_style=_pick(rng, ["box", "rolled", "none"], [0.5, 0.35, 0.15]),
            back_cushions=bool(rng.random() < 0.65), leg_style=_pick(rng, ["round", "tapered", "straight", "plinth"]),
            leg_w=_u(rng, 0.03, 0.05), radius=_u(rng, 0.015, 0.05),
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
