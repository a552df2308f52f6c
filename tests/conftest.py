"""Shared fixtures: an isolated data root and migrated SQLite database per test, real data location."""

from __future__ import annotations

import os
import pickle
import shutil
import socket
import subprocess
import tempfile
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"

if os.environ.get("PYTEST_XDIST_WORKER"):
    # Two workers share two cores: torch's (and BLAS's) OpenMP pool of one thread per core in each
    # worker oversubscribes them, and its spinning threads slow the other worker's tests (a 1.4 s
    # in-process training took 32 s). Set before any test imports torch; subprocesses inherit it.
    os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, or skip the test when this checkout has none beside it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture
def settings_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Point PHOTOSHAPE_DATA_ROOT at a fresh folder with its own SQLite database."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import get_engine

    data_root = tmp_path / "data"
    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", str(data_root))
    monkeypatch.delenv("PHOTOSHAPE_DATABASE_URL", raising=False)
    monkeypatch.delenv("PHOTOSHAPE_BLOB_ROOT", raising=False)
    get_settings.cache_clear()
    get_engine.cache_clear()
    yield data_root
    get_settings.cache_clear()
    get_engine.cache_clear()


@pytest.fixture
def db_url(settings_env: Path) -> str:
    """A migrated SQLite database under the test's data root; returns its URL."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate

    url = get_settings().resolved_database_url
    migrate.upgrade(url)
    return url


@pytest.fixture
def store(settings_env: Path):  # type: ignore[no-untyped-def]
    from photoshape_flow.config import get_settings
    from photoshape_flow.store import BlobStore

    return BlobStore(get_settings().blob_root)


# --- PostgreSQL --------------------------------------------------------------------------------
# The python-svc machines run a server at 127.0.0.1:5432 (trust auth). Where none answers, a
# throwaway cluster is started for the session. With CI=true a missing database fails the run: the
# PostgreSQL tests never silently skip there.


PG_ADMIN_URL = os.environ.get("PHOTOSHAPE_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres")


def _pg_answers(url: str) -> bool:
    import sqlalchemy as sa

    try:
        engine = sa.create_engine(url, connect_args={"connect_timeout": 3})
        with engine.connect() as conn:
            conn.execute(sa.text("SELECT 1"))
        engine.dispose()
        return True
    except Exception:
        return False


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start_throwaway_cluster() -> tuple[str, list[str], str]:
    """initdb + pg_ctl start on a free port; returns (admin url, stop command, data dir)."""
    bins = sorted(Path("/usr/lib/postgresql").glob("*/bin/initdb"))
    if not bins:
        raise RuntimeError("no PostgreSQL binaries under /usr/lib/postgresql (apt-get install -y postgresql)")
    bindir = bins[-1].parent
    datadir = tempfile.mkdtemp(prefix="photoshape-pg-")
    run_as: list[str] = []
    if os.geteuid() == 0:  # initdb refuses to run as root
        shutil.chown(datadir, "postgres", "postgres")
        run_as = ["runuser", "-u", "postgres", "--"]
    port = _free_port()
    subprocess.run([*run_as, str(bindir / "initdb"), "-D", datadir, "-U", "postgres", "--auth=trust", "-E", "UTF8"],
                   check=True, capture_output=True)
    opts = f"-c listen_addresses=127.0.0.1 -p {port} -k /tmp -c fsync=off -c synchronous_commit=off"
    subprocess.run([*run_as, str(bindir / "pg_ctl"), "-D", datadir, "-l", f"{datadir}/log", "-w", "-o", opts, "start"],
                   check=True, capture_output=True)
    stop = [*run_as, str(bindir / "pg_ctl"), "-D", datadir, "-m", "immediate", "stop"]
    return f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres", stop, datadir


@pytest.fixture(scope="session")
def pg_admin_url() -> Iterator[str]:
    """URL of a PostgreSQL maintenance database we may create databases in."""
    if _pg_answers(PG_ADMIN_URL):
        yield PG_ADMIN_URL
        return
    try:
        url, stop, datadir = _start_throwaway_cluster()
    except Exception as exc:
        message = f"no PostgreSQL at {PG_ADMIN_URL} and no throwaway cluster: {exc}"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message)
        pytest.skip(message)
    try:
        yield url
    finally:
        subprocess.run(stop, capture_output=True)
        shutil.rmtree(datadir, ignore_errors=True)


@pytest.fixture
def pg_url(pg_admin_url: str) -> Iterator[str]:
    """A fresh, empty PostgreSQL database for one test, dropped afterwards."""
    import sqlalchemy as sa

    name = f"photoshape_test_{uuid.uuid4().hex[:12]}"
    admin = sa.create_engine(pg_admin_url, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(sa.text(f'CREATE DATABASE "{name}"'))
    url = pg_admin_url.rsplit("/", 1)[0] + f"/{name}"
    try:
        yield url
    finally:
        from photoshape_flow.db.session import get_engine

        for engine_url in [url]:
            try:
                get_engine(engine_url).dispose()
            except Exception:
                pass
        get_engine.cache_clear()
        with admin.connect() as conn:
            conn.execute(sa.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def any_db_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """An empty database URL on SQLite and on PostgreSQL (the test runs once for each)."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'any.db'}"
    return request.getfixturevalue("pg_url")


# --- demo collections --------------------------------------------------------------------------


def once_per_session(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], Any]) -> Any:
    """`build(folder)` run once per test session, however many pytest-xdist workers share it.

    Workers' temp folders sit in one session folder; the first worker to take the lock builds in
    ``<session>/shared-<name>`` and pickles the result, later ones (waiting on the lock) read it. So
    every worker reads the same files, as one process would, and the reference run (over a minute)
    is not repeated per worker.
    """
    from filelock import FileLock

    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    folder, result = base / f"shared-{name}", base / f"shared-{name}.pickle"
    with FileLock(str(base / f"shared-{name}.lock")):
        if result.exists():
            return pickle.loads(result.read_bytes())
        shutil.rmtree(folder, ignore_errors=True)  # a build that failed in another worker
        folder.mkdir()
        built = build(folder)
        result.write_bytes(pickle.dumps(built))
        return built


@pytest.fixture(scope="session")
def tiny_demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny demo collections (generated once per test session)."""
    from photoshape_flow.demo import generate_demo

    def build(folder: Path) -> Path:
        generate_demo(folder, "tiny", seed=3)
        return folder

    return once_per_session(tmp_path_factory, "tiny-demo", build)


@pytest.fixture(scope="session")
def reference(tiny_demo: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """One uninterrupted `photoshape run all --profile tiny` on SQLite, as a user starts it (its data root
    and `snapshot`): what every resumed or concurrent run reproduces, and the built collection that the
    service tests copy (`copied_collection`) instead of building their own. Read-only: copy it to change it."""
    from tests.pipeline.whole_runs import run_all, snapshot

    def build(folder: Path) -> tuple[Path, dict[str, Any]]:
        root = data_root_with_inbox(folder / "data", tiny_demo)
        done = run_all(root, None)
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
        return root, snapshot(f"sqlite:///{root / 'photoshape.db'}")

    return once_per_session(tmp_path_factory, "reference", build)


def copied_collection(reference_root: Path, data_root: Path) -> Path:
    """A private copy of the reference run's data root (SQLite database, blobs, gallery; the inbox's links
    kept): a built tiny collection a test may change. Run commands on it with `PHOTOSHAPE_SEED=3`, the
    reference's seed (tests/pipeline/whole_runs.run_env), or every seeded hash differs."""
    shutil.copytree(reference_root, data_root, symlinks=True)
    return data_root


def data_root_with_inbox(data_root: Path, demo: Path) -> Path:
    """A data root whose inbox holds the demo collections (what `photoshape run ingest` reads)."""
    inbox = data_root / "inbox"
    inbox.mkdir(parents=True)
    for name in ("envmaps", "materials", "shapes", "exemplars"):
        (inbox / name).symlink_to(demo / name)
    return data_root


def ingest_tiny_demo(demo: Path, exemplar_size: int = 128) -> None:
    """The demo's exemplars, shapes and materials under the source `photoshape demo` gives them
    (demo-tiny), so its ground truth matches; into the database the settings point at."""
    from photoshape_flow.ingest.ingest import ingest_exemplars, ingest_materials, ingest_shapes

    assert ingest_exemplars([demo / "exemplars"], source="demo-tiny", size=exemplar_size).added
    assert ingest_shapes([demo / "shapes"], source="demo-tiny", isolate=False).added
    assert ingest_materials([demo / "materials"], source="demo-tiny", previews=False).added
