"""Method keys: which method, and which material classifier, an assignment row belongs to.

`assignment.method_key` (and `grade.method_key`, metric rows, export folders, render keys) is either a
plain method name (``color-match``, ``no-classifier``, ``builtin``) or a method with the classifier
its rows come from, ``<method>:<classifier id>``: ``classifier:3`` (ours, ranked by classifier 3),
``fit:3`` (the fit stage's re-ranking of classifier 3's rows). `MethodKey` is the one place that
writes and reads that text: build with `MethodKey.for_classifier` / `MethodKey.fit_of` (or the
constructor) and ``str()``, read with `MethodKey.parse`. `method_of` and `classifier_id_of` read any
text without raising, for code that shows or sorts whatever a table holds.

Plain text in, plain text out: no database, no torch.
"""

from __future__ import annotations

from dataclasses import dataclass

SEPARATOR = ":"
CLASSIFIER = "classifier"  # ours: `assignment.method` of the classifier's ranking (vocab.ASSIGNMENT_METHODS[0])
FIT = "fit"  # the fit stage's rows (`fitting.fit`)


def _split(text: str) -> tuple[str, str | None]:
    """(method, classifier part or None when there is no separator)."""
    method, separator, suffix = text.partition(SEPARATOR)
    return method, suffix if separator else None


def _number(suffix: str | None) -> int | None:
    return int(suffix) if suffix and suffix.isascii() and suffix.isdigit() else None


@dataclass(frozen=True)
class MethodKey:
    """A method name with, for methods that rank with a classifier, that classifier's id."""

    method: str
    classifier_id: int | None = None

    def __post_init__(self) -> None:
        if not self.method or SEPARATOR in self.method:
            raise ValueError(f"not a method name: {self.method!r}")
        if self.classifier_id is not None and (
                isinstance(self.classifier_id, bool) or not isinstance(self.classifier_id, int)
                or self.classifier_id < 0):
            raise ValueError(f"not a classifier id: {self.classifier_id!r}")

    @classmethod
    def parse(cls, text: str) -> MethodKey:
        """The key a stored text names; ValueError for anything `str()` of a key would not write."""
        method, suffix = _split(text)
        number = _number(suffix)
        if suffix is not None and (number is None or str(number) != suffix):
            raise ValueError(f"not a method key: {text!r} (expected 'method' or 'method{SEPARATOR}<classifier id>', "
                             f"e.g. 'color-match' or '{CLASSIFIER}{SEPARATOR}3')")
        try:
            return cls(method, number)
        except ValueError as exc:
            raise ValueError(f"not a method key: {text!r} ({exc})") from None

    @classmethod
    def for_classifier(cls, classifier_id: int) -> MethodKey:
        """Ours, ranked by material classifier `classifier_id` (``classifier:<id>``)."""
        return cls(CLASSIFIER, int(classifier_id))

    @classmethod
    def fit_of(cls, classifier_id: int) -> MethodKey:
        """The fit stage's rows re-ranking classifier `classifier_id`'s (``fit:<id>``)."""
        return cls(FIT, int(classifier_id))

    def __str__(self) -> str:
        return self.method if self.classifier_id is None else f"{self.method}{SEPARATOR}{self.classifier_id}"


def method_of(text: str) -> str:
    """The method name of a method key or name (``fit:3`` -> ``fit``, ``color-match`` as it is); never raises."""
    return _split(text)[0]


def classifier_id_of(text: str) -> int | None:
    """The classifier id of a method key (``classifier:3`` -> 3); None for a plain name or a malformed suffix."""
    return _number(_split(text)[1])


def is_method_name(text: str) -> bool:
    """True for a plain method name (``classifier``, ``fit``), False for an exact key naming a classifier."""
    return _split(text)[1] is None
