"""`photoshape_flow.sidecar`: depth is measured outside strings and comments, limits give one-line errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from photoshape_flow.sidecar import DocumentError, nesting_depth, parse_document, parse_text


def test_brackets_inside_strings_and_comments_do_not_count() -> None:
    assert nesting_depth('{"a": "' + "[" * 100 + '", "b": [1, {"c": "\\"]]"}]}') == 3
    toml = "# [[[[[[[[\n[table]\nx = '[[[[[['\ny = \"\"\"\n{{{{{{\n\"\"\"\nz = [[1], [2]]\n"
    assert nesting_depth(toml, toml=True) == 2
    assert parse_text(toml, "toml")["table"]["z"] == [[1], [2]]


def test_limits_and_malformed_documents_raise_document_errors(tmp_path: Path) -> None:
    with pytest.raises(DocumentError, match="nested 33 levels deep"):
        parse_text("[" * 33 + "]" * 33, "json")
    assert parse_text("[" * 32 + "]" * 32, "json") == [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]
    big = tmp_path / "material.json"
    big.write_text('{"a": "' + "x" * 100 + '"}')
    with pytest.raises(DocumentError, match="bytes \\(limit 50\\)"):
        parse_document(big, max_bytes=50)
    with pytest.raises(DocumentError, match="invalid TOML"):
        parse_text("a = [1,", "toml")
