"""Substance probabilities of an image's parts from either substance network family (section 4.3).

The stage's contract is a (6, H, W) probability map in SUBSTANCE_LABELS order that
`classify.substance_parts` turns into one substance per part. The from-scratch segmentation network
(`classify.substance_net`) predicts it per pixel. The part recogniser on a pretrained backbone
(`classify.part_net`, read through `MaterialClassifier`) classifies each part of the aligned part map
as a whole, from its own pixels; its map is *painted*: every pixel of a part carries that part's
substance vector, background pixels are background. The part-level vote, confidence and calibration
then read the recogniser's part probabilities exactly, and nothing downstream knows which family ran.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from photoshape_flow.classify.configs import ClassifierConfig, get_config
from photoshape_flow.classify.infer import MaterialClassifier
from photoshape_flow.classify.substance_configs import SubstanceTrainConfig
from photoshape_flow.classify.substance_train import predict_substances
from photoshape_flow.vocab import SUBSTANCE_LABELS


def recogniser_config(config: SubstanceTrainConfig) -> ClassifierConfig:
    """The part recogniser's training config for a backbone `SubstanceTrainConfig`.

    The classifier's ``backbone`` preset (augmentation, crop, fine-tuned stages) with the substance
    preset's budget; the epoch kept is the one with the best validation substance accuracy, the
    head this stage reads.
    """
    tiny = config.size < 64
    return get_config(
        "backbone", arch=config.arch, image_size=config.size, crop_size=32 if tiny else 160,
        epochs=config.epochs, finetune_epochs=config.epochs, batch_size=config.batch_size,
        max_steps_per_epoch=config.iters_per_epoch, lr=config.lr, select_metric="sub@1", seed=config.seed,
        background_every=0, eval_batch_size=32 if tiny else 64,
    )


def painted_substance_map(classifier: MaterialClassifier, image_rgb: np.ndarray, part_map: np.ndarray) -> np.ndarray:
    """(6, H, W) at the part map's size: each part's substance-head probabilities on its pixels."""
    part_map = np.asarray(part_map)
    h, w = part_map.shape
    out = np.zeros((len(SUBSTANCE_LABELS), h, w), np.float32)
    out[0] = 1.0
    indices = [int(i) for i in np.unique(part_map) if i > 0]
    if not indices:
        return out
    image = np.asarray(image_rgb)[..., :3]
    at_image = part_map
    if part_map.shape != image.shape[:2]:
        at_image = cv2.resize(part_map.astype(np.int32), (image.shape[1], image.shape[0]),
                              interpolation=cv2.INTER_NEAREST)
    kept = [i for i in indices if (at_image == i).any()]
    if not kept:
        return out
    _, substances = classifier.predict(image, [at_image == i for i in kept])
    for index, probs in zip(kept, substances, strict=True):
        out[:, part_map == index] = probs[:, None]
    return out


def substance_map(network: Any, image_rgb: np.ndarray, part_map: np.ndarray, size: int,
                  bn_prior: float | None = None) -> np.ndarray:
    """Substance probabilities (6, h, w) of an image whose parts `part_map` labels, from either family.

    The segmentation network's map is at the image's size (callers resize it to the part map); the
    recogniser's is painted at the part map's size.
    """
    if isinstance(network, MaterialClassifier):
        network.bn_prior = bn_prior
        return painted_substance_map(network, image_rgb, part_map)
    return predict_substances(network, image_rgb, size, bn_prior=bn_prior)
