"""The Jinja2 environment of the gallery: autoescaped, every shown value on one line.

The gallery shows names, attributions and URLs that anyone who writes a sidecar chooses, so its
pages are rendered from templates (``export/templates/``) with autoescape on, never assembled with
f-strings: a value can only ever be text. `finalize` passes every printed value through
`export.text.one_line` as well, so no control character or bidi override reaches a page either.
Only URLs that `is_web_url` accepts become links (the ``web_url`` test in the templates).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

from jinja2 import Environment, PackageLoader, StrictUndefined
from markupsafe import Markup

from photoshape_flow.export.text import is_web_url, one_line


def _finalize(value: Any) -> Any:
    """Printed values on one line; Markup (a macro's output) stays Markup: one_line adds no HTML."""
    if value is None:
        return ""
    if isinstance(value, Markup):
        return Markup(one_line(str(value)))
    return one_line(value) if isinstance(value, str) else value


def num(value: float | None, digits: int = 3) -> str:
    """A metric with `digits` decimals, "" when missing (sorts last in the table)."""
    return "" if value is None else f"{value:.{digits}f}"


def percent(value: float | None) -> str:
    return "" if value is None else f"{100 * value:.1f}%"


def grade_class(grade: str) -> str:
    """The badge colour of a grade label: good, acceptable, or wrong for the failure labels."""
    if grade in ("good", "acceptable"):
        return grade
    return "wrong" if grade.startswith(("wrong", "under", "over")) else ""


@lru_cache(maxsize=1)
def environment() -> Environment:
    """The gallery's environment (built once; templates are package data)."""
    env = Environment(
        loader=PackageLoader("photoshape_flow.export", "templates"),
        autoescape=True,
        finalize=_finalize,
        undefined=StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters.update(num=num, percent=percent, grade_class=grade_class)
    env.tests["web_url"] = is_web_url
    return env


def render(template: str, **context: Any) -> str:
    """`template` (a file name under export/templates/) rendered with `context`."""
    return environment().get_template(template).render(**context)
