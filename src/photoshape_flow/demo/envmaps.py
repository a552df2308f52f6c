"""Studio environment maps: soft boxes over a graded backdrop, as equirectangular float32 .hdr.

The paper renders everything under studio-like HDR maps (section 3.3). A studio here is a soft
vertical gradient (bright ceiling, dim floor) plus a key, fill, rim and top soft box, each a smooth
rectangle on the sphere with a colour temperature. The layout is drawn from a seed and rotated about
+y; the whole map is normalised to a fixed mean radiance so renders share one exposure.

Equirectangular layout (Mitsuba's `envmap`): row 0 looks straight up (+y), rows go down to -y;
columns sweep the azimuth once around.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from photoshape_flow.demo.seeding import child_rng
from photoshape_flow.demo.writing import write_bytes

MEAN_RADIANCE = 0.6  # lower than a grey card: keeps white seats under the key light from clipping


@dataclass(frozen=True)
class SoftBox:
    azimuth: float  # radians
    elevation: float  # radians
    width: float  # half-extent, radians
    height: float
    intensity: float
    kelvin: float


@dataclass(frozen=True)
class StudioSpec:
    name: str
    boxes: tuple[SoftBox, ...]
    sky: float  # backdrop radiance at the zenith
    floor: float  # backdrop radiance at the nadir
    kelvin: float  # backdrop colour temperature
    rotation: float  # radians about +y

    def to_json(self) -> dict:
        return asdict(self)


def kelvin_to_rgb(kelvin: float) -> np.ndarray:
    """Linear RGB of a black body at `kelvin` (Tanner Helland's fit), normalised to luminance 1."""
    t = kelvin / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = 99.4708025861 * np.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
    b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * np.log(t - 10) - 305.0447927307)
    srgb = np.clip(np.array([r, g, b]) / 255.0, 0, 1)
    lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    lum = float(lin @ np.array([0.2126, 0.7152, 0.0722]))
    return lin / max(lum, 1e-6)


Range = tuple[float, float]


@dataclass(frozen=True)
class BoxRanges:
    """Where one soft box's size, brightness and colour are drawn from (its azimuth is placed apart)."""

    elevation: Range
    width: Range
    height: Range
    intensity: Range
    kelvin_offset: Range | None  # None: exactly the studio's base temperature


KEY_BOX = BoxRanges((0.25, 0.7), (0.25, 0.45), (0.3, 0.5), (6, 10), (-300, 300))
FILL_BOX = BoxRanges((0.1, 0.4), (0.3, 0.5), (0.3, 0.5), (2, 4), (-600, 600))
RIM_BOX = BoxRanges((0.2, 0.6), (0.1, 0.2), (0.3, 0.6), (3, 8), (-500, 1500))
TOP_BOX = BoxRanges((1.2, 1.45), (0.3, 0.5), (0.3, 0.5), (2, 5), None)


def sample_box(rng: np.random.Generator, azimuth: float, ranges: BoxRanges, base_k: float) -> SoftBox:
    """One soft box drawn from `ranges`, field by field: seeded studios depend on this draw order."""
    return SoftBox(
        azimuth,
        float(rng.uniform(*ranges.elevation)),
        float(rng.uniform(*ranges.width)),
        float(rng.uniform(*ranges.height)),
        float(rng.uniform(*ranges.intensity)),
        base_k if ranges.kelvin_offset is None else base_k + float(rng.uniform(*ranges.kelvin_offset)),
    )


def sample_studio(rng: np.random.Generator, name: str) -> StudioSpec:
    """A random product-photo lighting set-up: key + fill + rim + top, warm to cool.

    Each box's azimuth is drawn just before its other fields (argument order): seeded studios depend on it.
    """
    base_k = float(rng.uniform(3800, 7500))
    key_az = float(rng.uniform(-0.9, 0.9))
    boxes = [
        sample_box(rng, key_az, KEY_BOX, base_k),
        sample_box(rng, key_az + np.sign(-key_az or 1.0) * float(rng.uniform(1.2, 1.9)), FILL_BOX, base_k),
        sample_box(rng, float(np.pi + rng.uniform(-0.6, 0.6)), RIM_BOX, base_k),
        sample_box(rng, float(rng.uniform(-np.pi, np.pi)), TOP_BOX, base_k),
    ]
    return StudioSpec(
        name=name,
        boxes=tuple(boxes),
        sky=float(rng.uniform(0.4, 0.9)),
        floor=float(rng.uniform(0.1, 0.3)),
        kelvin=base_k + float(rng.uniform(-500, 500)),
        rotation=float(rng.uniform(0, 2 * np.pi)),
    )


def directions(width: int) -> np.ndarray:
    """Unit direction of each equirectangular pixel centre, (H, W, 3) with H = width / 2."""
    h = width // 2
    theta = (np.arange(h) + 0.5) / h * np.pi  # from +y down
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], axis=-1)


def render_studio(spec: StudioSpec, width: int = 512) -> np.ndarray:
    """The linear RGB radiance map (H, W, 3) float32 of a studio spec."""
    d = directions(width)
    y = d[..., 1]
    grad = spec.floor + (spec.sky - spec.floor) * (0.5 + 0.5 * np.tanh(2.5 * y))
    img = grad[..., None] * kelvin_to_rgb(spec.kelvin)[None, None]
    for b in spec.boxes:
        az = b.azimuth + spec.rotation
        c = np.array([np.cos(b.elevation) * np.sin(az), np.sin(b.elevation), np.cos(b.elevation) * np.cos(az)])
        right = np.array([np.cos(az), 0.0, -np.sin(az)])
        up = np.cross(c, right)
        facing = d @ c
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(facing > 0, (d @ right) / facing, 1e9)
            yy = np.where(facing > 0, (d @ up) / facing, 1e9)
        wx, wy = np.tan(b.width), np.tan(b.height)
        soft = 0.15
        mask = (0.5 - 0.5 * np.tanh((np.abs(x) - wx) / (soft * wx))) * (
            0.5 - 0.5 * np.tanh((np.abs(yy) - wy) / (soft * wy))
        )
        img += (b.intensity * mask)[..., None] * kelvin_to_rgb(b.kelvin)[None, None]
    # normalise the solid-angle weighted mean radiance
    h = img.shape[0]
    w_row = np.sin((np.arange(h) + 0.5) / h * np.pi)
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    mean = float((lum * w_row[:, None]).sum() / (w_row.sum() * img.shape[1]))
    return (img * (MEAN_RADIANCE / mean)).astype(np.float32)


def encode_hdr(image: np.ndarray) -> bytes:
    """Radiance .hdr bytes of a linear RGB float image (cv2 wants BGR)."""
    ok, buf = cv2.imencode(".hdr", np.ascontiguousarray(image[..., ::-1], dtype=np.float32))
    if not ok:
        raise RuntimeError("HDR encoding failed")
    return buf.tobytes()


def write_studio(path: Path, spec: StudioSpec, width: int = 512) -> Path:
    write_bytes(path, encode_hdr(render_studio(spec, width)))
    return path


def studio_specs(seed: int, count: int, prefix: str) -> list[StudioSpec]:
    """`count` studios named <prefix>_NN, each from its own seeded stream."""
    return [sample_studio(child_rng(seed, "envmap", prefix, k), f"{prefix}_{k:02d}") for k in range(count)]
