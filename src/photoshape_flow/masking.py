"""Database passwords kept out of everything printed or logged: one helper and a logging filter.

`PHOTOSHAPE_DATABASE_URL` may hold a password (``postgresql+psycopg://user:secret@host/db``), and
that URL is printed by `photoshape status`, `db current`, `doctor` and connection errors, and can
reach a log line, which a Prefect worker forwards to the Prefect API for anyone with the UI to read.
`mask_password` replaces the password in every URL (and in every ``password=...`` of a libpq
connection string) within a text, leaving user, host and database readable. URLs are parsed, not
matched by a pattern: a URL runs from its ``scheme://`` to the next blank or quote, its user
information ends at its *last* ``@`` and the password starts at the user's first ``:``, so a
password holding ``@``, ``:`` or ``/`` (escaped or not, as libpq and SQLAlchemy accept them)
is masked whole. A URL whose path or query holds an ``@`` may be masked too generously, never
too little.
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
# where a URL starts, and where it ends (blanks and quotes never belong to a URL as printed)
_SCHEME = re.compile(r"\b[A-Za-z][A-Za-z0-9+.\-]*://")
_URL_END = re.compile(r"[\s'\"<>`]")
# libpq key/value form: password=secret or password='se cret'
_KEYWORD_PASSWORD = re.compile(r"(?P<head>\b(?:password|passwd|pwd)\s*=\s*)(?:'(?:[^'\\]|\\.)*'|[^\s'\"]+)",
                               re.IGNORECASE)


def mask_url(rest: str) -> str:
    """What follows a ``scheme://`` with its password masked: ``user:***@host...``, unchanged without one.

    The user information is everything before the last ``@``; the user is what precedes its first
    ``:`` and everything after that colon is the password, whatever it holds.
    """
    at = rest.rfind("@")
    if at < 0:
        return rest
    user, colon, _password = rest[:at].partition(":")
    if not colon or "/" in user:
        return rest
    return f"{user}:{MASK}{rest[at:]}"


def mask_password(text: str) -> str:
    """`text` (a URL, or any message holding URLs or connection strings) with passwords as ``***``."""
    out: list[str] = []
    position = 0
    for match in _SCHEME.finditer(text):
        if match.start() < position:  # a scheme inside a URL already masked (e.g. a redirect parameter)
            continue
        start = match.end()
        end_match = _URL_END.search(text, start)
        end = len(text) if end_match is None else end_match.start()
        out.append(text[position:start])
        out.append(mask_url(text[start:end]))
        position = end
    out.append(text[position:])
    return _KEYWORD_PASSWORD.sub(lambda m: m.group("head") + MASK, "".join(out))


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
