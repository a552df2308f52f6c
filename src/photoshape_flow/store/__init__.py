"""Content-addressed blob store for every file the pipeline writes.

A blob is named by the sha256 of its bytes plus an extension (``<sha256>.<ext>``); that name is the
*ref* stored in database rows. The store is a local folder (`store.local`) or an fsspec URL shared
by several machines (`store.remote`, read through a local cache); `BlobStore` (`store.blobstore`)
puts and reads blobs the same way over both, and `store.codecs` turns arrays, images and JSON into
bytes. Writes are atomic and idempotent: a ref that exists is always complete.
"""

from photoshape_flow.store.blobstore import BlobStore
from photoshape_flow.store.factory import default_store
from photoshape_flow.store.refs import REF_PATTERN, is_ref, is_url, sha256_bytes, sha256_file
from photoshape_flow.store.stored import BlobCorruptError, BlobNotFoundError, GcReport

__all__ = [
    "REF_PATTERN",
    "BlobCorruptError",
    "BlobNotFoundError",
    "BlobStore",
    "GcReport",
    "default_store",
    "is_ref",
    "is_url",
    "sha256_bytes",
    "sha256_file",
]
