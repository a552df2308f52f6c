"""How a stage records an item's failure on its row: one short line, the exception's type first."""

from __future__ import annotations


def error_line(exc: BaseException) -> str:
    """``Type: first line of the message``, at most 500 characters (the `error` column of a failed row)."""
    text = f"{type(exc).__name__}: {exc}".splitlines()
    return text[0][:500] if text else type(exc).__name__
