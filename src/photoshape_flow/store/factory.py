"""The one place a `BlobStore` is built from settings (issue 43): stages take theirs from the stage
context (`StageContext.store`), and functions also called directly (CLI verbs, flows, tests) default
to `default_store`; `tests/test_resources.py` holds every other module to that.
"""

from __future__ import annotations

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.store.blobstore import BlobStore


def default_store(settings: Settings | None = None) -> BlobStore:
    """The blob store `settings` configure (default: the process's settings)."""
    return BlobStore((settings or get_settings()).blob_root)
