"""Metadata text made safe for exported files and the gallery: one line, no hidden characters.

Names, licences, attributions and source URLs come from sidecars and archives that anyone can
write. In a line-based format (OBJ, MTL, ATTRIBUTION.txt) a newline in an attribution would end
its comment and start a live statement: ``"CC-BY\\nmtllib /etc/passwd"`` must never become an
``mtllib /etc/passwd`` line. So every exporter and the gallery pass metadata through `one_line`
(one place, pure): line breaks become a space, and the other control characters, bidi overrides
(which make a name render as another) and lone surrogates (which fail to encode) are written as
visible ``\\uXXXX`` escapes. `is_web_url` decides which URLs may become links.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Mapping
from typing import Any
from urllib.parse import urlsplit

# every boundary str.splitlines() knows, and tabs: a space each (runs collapse to one)
_BREAKS = re.compile("[\t\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029]+")
# other C0/C1 controls, bidi embeddings/overrides/isolates and marks, lone surrogates: escaped
_HIDDEN = re.compile("[\x00-\x1f\x7f-\x9f\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069\ud800-\udfff]")


def _escape(match: re.Match[str]) -> str:
    return f"\\u{ord(match.group()):04x}"


def one_line(value: object) -> str:
    """`value` as text on one line with no control, bidi or surrogate character (None -> "")."""
    if value is None:
        return ""
    text = _BREAKS.sub(" ", str(value))
    return _HIDDEN.sub(_escape, text)


def hidden_character(value: str) -> str | None:
    """The first line break, control, bidi or surrogate character of `value`, described (None if clean).

    For names that become keys or file names (ingest rejects them rather than store a name that
    renders as another or splits a line); free text is escaped by `one_line` instead.
    """
    match = _BREAKS.search(value) or _HIDDEN.search(value)
    if match is None:
        return None
    char = match.group()[0]
    name = unicodedata.name(char, "control character")
    return f"U+{ord(char):04X} ({name.lower()})"


def one_line_strings(value: Any) -> Any:
    """A copy of a JSON-like value with every string (keys included) passed through `one_line`."""
    if isinstance(value, str):
        return one_line(value)
    if isinstance(value, Mapping):
        return {one_line(k) if isinstance(k, str) else k: one_line_strings(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [one_line_strings(v) for v in value]
    return value


def safe_name(name: str, fallback: str = "material") -> str:
    """`name` reduced to letters, digits, ``-``, ``_`` and ``.``: a file stem or MTL/OBJ identifier."""
    cleaned = "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip("._")
    return cleaned or fallback


def is_web_url(value: object) -> bool:
    """True only for an absolute http(s) URL with a host and no whitespace or control character.

    Anything else (``javascript:``, ``data:``, ``vbscript:``, relative or malformed) is shown as
    text, never as a link: browsers strip tabs and newlines inside a scheme, so those are refused.
    """
    if not isinstance(value, str) or not value or value != value.strip():
        return False
    if _BREAKS.search(value) or _HIDDEN.search(value) or " " in value:
        return False
    try:
        parts = urlsplit(value)
    except ValueError:
        return False
    return parts.scheme.lower() in ("http", "https") and bool(parts.hostname)
