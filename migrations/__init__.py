"""Alembic migrations of the photoshape_flow metadata schema (one linear history)."""
