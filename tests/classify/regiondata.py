"""Colour-coded toy training data for the classifier and substance-network tests (no renderer needed).

Each render is a white square with two or three rectangular regions; every material has its own
colour plus a material-specific stripe pattern, so a small network can tell them apart in a few steps.
`toy_substances` is the substance network's equivalent: rectangles whose colour encodes the label.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from photoshape_flow.classify.dataset import RenderItem
from photoshape_flow.classify.substance_net import NUM_CLASSES
from photoshape_flow.classify.substance_train import SubstanceData

# substance label -> RGB colour of `toy_substances`' rectangles
SUBSTANCE_COLOURS = {1: (120, 60, 30), 2: (40, 90, 160), 3: (170, 120, 70), 4: (150, 150, 160), 5: (30, 160, 60)}


def toy_substances(n: int, size: int = 32, seed: int = 0) -> SubstanceData:
    """White background with two rectangles whose colour encodes their substance label."""
    rng = np.random.default_rng(seed)
    images, labels = [], []
    for _ in range(n):
        image = np.full((size, size, 3), 255, np.uint8)
        label = np.zeros((size, size), np.uint8)
        for _rect in range(2):
            k = int(rng.integers(1, NUM_CLASSES))
            y0, x0 = rng.integers(0, size // 2, 2)
            h, w = rng.integers(size // 4, size // 2, 2)
            noise = rng.integers(-15, 16, (h, w, 3))
            image[y0 : y0 + h, x0 : x0 + w] = np.clip(np.array(SUBSTANCE_COLOURS[k]) + noise, 0, 255)
            label[y0 : y0 + h, x0 : x0 + w] = k
        images.append(image)
        labels.append(label)
    return SubstanceData(images=images, labels=labels)

# material id -> (substance, RGB colour)
TOY_MATERIALS: dict[int, tuple[str, tuple[int, int, int]]] = {
    3: ("wood", (150, 90, 40)),
    5: ("wood", (200, 150, 90)),
    7: ("fabric", (40, 60, 170)),
    8: ("metal", (120, 120, 130)),
}


def render_arrays(index: int, size: int, materials: dict[int, tuple[str, tuple[int, int, int]]], seed: int = 0):
    rng = np.random.default_rng(seed * 1000 + index)
    ids = list(materials)
    chosen = rng.choice(ids, size=min(3, len(ids)), replace=False)
    image = np.full((size, size, 3), 255, np.uint8)
    id_map = np.zeros((size, size), np.uint16)
    bands = np.linspace(size // 8, size - size // 8, len(chosen) + 1).astype(int)
    yy, xx = np.mgrid[0:size, 0:size]
    for k, mid in enumerate(chosen):
        x0, x1 = sorted(rng.integers(size // 8, size - size // 8, size=2))
        x1 = max(x1, x0 + size // 4)
        y0, y1 = bands[k], bands[k + 1]
        region = np.zeros((size, size), bool)
        region[y0:y1, x0:min(x1, size)] = True
        colour = np.array(materials[int(mid)][1], np.float32)
        stripes = 1.0 + 0.15 * np.sin((xx * (1 + int(mid) % 3) + yy * (int(mid) % 2)) * 0.8)
        shade = np.clip(colour[None, None] * stripes[..., None] + rng.normal(0, 4, (size, size, 3)), 0, 255)
        image[region] = shade[region].astype(np.uint8)
        id_map[region] = int(mid)
    return image, id_map


def write_renders(
    root: Path, count: int, size: int = 48, materials=TOY_MATERIALS, seed: int = 0, start: int = 0
) -> list[RenderItem]:
    root.mkdir(parents=True, exist_ok=True)
    items = []
    for i in range(start, start + count):
        image, id_map = render_arrays(i, size, materials, seed)
        image_path, map_path = root / f"r{i:04d}.png", root / f"r{i:04d}_ids.png"
        cv2.imwrite(str(image_path), image[..., ::-1])
        cv2.imwrite(str(map_path), id_map)
        items.append(RenderItem(image_path, map_path, f"r{i:04d}"))
    return items


def substance_of(materials=TOY_MATERIALS) -> dict[int, str]:
    return {mid: value[0] for mid, value in materials.items()}
