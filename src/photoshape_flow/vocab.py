"""The paper's vocabulary as constants shared by every layer.

The five substances of section 4.3, the assignment methods (ours and the baselines) and the
curation grades of the original code's result taxonomy. Stage names come from the stage registry
(`photoshape_flow.stages.STAGE_NAMES`).
"""

from __future__ import annotations

# Index order matters: it is the label order of the substance network (0 = background).
SUBSTANCES: tuple[str, ...] = ("leather", "fabric", "wood", "metal", "plastic")
SUBSTANCE_LABELS: tuple[str, ...] = ("background", *SUBSTANCES)

GRADES: tuple[str, ...] = (
    "good",
    "acceptable",
    "wrong_ambiguous",
    "wrong_alignment",
    "wrong_material",
    "wrong_color",
    "under_segmented",
    "over_segmented",
    "bad_shape",
    "bad_exemplar",
    "limitation",
    "not_sure",
)

# ours first, then the baselines in the order inference runs them and tables list them
ASSIGNMENT_METHODS: tuple[str, ...] = ("classifier", "no-classifier", "color-match", "builtin")

RENDERING_KINDS: tuple[str, ...] = (
    "preview",        # material preview (sphere / cloth patch)
    "part-map",       # coarse part-ID map at a pair's camera
    "bootstrap",      # training render of the bootstrap round (substances drawn without prior)
    "training",       # training render conditioned on part substances
    "photoshape",     # final PhotoShape render
    "builtin",        # shape rendered with its built-in materials
    "exemplar-gt",    # demo: ground-truth render behind a synthetic exemplar
)

STATUS_OK = "ok"
STATUS_FAILED = "failed"
STATUS_REJECTED = "rejected"
STATUS_PENDING = "pending"

