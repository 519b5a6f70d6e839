"""Backgrounds for the synthetic dataset, drawn from disjoint pools for training and held-out instances.

Why pools: a SIFT matcher matches straight through a shared background (hundreds of false inliers), so
an image of a held-out instance must never show a background that a training image showed. Every
background source therefore belongs to exactly one of two pools:

* ``"train"`` -- backgrounds of the instances in the ``train`` split (the detectors' training images);
* ``"heldout"`` -- backgrounds of the ``fit`` and ``test`` instances.

The sources are photographs bundled with scikit-image (no download: only the images shipped inside the
wheel are used; the split of the photos between the pools is the fixed table `PHOTO_POOLS`) and
procedural scenes -- rooms, bookshelves, pin boards, cloudy textures and wallpapers -- drawn from the
dataset seed and the pool's name, so the two pools never share one. Each image then shows a random crop
of a source, possibly mirrored, colour-shifted and slightly defocused (the camera focuses on the object),
so a pool of a few dozen sources yields thousands of distinct backgrounds.
"""

from __future__ import annotations

import zlib
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np

from scrppl.datasets.synthetic.floors import periodic_noise

__all__ = [
    "POOLS",
    "PHOTO_POOLS",
    "PROCEDURAL_KINDS",
    "BackgroundChoice",
    "pool_of_split",
    "pool_sources",
    "source_image",
    "draw_background",
    "render_background",
]

#: The two background pools.
POOLS = ("train", "heldout")

#: scikit-image sample photographs (all bundled with the wheel) and the pool each belongs to.
PHOTO_POOLS: dict[str, tuple[str, ...]] = {
    "train": (
        "astronaut",
        "coffee",
        "hubble_deep_field",
        "retina",
        "camera",
        "brick",
        "gravel",
        "coins",
        "text",
    ),
    "heldout": (
        "chelsea",
        "rocket",
        "immunohistochemistry",
        "colorwheel",
        "grass",
        "moon",
        "page",
        "clock",
        "cell",
    ),
}

#: Kinds of procedural background scene.
PROCEDURAL_KINDS = ("room", "shelves", "pinboard", "clouds", "wallpaper")

#: Procedural scenes per kind in each pool.
N_PROCEDURAL = 8

_BG_SIZE = (360, 480)  # (H, W) of procedural sources


class BackgroundChoice(NamedTuple):
    """How one image's background is made from a source (see :func:`render_background`).

    Attributes
    ----------
    source : str
        Source key (``"photo:<name>"`` or ``"<kind>:<pool>:<k>"``).
    crop : tuple of 4 floats
        ``(size, aspect, cx, cy)``: the crop's width as a share of the widest crop of aspect ratio
        ``aspect`` (width / height) that fits the source, and its position as fractions of the free
        margin left and above it.
    flip : bool
        Mirror left-right.
    gain : tuple of 3 floats
        Per-channel RGB gain (colour shift and brightness).
    tint : tuple of 3 floats
        RGB colour given to grey-level sources.
    defocus : float
        Gaussian blur sigma in output pixels.
    """

    source: str
    crop: tuple[float, float, float, float]
    flip: bool
    gain: tuple[float, float, float]
    tint: tuple[float, float, float]
    defocus: float


def pool_of_split(split: str) -> str:
    """The background pool of an instance split: ``train`` -> ``"train"``, ``fit``/``test`` -> ``"heldout"``."""
    if split == "train":
        return "train"
    if split in ("fit", "test"):
        return "heldout"
    raise ValueError(f"unknown split {split!r}; expected 'train', 'fit' or 'test'")


def pool_sources(pool: str, seed: int) -> tuple[str, ...]:
    """Every source key of a pool (photographs first, then procedural scenes).

    The procedural keys name their pool, so the pools of one seed are disjoint by construction.
    """
    if pool not in POOLS:
        raise ValueError(f"unknown background pool {pool!r}; expected one of {POOLS}")
    photos = tuple(f"photo:{name}" for name in PHOTO_POOLS[pool])
    procedural = tuple(
        f"{kind}:{pool}:{seed}:{k}" for kind in PROCEDURAL_KINDS for k in range(N_PROCEDURAL)
    )
    return photos + procedural


# -- sources ---------------------------------------------------------------------------------------
@lru_cache(maxsize=32)
def _photo(name: str) -> np.ndarray:
    from scrppl._extras import require

    skimage_data = require("render", "skimage.data")
    try:
        img = getattr(skimage_data, name)()
    except Exception as err:  # a sample that would need a download, or a renamed one
        raise RuntimeError(
            f"scikit-image sample image {name!r} is not available offline: {err}"
        ) from err
    img = np.asarray(img)
    if img.dtype != np.uint8:
        img = np.clip(np.round(255 * img.astype(float) / max(float(img.max()), 1e-9)), 0, 255)
        img = img.astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    return img


def _c(rgb) -> tuple[int, int, int]:
    return tuple(int(round(255 * float(np.clip(v, 0, 1)))) for v in rgb)


def _wall(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    base = np.clip(rng.uniform(0.45, 0.92) * (1 + rng.uniform(-0.12, 0.12, 3)), 0, 1)
    y = np.linspace(0, 1, h)[:, None, None]
    grad = (
        1.0
        + rng.uniform(-0.25, 0.15) * y
        + rng.uniform(-0.15, 0.15) * np.linspace(-1, 1, w)[None, :, None]
    )
    img = base * grad * (1 + 0.04 * periodic_noise(rng, (h, w), 2.5))[..., None]
    return img.astype(np.float32)


def _text(rng: np.random.Generator, n: int) -> str:
    letters = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"
    return "".join(letters[i] for i in rng.integers(len(letters), size=n))


def _room(rng: np.random.Generator) -> np.ndarray:
    h, w = _BG_SIZE
    img = _wall(rng, h, w)
    floor_y = int(h * rng.uniform(0.6, 0.85))
    floor = np.clip(rng.uniform(0.2, 0.6) * (1 + rng.uniform(-0.2, 0.2, 3)), 0, 1)
    img[floor_y:] = floor * (1 + 0.08 * periodic_noise(rng, (h - floor_y, w), 1.5))[..., None]
    img[floor_y - 6 : floor_y] = np.clip(floor * 1.4, 0, 1)  # baseboard
    for _ in range(int(rng.integers(1, 4))):  # doors, windows, frames
        x0 = int(rng.integers(0, w - 60))
        ww = int(rng.integers(40, 160))
        y0 = int(rng.integers(10, max(11, floor_y - 120)))
        hh = int(rng.integers(50, max(51, floor_y - y0)))
        frame = _c(rng.uniform(0.1, 0.9, 3))
        cv2.rectangle(img, (x0, y0), (x0 + ww, y0 + hh), [v / 255 for v in frame], -1)
        inner = _c(rng.uniform(0.3, 1.0, 3))
        cv2.rectangle(
            img, (x0 + 6, y0 + 6), (x0 + ww - 6, y0 + hh - 6), [v / 255 for v in inner], -1
        )
        if rng.random() < 0.5:  # window bars
            cv2.line(img, (x0 + ww // 2, y0), (x0 + ww // 2, y0 + hh), [v / 255 for v in frame], 4)
            cv2.line(img, (x0, y0 + hh // 2), (x0 + ww, y0 + hh // 2), [v / 255 for v in frame], 4)
    return img


def _shelves(rng: np.random.Generator) -> np.ndarray:
    h, w = _BG_SIZE
    wood = np.clip(
        np.array([0.5, 0.34, 0.2]) * rng.uniform(0.6, 1.3) * (1 + rng.uniform(-0.1, 0.1, 3)), 0, 1
    )
    img = (wood * 0.55 * (1 + 0.05 * periodic_noise(rng, (h, w), 2.0))[..., None]).astype(
        np.float32
    )
    n = int(rng.integers(3, 6))
    step = h / n
    for k in range(n):
        y1 = int((k + 1) * step) - 8
        cv2.rectangle(img, (0, y1), (w, y1 + 8), tuple(float(v) for v in wood), -1)
        x = int(rng.integers(0, 20))
        while x < w:
            bw = int(rng.integers(8, 26))
            bh = int(step * rng.uniform(0.5, 0.9))
            col = tuple(float(v) for v in rng.uniform(0.05, 0.95, 3))
            if rng.random() < 0.15:  # a gap or a box
                x += bw * 2
                continue
            cv2.rectangle(img, (x, y1 - bh), (x + bw - 1, y1), col, -1)
            if rng.random() < 0.5:
                cv2.line(img, (x + 1, y1 - bh + 6), (x + bw - 2, y1 - bh + 6), (0.9, 0.85, 0.3), 1)
            x += bw
    return img


def _pinboard(rng: np.random.Generator) -> np.ndarray:
    h, w = _BG_SIZE
    img = _wall(rng, h, w)
    for _ in range(int(rng.integers(8, 20))):
        x0, y0 = int(rng.integers(-20, w - 20)), int(rng.integers(-20, h - 20))
        ww, hh = int(rng.integers(30, 140)), int(rng.integers(30, 140))
        col = tuple(float(v) for v in rng.uniform(0.05, 1.0, 3))
        if rng.random() < 0.25:
            cv2.circle(img, (x0, y0), ww // 2, col, -1)
            continue
        cv2.rectangle(img, (x0, y0), (x0 + ww, y0 + hh), col, -1)
        if rng.random() < 0.6:
            ink = tuple(
                float(v)
                for v in (rng.uniform(0, 0.3, 3) if np.mean(col) > 0.5 else rng.uniform(0.7, 1, 3))
            )
            for line in range(int(rng.integers(1, 4))):
                cv2.putText(
                    img,
                    _text(rng, int(rng.integers(3, 8))),
                    (x0 + 4, y0 + 18 + 16 * line),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.45,
                    ink,
                    1,
                    cv2.LINE_AA,
                )
    return img


def _clouds(rng: np.random.Generator) -> np.ndarray:
    h, w = _BG_SIZE
    beta = rng.uniform(1.5, 3.0)
    chans = [periodic_noise(rng, (h, w), beta) for _ in range(3)]
    base = rng.uniform(0.25, 0.75, 3)
    amp = rng.uniform(0.08, 0.25)
    mix = rng.uniform(0.3, 1.0)  # how colourful
    shared = chans[0]
    img = np.stack([base[c] + amp * (mix * chans[c] + (1 - mix) * shared) for c in range(3)], -1)
    return img.astype(np.float32)


def _wallpaper(rng: np.random.Generator) -> np.ndarray:
    h, w = _BG_SIZE
    img = _wall(rng, h, w)
    col = tuple(float(v) for v in np.clip(img.mean((0, 1)) * rng.uniform(0.5, 1.5, 3), 0, 1))
    period = int(rng.integers(14, 48))
    if rng.random() < 0.5:
        for x in range(0, w, period):
            cv2.rectangle(img, (x, 0), (x + period // int(rng.integers(2, 5)), h), col, -1)
    else:
        for y in range(0, h + period, period):
            for x in range(0, w + period, period):
                off = period // 2 if (y // period) % 2 else 0
                cv2.circle(img, (x + off, y), period // 4, col, -1)
    return img


_PROCEDURAL = {
    "room": _room,
    "shelves": _shelves,
    "pinboard": _pinboard,
    "clouds": _clouds,
    "wallpaper": _wallpaper,
}


@lru_cache(maxsize=128)
def source_image(key: str) -> np.ndarray:
    """The full source image of a background key, ``(h, w, 3)`` RGB or ``(h, w)`` grey, uint8."""
    kind, _, rest = key.partition(":")
    if kind == "photo":
        return _photo(rest)
    if kind not in _PROCEDURAL:
        raise ValueError(f"unknown background source {key!r}")
    pool, seed, k = rest.split(":")
    rng = np.random.default_rng(
        [zlib.crc32(kind.encode()), zlib.crc32(pool.encode()), int(seed), int(k)]
    )
    img = _PROCEDURAL[kind](rng)
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)


# -- one image's background ------------------------------------------------------------------------
def draw_background(
    rng: np.random.Generator, pool: str, seed: int, width: int, height: int
) -> BackgroundChoice:
    """Choose a source of ``pool`` and a random crop, flip, colour shift and defocus for it.

    Parameters
    ----------
    rng
        Generator for this image (seeded by the image's identity, so the choice is reproducible).
    pool
        ``"train"`` or ``"heldout"``.
    seed
        The dataset seed (it names the procedural sources).
    width, height
        Output size in pixels; the crop has this aspect ratio.
    """
    sources = pool_sources(pool, seed)
    source = sources[int(rng.integers(len(sources)))]
    aspect = width / height
    frac = rng.uniform(0.45, 1.0)  # share of the largest crop of this aspect
    # crop fractions are resolved against the source size in render_background
    cx, cy = rng.uniform(0, 1, 2)
    flip = bool(rng.random() < 0.5)
    brightness = rng.uniform(0.6, 1.1)
    gain = tuple(float(brightness * g) for g in rng.uniform(0.88, 1.12, 3))
    tint = tuple(float(t) for t in rng.uniform(0.55, 1.0, 3))
    defocus = float(rng.uniform(0.6, 2.0))
    return BackgroundChoice(source, (frac, aspect, float(cx), float(cy)), flip, gain, tint, defocus)


def render_background(choice: BackgroundChoice, width: int, height: int) -> np.ndarray:
    """The background image of a :class:`BackgroundChoice`.

    Returns
    -------
    (height, width, 3) float32 RGB array in [0, 1].
    """
    src = source_image(choice.source)
    sh, sw = src.shape[:2]
    frac, aspect, cx, cy = choice.crop
    cw = min(sw, sh * aspect)
    cw *= frac
    ch = cw / aspect
    x0 = cx * (sw - cw)
    y0 = cy * (sh - ch)
    ix0, iy0 = int(x0), int(y0)
    ix1, iy1 = max(ix0 + 2, int(round(x0 + cw))), max(iy0 + 2, int(round(y0 + ch)))
    crop = src[iy0:iy1, ix0:ix1]
    img = cv2.resize(crop, (width, height), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    if img.ndim == 2:
        img = img[..., None] * np.asarray(choice.tint, dtype=np.float32)
    if choice.flip:
        img = img[:, ::-1]
    img = img * np.asarray(choice.gain, dtype=np.float32)
    img = cv2.GaussianBlur(np.ascontiguousarray(img), (0, 0), choice.defocus)
    return np.clip(img, 0.0, 1.0)
