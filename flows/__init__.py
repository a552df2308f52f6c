"""Prefect flows and deployments (one flow per canonical stage)."""
