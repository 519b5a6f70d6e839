"""Procedural, seamlessly tiling floor textures for the synthetic dataset's ground plane.

Each instance is photographed on its own floor (wooden planks, ceramic tiles, carpet, concrete or
linoleum), drawn here from an integer seed. The textures tile without seams because every ingredient is
periodic over the texture: noise is synthesised in the Fourier domain (so it wraps around), and plank,
tile and checker layouts divide the texture size exactly. The renderer repeats the texture over the
ground plane, ``tile_size`` object units per copy.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

__all__ = ["FLOOR_KINDS", "Floor", "make_floor", "periodic_noise"]

#: The kinds of floor :func:`make_floor` draws from.
FLOOR_KINDS = ("wood", "tiles", "carpet", "concrete", "linoleum")

_SIZE = 256  # texture side in pixels; every periodic layout below divides it


class Floor(NamedTuple):
    """A floor texture and how large one copy of it is on the ground.

    Attributes
    ----------
    texture : (256, 256, 3) uint8 array
        RGB texture that tiles seamlessly in both directions.
    tile_size : float
        Side of one copy of the texture on the ground plane, in object units (objects are about 1 unit).
    kind : str
        One of `FLOOR_KINDS`.
    """

    texture: np.ndarray
    tile_size: float
    kind: str


def periodic_noise(rng: np.random.Generator, shape: tuple[int, int], beta: float) -> np.ndarray:
    """Gaussian noise with a ``1 / f**beta`` power spectrum that wraps around seamlessly.

    Parameters
    ----------
    rng
        Generator the random spectrum is drawn from.
    shape
        ``(H, W)`` of the output.
    beta
        Spectral exponent: 0 is white noise, 2 is cloudy, 3 is very smooth.

    Returns
    -------
    (H, W) float array with zero mean and unit standard deviation.
    """
    h, w = shape
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    amp = f ** (-beta / 2.0)
    amp[0, 0] = 0.0
    spec = amp * (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape))
    x = np.fft.irfft2(spec, s=(h, w))
    return (x - x.mean()) / (x.std() + 1e-12)


def _jitter_color(rng: np.random.Generator, base, spread: float) -> np.ndarray:
    return np.clip(np.asarray(base, dtype=float) * rng.uniform(1 - spread, 1 + spread, 3), 0, 1)


def _wood(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    n_planks = int(rng.choice([4, 8]))
    width = _SIZE // n_planks
    base = _jitter_color(
        rng,
        [(0.55, 0.36, 0.2), (0.72, 0.55, 0.36), (0.38, 0.24, 0.14), (0.8, 0.68, 0.5)][
            rng.integers(4)
        ],
        0.08,
    )
    u = np.ones((_SIZE, 1)) * np.arange(_SIZE)[None, :]
    warp = periodic_noise(rng, (_SIZE, _SIZE), 2.5)
    img = np.empty((_SIZE, _SIZE, 3))
    for k in range(n_planks):
        cols = slice(k * width, (k + 1) * width)
        plank = _jitter_color(rng, base, 0.12)
        # grain: stripes along the plank, their phase warped by smooth noise
        freq = rng.integers(3, 7)
        grain = np.sin(2 * np.pi * (freq * u[:, cols] / width + 0.6 * warp[:, cols]))
        shade = 1.0 + 0.14 * grain + 0.04 * periodic_noise(rng, (_SIZE, _SIZE), 1.0)[:, cols]
        img[:, cols] = plank * shade[..., None]
        # one butt joint per plank, staggered
        seam = int(rng.integers(_SIZE))
        img[seam : seam + 2, cols] *= 0.55
        img[:, k * width : k * width + 2] *= 0.5  # gap between planks
    return img, float(rng.uniform(1.6, 2.6))


def _tiles(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    n = int(rng.choice([2, 4]))
    side = _SIZE // n
    base = _jitter_color(
        rng,
        [(0.85, 0.84, 0.8), (0.6, 0.62, 0.65), (0.75, 0.6, 0.45), (0.35, 0.38, 0.42)][
            rng.integers(4)
        ],
        0.1,
    )
    grout = np.clip(base * rng.uniform(0.45, 0.75), 0, 1)
    gw = int(rng.integers(3, 7))
    mottle = periodic_noise(rng, (_SIZE, _SIZE), 2.0)
    img = np.empty((_SIZE, _SIZE, 3))
    for i in range(n):
        for j in range(n):
            c = _jitter_color(rng, base, 0.05)
            img[i * side : (i + 1) * side, j * side : (j + 1) * side] = c
    img *= (1.0 + 0.05 * mottle)[..., None]
    for k in range(n):
        img[k * side : k * side + gw] = grout
        img[:, k * side : k * side + gw] = grout
    return img, float(rng.uniform(0.9, 1.6))


def _carpet(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    base = _jitter_color(
        rng,
        [(0.45, 0.2, 0.18), (0.25, 0.3, 0.45), (0.5, 0.48, 0.42), (0.3, 0.4, 0.3)][rng.integers(4)],
        0.15,
    )
    fine = periodic_noise(rng, (_SIZE, _SIZE), 0.6)
    coarse = periodic_noise(rng, (_SIZE, _SIZE), 2.5)
    img = base * (1.0 + 0.12 * fine + 0.08 * coarse)[..., None]
    return img, float(rng.uniform(0.5, 0.9))


def _concrete(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    grey = rng.uniform(0.45, 0.7)
    base = _jitter_color(rng, (grey, grey * 0.98, grey * 0.95), 0.04)
    cloud = periodic_noise(rng, (_SIZE, _SIZE), 2.8)
    grit = periodic_noise(rng, (_SIZE, _SIZE), 0.3)
    img = base * (1.0 + 0.1 * cloud + 0.05 * grit)[..., None]
    specks = rng.random((_SIZE, _SIZE)) < 0.004
    img[specks] *= 0.55
    return img, float(rng.uniform(1.8, 3.0))


def _linoleum(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    n = int(rng.choice([2, 4, 8]))
    side = _SIZE // n
    hue = rng.uniform(0.25, 0.85, 3)
    a = np.clip(0.55 * hue + 0.45 * hue.mean(), 0, 1)  # muted colours
    b = np.clip(a * rng.uniform(0.45, 0.8), 0, 1)
    ii, jj = np.meshgrid(np.arange(_SIZE) // side, np.arange(_SIZE) // side, indexing="ij")
    img = np.where(((ii + jj) % 2 == 0)[..., None], a, b)
    img = img * (1.0 + 0.04 * periodic_noise(rng, (_SIZE, _SIZE), 1.5))[..., None]
    return img, float(rng.uniform(0.8, 1.6))


_DRAW = {
    "wood": _wood,
    "tiles": _tiles,
    "carpet": _carpet,
    "concrete": _concrete,
    "linoleum": _linoleum,
}


def make_floor(seed: int | np.random.Generator, kind: str | None = None) -> Floor:
    """Draw one floor texture.

    Parameters
    ----------
    seed
        Integer seed (or a NumPy generator); the same seed gives the same texture.
    kind
        One of `FLOOR_KINDS`; drawn at random when ``None``.

    Returns
    -------
    Floor
        The ``(256, 256, 3)`` uint8 texture, its size on the ground and its kind.
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if kind is None:
        kind = FLOOR_KINDS[int(rng.integers(len(FLOOR_KINDS)))]
    if kind not in _DRAW:
        raise ValueError(f"unknown floor kind {kind!r}; expected one of {', '.join(FLOOR_KINDS)}")
    img, tile = _DRAW[kind](rng)
    # a touch of blur: the renderer samples without mipmaps, so keep the texture free of aliasing bait
    pad = 4  # blur with wrap-around (OpenCV has no wrapping border for separable filters)
    img = np.pad(img.astype(np.float32), ((pad, pad), (pad, pad), (0, 0)), mode="wrap")
    img = cv2.GaussianBlur(img, (0, 0), 0.7)[pad:-pad, pad:-pad]
    tex = np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
    return Floor(tex, tile, kind)
