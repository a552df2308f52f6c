"""JSON and TOML documents from anyone's files, parsed within a size and a nesting-depth limit.

Python's json and tomllib parsers recurse once per nesting level: 400 KB of ``[[[[...`` raises
`RecursionError`, which no ``except ValueError`` catches and which ended a whole ingest batch. So
every sidecar (material.json/.toml) and glTF JSON is read through `parse_document`: the size is
checked before reading, the bracket depth is measured by a linear scan before parsing (strings and
comments skipped), and anything over a limit or malformed raises `DocumentError`, a ValueError with
one line that says why; the caller names the file.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

MAX_BYTES = 1024 * 1024  # a sidecar is a few hundred bytes; a megabyte is already absurd
MAX_DEPTH = 32  # no sidecar or glTF nests deeper than a handful of levels


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


def parse_text(text: str, kind: str, max_depth: int = MAX_DEPTH) -> Any:
    """`text` parsed as ``json`` or ``toml`` within the depth limit, or DocumentError."""
    depth = nesting_depth(text, toml=kind == "toml")
    if depth > max_depth:
        raise DocumentError(f"nested {depth} levels deep (limit {max_depth})")
    try:
        return json.loads(text) if kind == "json" else tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise DocumentError(f"invalid JSON at line {exc.lineno} ({exc.msg})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise DocumentError(f"invalid TOML ({exc})") from exc
    except RecursionError as exc:  # the scan is the guard; this is the backstop
        raise DocumentError("nested too deeply to parse") from exc


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
