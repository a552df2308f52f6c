"""Security: a local Dask cluster's dashboard binds 127.0.0.1 unless configured otherwise."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from photoshape_flow.config import get_settings


@pytest.fixture
def dask_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[pytest.MonkeyPatch]:
    for name in ("PHOTOSHAPE_DASK_ADDRESS", "PHOTOSHAPE_DASK_DASHBOARD_ADDRESS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("PHOTOSHAPE_DASK_WORKERS", "2")
    get_settings.cache_clear()
    yield monkeypatch
    get_settings.cache_clear()


def _cluster_kwargs() -> dict:
    from photoshape_flow.flows.tasks import task_runner

    get_settings.cache_clear()
    return task_runner().cluster_kwargs


def test_local_cluster_dashboard_binds_localhost(dask_env: pytest.MonkeyPatch) -> None:
    from distributed import LocalCluster

    kwargs = _cluster_kwargs()
    # what the runner would start, without its worker processes: the HTTP server listens on 127.0.0.1 only
    with LocalCluster(**{**kwargs, "n_workers": 0}) as cluster:
        assert cluster.scheduler.http_server.address == "127.0.0.1"
        assert cluster.scheduler.address.startswith("tcp://127.0.0.1:")
    assert kwargs.get("dashboard_address") == "127.0.0.1:8787"


def test_dashboard_address_is_configurable_or_off(dask_env: pytest.MonkeyPatch) -> None:
    dask_env.setenv("PHOTOSHAPE_DASK_DASHBOARD_ADDRESS", "0.0.0.0:9797")
    assert _cluster_kwargs().get("dashboard_address") == "0.0.0.0:9797"
    for off in ("", "off", "none"):
        dask_env.setenv("PHOTOSHAPE_DASK_DASHBOARD_ADDRESS", off)
        assert "dashboard_address" in _cluster_kwargs() and _cluster_kwargs()["dashboard_address"] is None
