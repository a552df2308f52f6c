"""Descriptor preparation (square crop, resize, pad) and self-retrieval of a rendered shape."""

from __future__ import annotations

import math

import numpy as np
import pytest

from photoshape_flow.align.descriptors import (
    HogParams,
    crop_mask,
    crop_square,
    descriptors,
    exemplar_descriptor,
    prepare,
    square_box,
    view_descriptors,
)


def test_square_box_and_crop_fill_outside_the_image() -> None:
    mask = np.zeros((40, 60), bool)
    mask[5:15, 50:60] = True  # touches the right border
    mask[10:12, 30:32] = True
    box = square_box(mask)
    assert box == (30, -5, 30)  # 10 rows x 30 cols -> a 30-pixel square, centred: leaves the image
    crop = crop_square(np.arange(40 * 60).reshape(40, 60), 50, -5, 20, fill=-1)
    assert crop.shape == (20, 20)
    assert (crop[:5] == -1).all() and (crop[:, 10:] == -1).all() and crop[5, 0] == 50
    assert square_box(np.zeros((5, 5), bool)) is None


def test_prepare_is_translation_and_scale_invariant() -> None:
    params = HogParams(blur_sigma=0.0, channels="all31")
    small = np.ones((120, 120), np.float32)
    mask_small = np.zeros((120, 120), bool)
    mask_small[20:60, 30:50] = True
    small[mask_small] = 0.3
    small[20:40, 30:50] = 0.6
    big = np.kron(small, np.ones((2, 2), np.float32))  # the same object twice as large
    big = np.roll(big, (7, -11), axis=(0, 1))
    mask_big = np.roll(np.kron(mask_small, np.ones((2, 2), bool)), (7, -11), axis=(0, 1))
    a, b = prepare(small, mask_small, params), prepare(big, mask_big, params)
    assert a.shape == (116, 116) and abs(a.mean()) < 1e-5 and abs(a.std() - 1) < 1e-3
    assert np.abs(a - b).mean() < 0.03  # only resampling differences along the edges
    da, db = descriptors(small[None], mask_small[None], params), descriptors(big[None], mask_big[None], params)
    assert da.shape == (1, params.dims) == (1, 13 * 13 * 31)
    other = small.copy()
    other[20:40, 30:50], other[40:60, 30:50] = 0.3, 0.6  # the same silhouette, the stripe moved
    do = descriptors(other[None], mask_small[None], params)
    assert np.linalg.norm(da - db) < 0.5 * np.linalg.norm(da - do)


def test_exemplar_and_view_paths_agree() -> None:
    params = HogParams(channels="all31")
    grey = np.ones((90, 90), np.float32)
    ids = np.zeros((90, 90), np.uint16)
    ids[20:70, 30:60] = 1
    ids[20:35, 30:60] = 2
    grey[ids == 1], grey[ids == 2] = 0.4, 0.7
    rgb = np.repeat((grey * 255).round().astype(np.uint8)[..., None], 3, axis=2)
    view = view_descriptors(grey[None], ids[None], params)[0]
    photo = exemplar_descriptor(rgb, (ids > 0).astype(np.uint8) * 255, params)
    assert view.shape == photo.shape == (13 * 13 * 31,)
    np.testing.assert_allclose(view, photo, atol=0.02)
    # a mask stored at another resolution than the photo is resized to it
    half = ((ids[::2, ::2] > 0) * 255).astype(np.uint8)
    assert exemplar_descriptor(rgb, half, params).shape == photo.shape
    # an empty mask gives a zero descriptor rather than an error
    assert not view_descriptors(grey[None], np.zeros_like(ids)[None], params).any()
    assert crop_mask(ids > 0, 32).shape == (32, 32)


def test_params_name_dims_and_hash() -> None:
    p = HogParams()
    assert p.name == "hog-insensitive9" and p.dims == 13 * 13 * 9
    assert HogParams(channels="energy8").dims == 1352  # the paper's
    assert HogParams(channels="all31").dims == 13 * 13 * 31
    assert p.params_hash(mesh="a") != p.params_hash(mesh="b") != HogParams(blur_sigma=1.0).params_hash(mesh="b")
    assert HogParams.from_dict(p.to_dict()) == p
    with pytest.raises(ValueError):
        HogParams(channels="bogus")


@pytest.mark.render
def test_rendered_shape_retrieves_itself_at_its_pose() -> None:
    from photoshape_flow.align.descriptors import render_view_descriptors
    from photoshape_flow.align.index import ArrayDatabase
    from photoshape_flow.align.retrieval import search
    from photoshape_flow.align.viewpoints import ViewpointParams, viewpoints
    from photoshape_flow.render.renderer import Renderer
    from photoshape_flow.render.testing import box_part, normalise_to_unit_cube

    def chair(back: float, arm: bool, leg: float):  # an asymmetric chair built from boxes
        parts = [
            box_part(1, (0, 0, 0), (0.3, 0.04, 0.3), "seat"),
            box_part(2, (0, back / 2, -0.27), (0.3, back / 2, 0.03), "back"),
            box_part(3, (0.2, -leg / 2, 0.2), (0.03, leg / 2, 0.03), "leg"),
            box_part(4, (-0.2, -leg / 2, -0.2), (0.03, leg / 2, 0.03), "leg2"),
        ]
        if arm:
            parts.append(box_part(5, (0.28, 0.12, 0.0), (0.02, 0.1, 0.25), "arm"))
        return normalise_to_unit_cube(parts)

    shapes = [chair(0.5, True, 0.4), chair(0.25, False, 0.45), chair(0.7, False, 0.2)]
    params = HogParams(render_size=128)
    cams = viewpoints(ViewpointParams(num_rings=4, equator_azimuths=16))
    renderer = Renderer()
    db = np.stack([render_view_descriptors(renderer, s, cams, params) for s in shapes]).astype(np.float16)
    for target_view in (5, len(cams) - 3):
        true = cams[target_view]
        # the "photo": a larger render, slightly off the grid, 1 degree away from the view
        cam = true.replace(azimuth=true.azimuth + math.radians(1.0))
        sweep = renderer.sweep(shapes[0], [cam], size=256, shaded=True)
        rgb = np.repeat((sweep.shaded[0] * 255).round().astype(np.uint8)[..., None], 3, axis=2)
        query = exemplar_descriptor(rgb, sweep.part_ids[0] > 0, params)
        found = search(query[None], ArrayDatabase(db), 3)
        assert found.shapes[0, 0] == 0
        assert found.views[0, 0] == target_view
