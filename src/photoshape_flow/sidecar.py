"""JSON and TOML documents from anyone's files, parsed within a size and a nesting-depth limit.

Python's json and tomllib parsers recurse once per nesting level: 400 KB of ``[[[[...`` raises
`RecursionError`, which no ``except ValueError`` catches and which ended a whole ingest batch. So
every sidecar (material.json/.toml) and glTF JSON is read through `parse_document`: the size is
checked before reading, the bracket depth is measured by a linear scan before parsing (strings and
comments skipped), and anything over a limit or malformed raises `DocumentError`, a ValueError with
one line that says why; the caller names the file.

Numbers are bounded too: Python refuses to convert integers of more than 4300 digits with a bare
ValueError (``Exceeds the limit (4300 digits)``) that escaped every ``except JSONDecodeError``, and
a 1e400 or NaN reaches a float column as infinity or NaN. So integers are read through a digit
limit, and every parsed number (JSON and TOML alike) must be finite and within `MAX_MAGNITUDE`;
anything else is a DocumentError naming the number.

Text must be storable: a lone surrogate (a JSON ``\\ud800`` or a .properties ``\\uD800`` escape) cannot
be encoded as UTF-8 and a NUL cannot be stored in PostgreSQL text or JSONB, so either would reach the
row's write as a bare UnicodeEncodeError or DataError, outside any item's guard.
`unstorable_character` names such a character, and `check_values` refuses it anywhere in a
sidecar, as it refuses TOML dates and times, which no JSON column can hold.
"""

from __future__ import annotations

import json
import re
import sys
import tomllib
from pathlib import Path
from typing import Any

MAX_BYTES = 1024 * 1024  # a sidecar is a few hundred bytes; a megabyte is already absurd
MAX_DEPTH = 32  # no sidecar or glTF nests deeper than a handful of levels
MAX_DIGITS = 24  # a 64-bit integer has at most 20 digits; longer ones are no sidecar's or glTF's
MAX_MAGNITUDE = 1e30  # beyond it no scale, count, offset or colour of a sidecar or glTF means anything
_UNSTORABLE = re.compile("[\x00\ud800-\udfff]")  # NUL (PostgreSQL refuses it), lone surrogates (no UTF-8)


class DocumentError(ValueError):
    """A document that cannot be parsed safely: too big, too deep, not UTF-8, or malformed."""


def nesting_depth(text: str, toml: bool = False) -> int:
    """The deepest nesting of ``[``/``{`` outside strings (and, for TOML, comments): a linear scan."""
    depth = deepest = 0
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in "\"'" and (toml or c == '"'):
            triple = toml and text.startswith(c * 3, i)
            end_quote = c * 3 if triple else c
            i += len(end_quote)
            while i < n and not text.startswith(end_quote, i):
                if text[i] == "\\" and c == '"':
                    i += 1
                elif text[i] == "\n" and not triple:
                    break  # an unterminated string: the parser reports it
                i += 1
            i += len(end_quote)
            continue
        if toml and c == "#":
            newline = text.find("\n", i)
            i = n if newline < 0 else newline + 1
            continue
        if c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth = max(depth - 1, 0)
        i += 1
    return deepest


def _bounded_int(digits: str) -> int:
    """A JSON integer, refused before conversion when it has more than `MAX_DIGITS` digits."""
    count = len(digits.lstrip("+-"))
    if count > MAX_DIGITS:
        raise DocumentError(f"a number with {count} digits (limit {MAX_DIGITS})")
    return int(digits)


def _no_constant(name: str) -> Any:
    """JSON's non-standard NaN / Infinity / -Infinity, which Python's parser would accept."""
    raise DocumentError(f"non-finite number {name} (not allowed)")


def check_numbers(value: Any, depth: int = 0) -> None:
    """DocumentError when any number inside a parsed document is non-finite or absurdly large.

    Recursion is bounded: documents reach here only after the depth scan.
    """
    if isinstance(value, bool):
        return
    if isinstance(value, int | float):
        if value != value or value in (float("inf"), float("-inf")):
            raise DocumentError(f"non-finite number {value} (not allowed)")
        if abs(value) > MAX_MAGNITUDE:
            shown = f"{value:.3g}" if isinstance(value, float) else f"with {len(str(abs(value)))} digits"
            raise DocumentError(f"a number {shown} beyond the limit {MAX_MAGNITUDE:.0e}")
    elif isinstance(value, dict):
        for item in value.values():
            check_numbers(item, depth + 1)
    elif isinstance(value, list):
        for item in value:
            check_numbers(item, depth + 1)


def unstorable_character(text: str) -> str | None:
    """The first character of `text` that no database column can store, described; None when there is none."""
    match = _UNSTORABLE.search(text)
    if match is None:
        return None
    char = match.group()
    what = "null" if char == "\x00" else "a lone surrogate"
    return f"U+{ord(char):04X} ({what}, which cannot be stored)"


def check_values(value: Any) -> None:
    """DocumentError unless a parsed sidecar holds only storable text, numbers, booleans, lists and tables.

    TOML's dates and times have no JSON form (a `params` table holding one failed at the row's write
    with a TypeError); a NUL or lone surrogate in any string or key fails there too (see the module).
    Recursion is bounded: documents reach here only after the depth scan.
    """
    if isinstance(value, str):
        problem = unstorable_character(value)
        if problem is not None:
            raise DocumentError(f"text {value[:40]!r} contains {problem}")
    elif isinstance(value, dict):
        for key, item in value.items():
            check_values(key)
            check_values(item)
    elif isinstance(value, list):
        for item in value:
            check_values(item)
    elif value is not None and not isinstance(value, bool | int | float):
        raise DocumentError(f"a {type(value).__name__} value {str(value)[:40]!r} (sidecars hold text, numbers, "
                            "booleans, lists and tables)")


def parse_text(text: str, kind: str, max_depth: int = MAX_DEPTH, finite_only: bool = True) -> Any:
    """`text` parsed as ``json`` or ``toml`` within the depth and number limits, or DocumentError.

    `finite_only=False` lets NaN, infinities and large magnitudes through (integer digits stay
    bounded) for formats that judge their numbers field by field, one entry at a time.
    """
    depth = nesting_depth(text, toml=kind == "toml")
    if depth > max_depth:
        raise DocumentError(f"nested {depth} levels deep (limit {max_depth})")
    try:
        if kind == "json":
            data = json.loads(text, parse_int=_bounded_int, **({"parse_constant": _no_constant} if finite_only else {}))
        else:
            data = tomllib.loads(text)
    except DocumentError:
        raise
    except json.JSONDecodeError as exc:
        raise DocumentError(f"invalid JSON at line {exc.lineno} ({exc.msg})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise DocumentError(f"invalid TOML ({exc})") from exc
    except RecursionError as exc:  # the scan is the guard; this is the backstop
        raise DocumentError("nested too deeply to parse") from exc
    except ValueError as exc:  # TOML integers past Python's 4300-digit conversion limit, and the like
        if "digits" in str(exc):
            raise DocumentError(f"a number with more than {sys.get_int_max_str_digits()} digits "
                                f"(limit {MAX_DIGITS})") from exc
        raise DocumentError(f"a number that cannot be read ({str(exc).splitlines()[0][:120]})") from exc
    if finite_only:
        check_numbers(data)
    return data


def parse_document(path: Path, max_bytes: int = MAX_BYTES, max_depth: int = MAX_DEPTH) -> Any:
    """The JSON (``.json``, ``.gltf``) or TOML (``.toml``) document in `path`, or DocumentError/OSError."""
    size = path.stat().st_size
    if size > max_bytes:
        raise DocumentError(f"{size} bytes (limit {max_bytes})")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DocumentError(f"not UTF-8 text (byte {exc.start})") from exc
    return parse_text(text, "toml" if path.suffix.lower() == ".toml" else "json", max_depth)
