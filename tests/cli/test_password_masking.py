"""Security: the database password never appears in what is printed or logged (photoshape_flow.masking)."""

from __future__ import annotations

import logging
import socket
from pathlib import Path

import pytest
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.config import get_settings
from photoshape_flow.masking import PasswordMaskFilter, install_password_masking, mask_password

SECRET = "s3cret-Pa55"
runner = CliRunner()


def _use_url(monkeypatch: pytest.MonkeyPatch, url: str) -> None:
    from photoshape_flow.db.session import get_engine

    monkeypatch.setenv("PHOTOSHAPE_DATABASE_URL", url)
    get_settings.cache_clear()
    get_engine.cache_clear()


def _flat(text: str) -> str:
    """Output without whitespace: rich wraps long lines, possibly inside a URL."""
    return "".join(text.split())


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_mask_password_keeps_user_host_and_database() -> None:
    assert mask_password(f"postgresql+psycopg://ps:{SECRET}@db:5432/photo") == "postgresql+psycopg://ps:***@db:5432/photo"
    assert mask_password(f"a postgres://u:{SECRET}@h/d and redis://:{SECRET}@r:6379/0.") == \
        "a postgres://u:***@h/d and redis://:***@r:6379/0."
    assert mask_password(f"host=db user=ps password={SECRET} dbname=x") == "host=db user=ps password=*** dbname=x"
    assert mask_password(f"PASSWORD = '{SECRET} 2'") == "PASSWORD = ***"
    for plain in ("postgresql+psycopg://ps@db:5432/photo", "sqlite:////tmp/a:b/photoshape.db", "http://h:8080/x"):
        assert mask_password(plain) == plain


def test_connection_errors_mask_the_password(settings_env: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _use_url(monkeypatch, f"postgresql+psycopg://ps_user:{SECRET}@127.0.0.1:{_closed_port()}/photoshape")
    for verb in (["status"], ["db", "current"], ["demo", "--size", "tiny"]):
        result = runner.invoke(app, verb)
        assert result.exit_code != 0, verb
        assert SECRET not in _flat(result.output) and SECRET not in str(result.exception), verb
    result = runner.invoke(app, ["status"])
    assert "ps_user:***@127.0.0.1" in _flat(result.output) and "cannotconnect" in _flat(result.output)


def test_logged_urls_are_masked_for_every_logger_and_handler() -> None:
    """The filter runs at record creation, so handlers added later (Prefect's API handler) get masked records."""
    assert getattr(logging.getLogRecordFactory(), "masks_passwords", False)  # installed by importing photoshape_flow
    seen: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(self.format(record))

    logger = logging.getLogger("prefect.flow_runs.test_masking")
    handler = Collect()
    logger.addHandler(handler)
    try:
        url = f"postgresql+psycopg://ps:{SECRET}@db/photo"
        logger.warning("connecting to %s", url)
        logger.warning(f"engine {url}")
        try:
            raise ConnectionError(f"cannot reach {url}")
        except ConnectionError:
            logger.exception("failed")
    finally:
        logger.removeHandler(handler)
    assert len(seen) == 3 and "ps:***@db/photo" in seen[0] and "ps:***@db/photo" in seen[1]
    assert "ConnectionError: cannot reach postgresql+psycopg://ps:***@db/photo" in seen[2]
    assert not any(SECRET in line for line in seen)


def test_handlers_mask_records_that_never_passed_the_record_factory() -> None:
    """Prefect's API log handler (what reaches the Prefect UI) and any handler configured before the install
    carry the filter, so a record rebuilt from a dict (a queue or socket listener, a Dask worker's
    forwarded log line) is masked too."""
    import photoshape_flow.flows.tasks  # noqa: F401  (imports prefect, which configures its handlers)
    from prefect.logging.handlers import APILogHandler

    api = [h for h in logging.getLogger("prefect.flow_runs").handlers if isinstance(h, APILogHandler)]
    assert api and all(any(isinstance(f, PasswordMaskFilter) for f in h.filters) for h in api)
    seen: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(self.format(record))

    logger = logging.getLogger("photoshape_flow.pipeline.test_masking")
    handler = Collect()
    logger.addHandler(handler)
    try:
        install_password_masking()  # as the CLI and the flow modules do after configuring handlers
        url = f"postgresql+psycopg://ps:{SECRET}@db/photo"
        record = logging.makeLogRecord({"name": logger.name, "msg": "connecting to %s", "args": (url,),
                                        "levelno": logging.WARNING, "levelname": "WARNING"})
        assert SECRET in record.getMessage()  # built outside the factory: not masked yet
        logger.handle(record)
        assert api[0].filter(record) and SECRET not in record.getMessage()
    finally:
        logger.removeHandler(handler)
    assert seen == ["connecting to postgresql+psycopg://ps:***@db/photo"]


@pytest.mark.postgres
def test_status_prints_the_url_without_its_password(pg_url: str, settings_env: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A reachable server (trust auth ignores the password): status, db current and doctor mask it."""
    with_password = pg_url.replace("://postgres@", f"://postgres:{SECRET}@")
    assert with_password != pg_url
    _use_url(monkeypatch, with_password)
    upgrade = runner.invoke(app, ["db", "upgrade"])  # a fresh database: the new-database line, masked
    assert upgrade.exit_code == 0 and "created a new database at postgresql+psycopg://postgres:***@" in upgrade.output
    status = runner.invoke(app, ["status"])
    assert status.exit_code == 0 and "postgres:***@127.0.0.1" in _flat(status.output)
    current = runner.invoke(app, ["db", "current"])
    assert "up to date" in current.output
    doctor = runner.invoke(app, ["doctor"])
    assert "postgres:***@" in _flat(doctor.output)  # inside a table cell, which rich may wrap
    for result in (upgrade, status, current, doctor):
        assert SECRET not in _flat(result.output)


@pytest.mark.parametrize("password", ["p@ss", "p@ss@word", "pa:ss", "pa/ss", "a@b:c/d", "p%40ss%2Fx%3A",
                                      "@q@", ":x:", "/y/", "s3cret-Pa55@db:5432/photo"])
def test_passwords_with_url_delimiters_never_appear(password: str) -> None:
    """Masking parses the URL: the password is everything between the user's ':' and the last '@'."""
    for text in (f"postgresql+psycopg://ps:{password}@db:5432/photo",
                 f"cannot connect to postgresql://ps:{password}@db/photo (timeout); retrying"):
        masked = mask_password(text)
        assert password not in masked and "ps:***@db" in masked, masked
        assert masked.replace("ps:***@", f"ps:{password}@") == text  # nothing else changed


def test_urls_without_a_password_are_left_alone() -> None:
    for plain in ("https://github.com/@someone", "s3://bucket/a@b/c", "file:///tmp/x:y@z", "postgresql://ps@db/photo"):
        assert mask_password(plain) == plain


def test_an_unescaped_at_in_the_password_is_masked_on_the_cli(settings_env: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    secret = "pa@ss:wo/rd"
    _use_url(monkeypatch, f"postgresql+psycopg://ps_user:{secret}@127.0.0.1:{_closed_port()}/photoshape")
    result = runner.invoke(app, ["status"])
    flat = _flat(result.output)
    assert result.exit_code != 0 and "ps_user:***@127.0.0.1" in flat, result.output
    for fragment in ("pa@ss", "ss:wo", "wo/rd"):
        assert fragment not in flat and fragment not in str(result.exception), fragment
