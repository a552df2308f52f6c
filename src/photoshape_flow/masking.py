"""Database passwords kept out of everything printed or logged: one helper and a logging filter.

`PHOTOSHAPE_DATABASE_URL` may hold a password (``postgresql+psycopg://user:secret@host/db``), and
that URL is printed by `photoshape status`, `db current`, `doctor` and connection errors, and can
reach a log line, which a Prefect worker forwards to the Prefect API for anyone with the UI to read.
`mask_password` replaces the password in every URL (and in every ``password=...`` of a libpq
connection string) within a text, leaving user, host and database readable.
`PasswordMaskFilter` applies it to log records; `install_password_masking` runs that filter on every
record as it is created (the record factory), so it holds for every logger and every handler,
including those Prefect configures and its API log handler, not only the handlers known here.
"""

from __future__ import annotations

import logging
import re
from typing import Any

MASK = "***"
# scheme://user:PASSWORD@host: the password runs to the first "@", as in SQLAlchemy's URL parser
_URL_PASSWORD = re.compile(r"(?P<head>\b[A-Za-z][A-Za-z0-9+.\-]*://[^:/?#@\s]*:)[^@\s]*(?=@)")
# libpq key/value form: password=secret or password='se cret'
_KEYWORD_PASSWORD = re.compile(r"(?P<head>\b(?:password|passwd|pwd)\s*=\s*)(?:'(?:[^'\\]|\\.)*'|[^\s'\"]+)",
                               re.IGNORECASE)


def mask_password(text: str) -> str:
    """`text` (a URL, or any message holding URLs or connection strings) with passwords as ``***``."""
    text = _URL_PASSWORD.sub(lambda m: m.group("head") + MASK, text)
    return _KEYWORD_PASSWORD.sub(lambda m: m.group("head") + MASK, text)


class PasswordMaskFilter(logging.Filter):
    """Masks passwords in a record's message and traceback text; never drops a record."""

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a malformed call: leave it to the handler to report
            return True
        masked = mask_password(message)
        if masked != message:
            record.msg, record.args = masked, None
        if record.exc_info and not record.exc_text:  # formatters reuse exc_text: format it once, masked
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = mask_password(record.exc_text)
        return True


_FILTER = PasswordMaskFilter()


def install_password_masking() -> None:
    """Run `PasswordMaskFilter` on every log record this process creates (idempotent).

    A filter added to a handler would miss handlers configured later (Prefect's dictConfig replaces
    them) and a logger filter misses child loggers, so the filter wraps the record factory instead.
    """
    previous = logging.getLogRecordFactory()
    if getattr(previous, "masks_passwords", False):
        return

    def factory(*args: Any, **kwargs: Any) -> logging.LogRecord:
        record = previous(*args, **kwargs)
        _FILTER.filter(record)
        return record

    factory.masks_passwords = True  # type: ignore[attr-defined]
    logging.setLogRecordFactory(factory)
