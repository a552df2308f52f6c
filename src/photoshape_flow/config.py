"""Settings from PHOTOSHAPE_* environment variables, a .env file, or defaults.

Nothing else in the package reads the environment for configuration: every path, URL and knob
comes through `Settings`, so a deployment is described by its environment alone.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationInfo, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Runtime configuration of photoshape_flow."""

    model_config = SettingsConfigDict(env_prefix="PHOTOSHAPE_", env_file=".env", extra="ignore")

    data_root: Path = Field(
        default=Path("./photoshape-data"),
        description="Folder holding the blob store, the default SQLite database and generated data.",
    )
    blob_root: Path | str | None = Field(
        default=None,
        validate_default=True,
        description="Where blobs live: a folder, or an fsspec URL shared by workers on several machines "
        "(s3://bucket/blobs, gs://bucket/blobs, file:///mnt/shared/blobs; the protocol's package, e.g. s3fs, "
        "must be installed). Default: data_root/blobs. A URL store is read through data_root/cache/blobs.",
    )
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL of the metadata database; default: SQLite file under data_root. "
        "PostgreSQL: postgresql+psycopg://user@host:5432/db",
    )
    render_variant: str = Field(
        default="llvm_ad_rgb",
        description="Mitsuba variant. The pip wheel has no llvm_rgb; llvm_ad_rgb costs nothing extra "
        "unless gradients are enabled. scalar_rgb works without LLVM but is ~170x slower for AOVs.",
    )
    render_threads: int = Field(
        default=0,
        description="Dr.Jit worker threads; 0 = all cores. Values below 2 are raised to 2 because "
        "Mitsuba deadlocks loading an envmap with a single worker thread.",
    )
    torch_threads: int = Field(default=0, description="torch intra-op threads; 0 = all cores.")
    device: Literal["auto", "cpu", "cuda"] = Field(
        default="auto", description="Device for the networks: cuda when available under auto."
    )
    seed: int = Field(default=0, description="Global seed; every item's seed derives from it and its key.")
    claim_lease_seconds: int = Field(
        default=900, description="How long a worker's claim on a batch lasts before another may take it."
    )
    gc_grace_seconds: int = Field(
        default=3600,
        description="gc keeps unreferenced blobs younger than this (they may belong to a write in flight).",
    )
    dask_address: str | None = Field(
        default=None,
        description="Scheduler address of an existing Dask cluster; flows then fan batches out to its worker "
        "processes (prefect-dask). The workers need PREFECT_API_URL of a real server.",
    )
    dask_workers: int = Field(
        default=0,
        description="Start a local Dask cluster with this many single-threaded worker processes for the flows' "
        "fan-out (0: batches run one after another in the flow's process).",
    )
    dask_dashboard_address: str | None = Field(
        default="127.0.0.1:8787",
        description="host:port of the local Dask cluster's dashboard and HTTP endpoints; empty: no dashboard "
        "(those endpoints stay on the scheduler's own 127.0.0.1). Only this machine can reach it unless "
        "a host is named here (0.0.0.0:8787 for every interface): it shows task arguments and worker logs.",
    )
    ingest_max_faces: int = Field(default=500_000, description="Reject shapes with more triangles than this.")
    ingest_max_file_mb: float = Field(default=100.0, description="Reject source files larger than this (MB).")
    ingest_max_image_megapixels: float = Field(
        default=64.0, description="Reject images larger than this (decompression-bomb guard)."
    )
    prefect_api_url: str | None = Field(
        default=None,
        description="Prefect API URL for events and deployments (falls back to PREFECT_API_URL).",
    )

    @field_validator("database_url")
    @classmethod
    def _normalise_url(cls, value: str | None) -> str | None:
        """Accept the common postgres:// spellings and route them to psycopg 3."""
        if value is None or value == "":
            return None
        for prefix in ("postgres://", "postgresql://"):
            if value.startswith(prefix):
                return "postgresql+psycopg://" + value[len(prefix) :]
        return value

    @field_validator("blob_root")
    @classmethod
    def _blob_root(cls, value: Path | str | None, info: ValidationInfo) -> Path | str:
        """A URL stays a string (fsspec parses it); a folder becomes a Path; unset: data_root/blobs."""
        if value is None or str(value).strip() == "":
            return Path(info.data.get("data_root") or "./photoshape-data") / "blobs"
        text = str(value).strip()
        return text if "://" in text else Path(text)

    @field_validator("dask_dashboard_address")
    @classmethod
    def _no_dashboard(cls, value: str | None) -> str | None:
        """An empty value (or "none"/"off") turns the dashboard off."""
        if value is None or value.strip().lower() in ("", "none", "off", "false"):
            return None
        return value.strip()

    @property
    def resolved_database_url(self) -> str:
        """The database URL in effect: the configured one or SQLite under the data root."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_root / 'photoshape.db').resolve()}"

    @property
    def blob_cache_root(self) -> Path:
        """This machine's read-through cache of a blob store at a URL (unused for a folder)."""
        return self.data_root / "cache" / "blobs"

    @property
    def effective_render_threads(self) -> int:
        wanted = self.render_threads or (os.cpu_count() or 2)
        return max(2, wanted)

    @property
    def effective_prefect_api_url(self) -> str | None:
        return self.prefect_api_url or os.environ.get("PREFECT_API_URL") or None


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings (cached; call `get_settings.cache_clear()` after changing env)."""
    return Settings()
