"""SVBRDF material folders: recognise maps by name, read the sidecar, convert to the contract's channels.

A folder holds one material: image maps named the way common sources name them (ambientCG
`_Color/_NormalGL/_NormalDX/_Roughness/_Displacement/_Metalness`, Poly Haven `_diff/_nor_gl/_rough/
_arm/_disp`, Poliigon `_COL/_NRM/_GLOSS/_REFL/_DISP`, plain `albedo.png`, `normal_gl.png`, ...) and an
optional sidecar `material.json` / `material.toml` (see docs/contributing.md; an optional `"maps":
{channel: file}` table overrides name recognition). Conversions on ingest: gloss -> roughness
(1 - g), DirectX normals -> OpenGL (green flipped), Poly Haven/glTF packed `arm`/`orm` (R = AO,
G = roughness, B = metallic) unpacked. Single-channel maps keep one channel; bit depth is kept.
Analytic materials are a sidecar with `"kind": "analytic"` and `params`, and no maps.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.export.text import hidden_character
from photoshape_flow.imaging.io import DEFAULT_MAX_BYTES, DEFAULT_MAX_PIXELS, BadImageError, read_map
from photoshape_flow.inputs import link_refusal
from photoshape_flow.sidecar import DocumentError, check_values, parse_document
from photoshape_flow.vocab import SUBSTANCES

CHANNELS: tuple[str, ...] = ("albedo", "roughness", "metallic", "specular", "normal", "height")
SIDECARS: tuple[str, ...] = ("material.json", "material.toml")
SCALE_RANGE = (1e-6, 1e6)  # unit-cube units; beyond it UVs x 1/scale overflow float32 into NaN texture lookups
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".tga", ".bmp", ".webp"}

_KEYWORDS: dict[str, str] = {}
for _kind, _words in {
    "albedo": ("albedo", "basecolor", "basecolour", "diffuse", "diff", "dif", "color", "colour", "col", "alb"),
    "roughness": ("roughness", "rough", "rgh"),
    "gloss": ("gloss", "glossiness", "gls"),
    "specular": ("specular", "spec", "refl", "reflection", "specularity", "specularlevel"),
    "metallic": ("metallic", "metalness", "metal"),
    "normal": ("normal", "normals", "nor", "nrm", "norm", "nrml"),
    "height": ("height", "heightmap", "displacement", "displace", "disp", "displ", "bump", "hgt"),
    "arm": ("arm", "orm"),
    "ao": ("ao", "occlusion", "ambientocclusion"),
    "ignored": ("opacity", "alpha", "mask", "emission", "emissive", "sss", "translucency", "transmission",
                "preview", "thumbnail", "thumb", "sphere", "cavity", "curvature", "idmap", "sheen", "fuzz"),
}.items():
    for _word in _words:
        _KEYWORDS[_word] = _kind
_PAIRS = {("base", "color"): "albedo", ("base", "colour"): "albedo", ("ambient", "occlusion"): "ao"}
_DIGIT_SUFFIXED = {"nrm", "disp", "col", "norm", "rough", "refl", "gloss", "ao", "normal", "bump"}
_GL = {"gl", "ogl", "opengl"}
_DX = {"dx", "directx", "d3d"}


class BadMaterialError(ValueError):
    """A material folder or sidecar that cannot become a material."""


def _tokens(stem: str) -> list[str]:
    spaced = re.sub(r"([a-z0-9])([A-Z])", r"\1_\2", stem)
    spaced = re.sub(r"([A-Z]+)([A-Z][a-z])", r"\1_\2", spaced)
    return [t for t in re.split(r"[^a-z0-9]+", spaced.lower()) if t]


def classify_map(filename: str) -> tuple[str, str | None] | None:
    """(kind, normal convention) of a map file name, or None when no keyword matches.

    Kinds: albedo, roughness, gloss, specular, metallic, normal, height, arm, ao, ignored. The last
    keyword in the name wins (channel suffixes follow the material's own name, which may itself
    contain words such as "metal").
    """
    tokens = _tokens(Path(filename).stem)
    for i in range(len(tokens) - 1, -1, -1):
        token = tokens[i]
        if i > 0 and (tokens[i - 1], token) in _PAIRS:
            return _PAIRS[(tokens[i - 1], token)], None
        if token in _GL | _DX and i > 0:
            prev = tokens[i - 1]
            if _KEYWORDS.get(prev) == "normal" or _KEYWORDS.get(re.sub(r"\d+$", "", prev)) == "normal":
                return "normal", "gl" if token in _GL else "dx"
        kind = _KEYWORDS.get(token)
        if kind is None:
            stripped = re.sub(r"\d+$", "", token)
            if stripped in _DIGIT_SUFFIXED:
                kind = _KEYWORDS.get(stripped)
        if kind is not None:
            convention = None
            if kind == "normal" and i + 1 < len(tokens):
                nxt = tokens[i + 1]
                convention = "gl" if nxt in _GL else "dx" if nxt in _DX else None
            return kind, convention
    return None


def read_sidecar(folder: Path) -> tuple[dict[str, Any] | None, Path | None]:
    """The parsed sidecar of a folder (JSON preferred over TOML), or (None, None).

    Parsed within size and depth limits (`photoshape_flow.sidecar`): a hostile sidecar is one
    BadMaterialError naming the file, never a RecursionError that would end the batch; and it may
    hold only storable values (`check_values`), so nothing it says fails later at the row's write.
    """
    for name in SIDECARS:
        path = folder / name
        link = link_refusal(path, folder)
        if link is not None:
            raise BadMaterialError(f"{name}: {link}")
        if not path.is_file():
            continue
        try:
            data = parse_document(path)
            check_values(data)
        except OSError as exc:
            raise BadMaterialError(f"{name}: unreadable ({exc.strerror or exc})") from exc
        except DocumentError as exc:
            raise BadMaterialError(f"{name}: {exc}") from exc
        if not isinstance(data, dict):
            raise BadMaterialError(f"{name}: expected an object at the top level")
        return data, path
    return None, None


def _number(value: Any, what: str) -> float:
    """A sidecar number: JSON/TOML numbers only, since float() would also take true, "1e300" or "1_0"."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BadMaterialError(f"{what} must be a number, got {value!r}")
    return float(value)


def _unit(value: Any, what: str) -> float:
    number = _number(value, what)
    if not math.isfinite(number) or not 0.0 <= number <= 1.0:
        raise BadMaterialError(f"{what} must be within 0..1, got {value!r}")
    return number


def validate_params(params: Any, what: str = "params") -> dict[str, Any]:
    """Analytic/constant parameters: albedo [r, g, b] and roughness/metallic/specular in 0..1."""
    if params is None:
        return {}
    if not isinstance(params, dict):
        raise BadMaterialError(f"{what} must be a table of values")
    out: dict[str, Any] = {}
    for key, value in params.items():
        if key == "albedo":
            if not isinstance(value, list | tuple) or len(value) != 3:
                raise BadMaterialError(f"{what}.albedo must be [r, g, b], got {value!r}")
            out["albedo"] = [_unit(v, f"{what}.albedo") for v in value]
        elif key in ("roughness", "metallic", "specular"):
            out[key] = _unit(value, f"{what}.{key}")
        else:
            out[key] = value
    return out


@dataclass
class MaterialScan:
    """What a folder holds, before any pixel is decoded (cheap: used to hash and skip)."""

    folder: Path
    name: str
    substance: str
    kind: str  # svbrdf | analytic
    scale: float
    normal_convention: str  # gl | dx, for normal maps named without a convention
    files: dict[str, Path]  # kind (albedo, roughness, gloss, ..., arm) -> file
    conventions: dict[str, str | None]
    sidecar: Path | None
    params: dict[str, Any]
    provenance: dict[str, Any]
    warnings: list[str] = field(default_factory=list)

    def hashed_files(self) -> list[Path]:
        files = sorted(set(self.files.values()))
        return ([self.sidecar] if self.sidecar else []) + files


def _preference(path: Path) -> tuple[int, str]:
    """Lossless and higher-depth formats first, then name order."""
    order = {".png": 0, ".tif": 0, ".tiff": 0, ".tga": 1, ".bmp": 1, ".webp": 2, ".jpg": 3, ".jpeg": 3}
    return order.get(path.suffix.lower(), 9), path.name


def is_material_folder(folder: Path) -> bool:
    """A folder with a sidecar or at least one recognised map image."""
    if any((folder / name).is_file() for name in SIDECARS):
        return True
    try:
        entries = list(folder.iterdir())
    except OSError:
        return False
    for entry in entries:
        if entry.is_file() and entry.suffix.lower() in IMAGE_SUFFIXES:
            kind = classify_map(entry.name)
            if kind is not None and kind[0] not in ("ignored",):
                return True
    return False


def _text_field(sidecar: dict[str, Any], key: str, max_chars: int) -> str | None:
    """A sidecar's text value (None when absent), or BadMaterialError when it is not short text.

    Free text may hold any character (exports and the gallery escape it); it must be a string,
    since a list or table would reach a text column or a file name.
    """
    value = sidecar.get(key)
    if value is None or value == "":
        return None
    if not isinstance(value, str):
        raise BadMaterialError(f"{key} must be text, got {type(value).__name__}")
    if len(value) > max_chars:
        raise BadMaterialError(f"{key} is {len(value)} characters long (limit {max_chars})")
    return value.strip()


def scan_material(folder: Path, *, substance: str | None = None, source: str | None = None,
                  license: str | None = None, attribution: str | None = None) -> MaterialScan:
    """Classify a folder's files and read its sidecar; BadMaterialError if it cannot be a material.

    Substance: the sidecar's, else `substance`, else the folder-name prefix `<substance>_<name>`.
    """
    folder = Path(folder)
    sidecar, sidecar_path = read_sidecar(folder)
    sidecar = sidecar or {}
    warnings: list[str] = []
    name = _text_field(sidecar, "name", 255) or folder.name.strip()
    if not name:
        raise BadMaterialError("empty material name")
    hidden = hidden_character(name)
    if hidden is not None:
        raise BadMaterialError(f"material name contains {hidden}")
    chosen = sidecar.get("substance") or substance
    if not chosen:
        prefix = folder.name.split("_", 1)[0].lower()
        chosen = prefix if prefix in SUBSTANCES else None
    if not chosen:
        raise BadMaterialError(
            "no substance: set \"substance\" in material.json, pass --substance, or name the folder "
            f"<substance>_<name> ({', '.join(SUBSTANCES)})"
        )
    chosen = str(chosen).lower()
    if chosen not in SUBSTANCES:
        raise BadMaterialError(f"unknown substance {chosen!r} (expected one of {', '.join(SUBSTANCES)})")
    kind = str(sidecar.get("kind", "svbrdf")).lower()
    if kind not in ("svbrdf", "analytic"):
        raise BadMaterialError(f"unknown kind {kind!r} (svbrdf or analytic)")
    scale = _number(sidecar.get("scale", 0.25), "scale")
    if not math.isfinite(scale) or scale <= 0:
        raise BadMaterialError(f"scale must be a positive number, got {sidecar.get('scale')!r}")
    if not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        raise BadMaterialError(f"scale must be within {SCALE_RANGE[0]:g}..{SCALE_RANGE[1]:g}, got {scale:g}")
    convention = str(sidecar.get("normal", "gl")).lower()
    if convention not in ("gl", "dx"):
        raise BadMaterialError(f"normal must be \"gl\" or \"dx\", got {sidecar.get('normal')!r}")
    params = validate_params(sidecar.get("params"))
    provenance = {
        "source": _text_field(sidecar, "source", 64) or source,
        "license": _text_field(sidecar, "license", 2000) or license,
        "attribution": _text_field(sidecar, "attribution", 2000) or attribution,
        "source_url": _text_field(sidecar, "source_url", 2000),
    }
    files: dict[str, Path] = {}
    conventions: dict[str, str | None] = {}
    if kind == "analytic":
        if "albedo" not in params:
            raise BadMaterialError("analytic material needs params.albedo")
        return MaterialScan(folder, name, chosen, kind, scale, convention, files, conventions, sidecar_path,
                            params, provenance, warnings)
    explicit = sidecar.get("maps") or {}
    if not isinstance(explicit, dict):
        raise BadMaterialError("maps must be a table of channel -> file name")
    for channel, filename in explicit.items():
        if channel not in (*CHANNELS, "gloss", "arm"):
            raise BadMaterialError(f"maps: unknown channel {channel!r}")
        hidden = hidden_character(str(filename))
        if hidden is not None:  # a NUL would reach os calls as a ValueError; a newline would split the reason
            raise BadMaterialError(f"maps.{channel}: file name contains {hidden}")
        link = link_refusal(folder / str(filename), folder)
        if link is not None:
            raise BadMaterialError(f"maps.{channel}: {link}")
        target = (folder / str(filename)).resolve()
        if not target.is_relative_to(folder.resolve()) or not target.is_file():
            raise BadMaterialError(f"maps.{channel}: file {filename!r} not found in the folder")
        files[channel] = target
        conventions[channel] = None
    candidates: dict[str, list[tuple[Path, str | None]]] = {}
    taken = set(files.values())
    for entry in sorted(folder.iterdir()):
        if entry.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        link = link_refusal(entry, folder)
        if link is not None:
            raise BadMaterialError(f"{entry.name}: {link}")
        if not entry.is_file() or entry.resolve() in taken:
            continue
        found = classify_map(entry.name)
        if found is None:
            warnings.append(f"{entry.name}: unrecognised map name; ignored")
            continue
        map_kind, conv = found
        if map_kind in ("ignored", "ao"):
            continue
        candidates.setdefault(map_kind, []).append((entry, conv))
    for map_kind, entries in candidates.items():
        if map_kind in files:
            continue
        if map_kind == "normal":
            entries.sort(key=lambda e: ({"gl": 0, None: 1, "dx": 2}[e[1]], _preference(e[0])))
        else:
            entries.sort(key=lambda e: _preference(e[0]))
        files[map_kind], conventions[map_kind] = entries[0]
        for other, _ in entries[1:]:
            warnings.append(f"{other.name}: second {map_kind} map; {entries[0][0].name} is used")
    if "roughness" in files and "gloss" in files:
        warnings.append(f"{files.pop('gloss').name}: gloss map ignored (a roughness map is present)")
    if "albedo" not in files:
        raise BadMaterialError("no albedo map (expected a file named like albedo/basecolor/diffuse/color)")
    return MaterialScan(folder, name, chosen, kind, scale, convention, files, conventions, sidecar_path,
                        params, provenance, warnings)


def _one_channel(array: np.ndarray) -> np.ndarray:
    return array if array.ndim == 2 else np.ascontiguousarray(array[..., 0])


def _max_value(array: np.ndarray) -> int:
    return 65535 if array.dtype == np.uint16 else 255


def load_maps(
    scan: MaterialScan, *, max_pixels: int = DEFAULT_MAX_PIXELS, max_bytes: int = DEFAULT_MAX_BYTES
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Decode and convert a scan's maps into the contract's channels; returns (maps, meta)."""
    maps: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {"files": {k: p.name for k, p in scan.files.items()}}

    def read(kind: str) -> np.ndarray:
        path = scan.files[kind]
        try:
            array = read_map(path, max_pixels=max_pixels, max_bytes=max_bytes)
        except BadImageError as exc:
            raise BadMaterialError(f"{path.name}: {exc}") from exc
        if array.dtype not in (np.uint8, np.uint16):
            raise BadMaterialError(f"{path.name}: unsupported pixel type {array.dtype}")
        return array

    albedo = read("albedo")
    maps["albedo"] = np.stack([albedo] * 3, axis=-1) if albedo.ndim == 2 else albedo
    if "roughness" in scan.files:
        maps["roughness"] = _one_channel(read("roughness"))
    elif "gloss" in scan.files:
        gloss = _one_channel(read("gloss"))
        maps["roughness"] = (_max_value(gloss) - gloss.astype(np.int64)).astype(gloss.dtype)
        meta["roughness_from"] = "gloss"
    for channel in ("metallic", "specular", "height"):
        if channel in scan.files:
            maps[channel] = _one_channel(read(channel))
    if "arm" in scan.files and ("roughness" not in maps or "metallic" not in maps):
        arm = read("arm")
        if arm.ndim == 3:
            maps.setdefault("roughness", np.ascontiguousarray(arm[..., 1]))
            maps.setdefault("metallic", np.ascontiguousarray(arm[..., 2]))
            meta["unpacked"] = "arm"
        else:
            scan.warnings.append(f"{scan.files['arm'].name}: packed ARM map is not RGB; ignored")
    if "normal" in scan.files:
        normal = read("normal")
        if normal.ndim != 3:
            raise BadMaterialError(f"{scan.files['normal'].name}: normal map must be RGB")
        convention = scan.conventions.get("normal") or scan.normal_convention
        if convention == "dx":
            normal = normal.copy()
            normal[..., 1] = _max_value(normal) - normal[..., 1]
            meta["normal_converted_from"] = "dx"
        maps["normal"] = normal
    meta["sizes"] = {k: [int(v.shape[1]), int(v.shape[0])] for k, v in maps.items()}
    return maps, meta
