"""A frozen ImageNet backbone read as texture feature maps (for `fit.deep_texture`).

The fit compares a rendered part with the photo's by the moments of these maps over the part's mask;
the frame is read upsampled so that the parts of a 128 px frame span several cells at stride 16, and
the maps stop at stage 3, so a read costs a fraction of a classification.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from photoshape_flow.classify.backbone import load_backbone

STAGES = (1, 2, 3)  # taps at the ends of EfficientNet-Lite stages 1-3 (strides 4, 8, 16 of the input)
UPSCALE = 2.0  # a 20 px part of a 128 px frame then spans 2-3 cells at stride 16


class FeatureMaps:
    """The frozen backbone that turns an sRGB frame into the maps `fit.deep_texture.deep_stats` pools.

    Built once per stage run (loading the weights takes a moment); `maps` is deterministic.
    """

    def __init__(self, name: str = "efficientnet-lite0"):
        self.name = name
        self.model = load_backbone(name).eval()
        self.taps = tuple(self.model.stage_ends[i] for i in STAGES)

    def maps(self, srgb: np.ndarray) -> list[np.ndarray]:
        """(C, h, w) float32 feature maps at each tap of an (H, W, 3) sRGB image in 0..1."""
        x = torch.from_numpy(np.ascontiguousarray(srgb[..., :3], np.float32)).permute(2, 0, 1)[None]
        with torch.inference_mode():
            if UPSCALE != 1.0:
                x = F.interpolate(x, scale_factor=UPSCALE, mode="bilinear", align_corners=False)
            return [t[0].numpy() for t in self.model.forward_taps(x, self.taps)]
