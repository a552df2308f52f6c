"""The paper's vocabulary as constants shared by every layer.

One canonical list of stage names (CLI `run`/`status`, flows and deployments use these), the five
substances of section 4.3, and the curation grades of the original code's result taxonomy.
"""

from __future__ import annotations

STAGES: tuple[str, ...] = (
    "ingest",
    "coarse-alignment",
    "fine-alignment",
    "substances",
    "training-renders",
    "training",
    "inference",
    "publish",
)

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

ASSIGNMENT_METHODS: tuple[str, ...] = ("classifier", "builtin", "no-classifier", "color-match")

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
