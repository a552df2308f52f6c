"""Database passwords kept out of everything printed or logged: one helper and a logging filter.

`PHOTOSHAPE_DATABASE_URL` may hold a password (``postgresql+psycopg://user:secret@host/db``), and
that URL is printed by `photoshape status`, `db current`, `doctor` and connection errors, and can
reach a log line, which a Prefect worker forwards to the Prefect API for anyone with the UI to read.
`mask_password` replaces the password in every URL (and in every ``password=...`` of a libpq
connection string) within a text, leaving user, host and database readable.
`PasswordMaskFilter` is a `logging.Filter` applying it to log records. `install_password_masking`
puts it in two places: on every handler configured so far (the root's, the CLI's, and Prefect's
console and API log handlers, which forward records to the Prefect UI), where it sees every record a
handler emits, including records rebuilt from dicts (`logging.makeLogRecord`, queue and socket
listeners, logs forwarded from Dask workers) that never passed through this process's record
factory; and in the record factory, so records created here are masked even for handlers added
later. Whoever configures handlers calls it again afterwards (the CLI's `setup_logging`, the flow
modules after Prefect set up its logging on import).
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
    """Mask passwords in every log record this process emits (idempotent; call again after new handlers).

    The filter goes on every handler configured now (a logger's own filter would miss records
    propagated from child loggers; a handler's sees them all) and wraps the record factory, so
    handlers configured later still get masked records from this process.
    """
    mask_handlers()
    previous = logging.getLogRecordFactory()
    if getattr(previous, "masks_passwords", False):
        return

    def factory(*args: Any, **kwargs: Any) -> logging.LogRecord:
        record = previous(*args, **kwargs)
        _FILTER.filter(record)
        return record

    factory.masks_passwords = True  # type: ignore[attr-defined]
    logging.setLogRecordFactory(factory)


def mask_handlers() -> int:
    """Add `PasswordMaskFilter` to the handlers of the root and of every logger that has any; returns how many."""
    loggers = [logging.getLogger(), *(lg for lg in logging.root.manager.loggerDict.values()
                                      if isinstance(lg, logging.Logger))]
    added = 0
    for logger in loggers:
        for handler in logger.handlers:
            if not any(isinstance(f, PasswordMaskFilter) for f in handler.filters):
                handler.addFilter(_FILTER)
                added += 1
    return added
