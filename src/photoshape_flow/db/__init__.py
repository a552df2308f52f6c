"""Metadata database: ORM models, sessions, idempotent upserts, views, migrations, work claims."""

from photoshape_flow.db import models
from photoshape_flow.db.session import get_engine, session_scope

__all__ = ["get_engine", "models", "session_scope"]
