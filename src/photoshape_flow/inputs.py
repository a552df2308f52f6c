"""The files a user hands to ingest: walking folders, naming what cannot be used, and source ids.

Shared by the shape, exemplar and envmap ingest so every collection treats paths alike:

- a folder is walked recursively (sorted, symlinked folders not followed); each entry with a
  supported suffix becomes a `Found` with `root` = the folder argument, and entries that have a
  supported suffix but cannot be used (a directory named ``folder.obj``, a symlink leading out of
  the folder, a name with a control or bidi character) come back with a reason, so nothing the
  user might expect to be ingested disappears silently; files of other types (MTLs, textures,
  notes) are the model's companions and stay quiet;
- a file given by itself has no root (`root` is None);
- a given folder with no usable file at all is named too.

`source_id_for` turns a found file into its natural key: the path relative to the ingested root
without the extension, with ``/`` separators and NFC-normalised, so ``shapes/a/chair.obj`` and
``shapes/b/chair.obj`` are ``a/chair`` and ``b/chair`` (two models called ``chair`` in a
folder-per-model collection no longer collide); a file given by itself keeps its stem.
"""

from __future__ import annotations

import os
import unicodedata
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from photoshape_flow.export.text import hidden_character

MAX_ID_CHARS = 255  # the width of the source_id columns


@dataclass(frozen=True)
class Found:
    """One input: a usable file (`reason` None) or a path that cannot be used and why."""

    path: Path
    root: Path | None = None  # the folder argument it was found under; None for a file given by itself
    reason: str | None = None

    @property
    def source_id(self) -> str:
        return source_id_for(self.path, self.root)

    @property
    def legacy_id(self) -> str:
        """The id this file had before ids were relative paths (its stem): for finding its old row."""
        return unicodedata.normalize("NFC", self.path.stem)


def source_id_for(path: Path, root: Path | None) -> str:
    """The natural key of a file: its path relative to `root` without extension (its stem without a root)."""
    if root is None:
        return unicodedata.normalize("NFC", path.stem)
    try:
        relative = path.relative_to(root)
    except ValueError:
        return unicodedata.normalize("NFC", path.stem)
    return unicodedata.normalize("NFC", relative.with_suffix("").as_posix())


def describe_suffixes(suffixes: Iterable[str]) -> str:
    return " ".join(sorted(suffixes))


def _walk(folder: Path) -> list[Path]:
    """Every entry under `folder` sorted by path (as rglob-and-sort did), symlinked folders not followed."""
    entries: list[Path] = []
    for current, dirs, files in os.walk(folder, followlinks=False):
        base = Path(current)
        entries.extend(base / name for name in [*dirs, *files])
    return sorted(entries)


def link_refusal(path: Path, root: Path | None) -> str | None:
    """Why a symbolic link may not be followed (None for a plain entry or a link that stays inside `root`).

    The one link policy of every collection (shapes, exemplars, envmaps, material maps, sidecars and
    folders): a link must resolve inside the ingested folder, checked from the link alone, before
    anything opens its target; `/etc/passwd` behind an `albedo.png` is never read.
    """
    if not path.is_symlink():
        return None
    if not path.exists():
        return "broken symbolic link"
    if root is not None and not path.resolve().is_relative_to(root.resolve()):
        return f"symbolic link to {path.resolve()}, outside the ingested folder {root}"
    return None


def check_entry(path: Path, root: Path | None) -> str | None:
    """Why a path with a supported suffix cannot be ingested, or None when it is a usable file."""
    hidden = hidden_character(path.name if root is None else path.relative_to(root).as_posix())
    if hidden is not None:
        return f"name contains {hidden}; rename the file"
    link = link_refusal(path, root)
    if link is not None:
        return link
    if path.is_dir():
        return "a folder, not a file (its name ends like a supported file)"
    if not path.is_file():
        return "not a regular file"
    return None


def walk_inputs(paths: Iterable[str | Path], suffixes: set[str]) -> Iterator[Found]:
    """The inputs under the given paths, in a deterministic order (see the module docstring).

    `suffixes`: lower-case suffixes with their dot. Given paths that are missing, files of another
    type and folders without a single usable file come back with a reason.
    """
    wanted = describe_suffixes(suffixes)
    for given in paths:
        path = Path(given)
        if not path.exists() and not path.is_symlink():
            yield Found(path, reason="no such file or folder")
            continue
        if path.is_dir():
            matched = False
            for entry in _walk(path):
                if entry.suffix.lower() not in suffixes:
                    continue
                matched = True
                reason = check_entry(entry, path)
                if reason is None and len(source_id_for(entry, path)) > MAX_ID_CHARS:
                    reason = f"relative path longer than {MAX_ID_CHARS} characters (its source id); ingest a subfolder"
                yield Found(entry, path, reason)
            if not matched:
                yield Found(path, reason=f"no {wanted} files in this folder")
            continue
        if path.suffix.lower() not in suffixes:
            yield Found(path, reason=f"unsupported file type {path.suffix or '(none)'!r} (expected {wanted})")
            continue
        yield Found(path, None, check_entry(path, None))


class ChangedWhileReadingError(ValueError):
    """An input file was rewritten between its hashing and its last read: its row would lie."""


Fingerprints = dict[Path, tuple[int, ...]]


def fingerprint(paths: Iterable[Path]) -> Fingerprints:
    """Device, inode, size and modification/change times of each file, taken before it is hashed.

    The content hash is computed from one read of a file and its data from another (the decoder's,
    the store's copy); a rewrite in between would store a hash that matches neither version. The
    change time moves on every write and rename, so comparing these after the last read
    (`check_unchanged`) proves both reads saw the same file, without reading it a third time.
    """
    out: Fingerprints = {}
    for path in paths:
        stat = os.stat(path)
        out[Path(path)] = (stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns)
    return out


def check_unchanged(before: Fingerprints) -> None:
    """ChangedWhileReadingError naming the first file whose fingerprint moved since `before` was taken."""
    try:
        now = fingerprint(before)
    except OSError as exc:
        raise ChangedWhileReadingError(f"{exc.filename or 'a file'} disappeared while being read") from exc
    for path, seen in before.items():
        if now[path] != seen:
            raise ChangedWhileReadingError(f"{path.name} changed while being read; ingest it again once it is "
                                           "completely written")
