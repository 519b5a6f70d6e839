"""Compositing and "camera development" of a rendered frame: background, colour, blur, noise, JPEG.

A :class:`~scrppl.datasets.synthetic.render.Frame` holds the object and the floor; everything else is
the background photograph (`scrppl.datasets.synthetic.backgrounds`). :func:`composite` lays the frame
over the background, fading the floor out with its distance from the object so the floor blends into
the scene behind it instead of ending in a hard edge. :func:`develop` then plays the camera: exposure,
white balance, contrast and gamma jitter, a mild lens blur, Gaussian sensor noise and 8-bit
quantisation; :func:`encode_jpeg` compresses like a camera would.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

__all__ = [
    "Development",
    "draw_development",
    "composite",
    "develop",
    "encode_jpeg",
    "encode_png",
]


class Development(NamedTuple):
    """Camera and post-processing parameters of one image.

    Attributes
    ----------
    exposure : float
        Overall gain.
    white_balance : tuple of 3 floats
        Per-channel RGB gain.
    contrast : float
        Contrast about mid-grey.
    gamma : float
        Tone curve exponent.
    blur : float
        Gaussian lens blur sigma in pixels.
    noise : float
        Standard deviation of the Gaussian sensor noise, in 8-bit grey levels.
    vignette : float
        Relative darkening at the corners.
    jpeg_quality : int
        JPEG quality (0-100).
    """

    exposure: float
    white_balance: tuple[float, float, float]
    contrast: float
    gamma: float
    blur: float
    noise: float
    vignette: float
    jpeg_quality: int


_NOISE_BANK: np.ndarray | None = None
_NOISE_BANK_SIZE = 1 << 21


def _sensor_noise(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normal noise of ``shape``: a window of a fixed bank of normals at a random offset.

    Drawing 230,400 fresh normals per image costs more than the rest of the camera model; a window
    of a bank (drawn once from a fixed seed) is as good for sensor noise and still reproducible.
    """
    global _NOISE_BANK
    n = int(np.prod(shape))
    size = max(
        _NOISE_BANK_SIZE, 2 * n
    )  # depends on the image size only, so offsets are reproducible
    if _NOISE_BANK is None or _NOISE_BANK.size < size:
        # a larger bank begins with the same values as a smaller one (same seed, sequential draws)
        _NOISE_BANK = np.random.default_rng(0x5E4502).standard_normal(size, dtype=np.float32)
    start = int(rng.integers(size - n + 1))
    return _NOISE_BANK[start : start + n].reshape(shape)


def draw_development(rng: np.random.Generator, strength: float = 1.0) -> Development:
    """Random camera parameters around a neutral camera (``strength = 0``: exactly neutral but blur)."""
    k = float(strength)
    return Development(
        exposure=float(np.exp(k * rng.uniform(-0.15, 0.15))),
        white_balance=tuple(float(np.exp(k * g)) for g in rng.uniform(-0.06, 0.06, 3)),
        contrast=float(np.exp(k * rng.uniform(-0.12, 0.12))),
        gamma=float(np.exp(k * rng.uniform(-0.1, 0.1))),
        blur=float(0.45 + k * rng.uniform(0.0, 0.35)),
        noise=float(k * rng.uniform(1.5, 4.0)),
        vignette=float(k * rng.uniform(0.0, 0.25)),
        jpeg_quality=int(rng.integers(85, 96)) if k > 0 else 95,
    )


def composite(frame, background: np.ndarray, fade: tuple[float, float]) -> np.ndarray:
    """Lay a rendered frame over a background photograph.

    Parameters
    ----------
    frame : Frame
        The rendered view (``rgb``, ``object_mask``, ``floor_mask``, ``floor_radius``).
    background : (H, W, 3) float array
        Background RGB in [0, 1].
    fade : (float, float)
        Floor radii ``(r_in, r_out)`` in object units: the floor is opaque within ``r_in`` of the
        object's centre and fades (smoothstep) to fully transparent at ``r_out``.

    Returns
    -------
    (H, W, 3) float32 array in [0, 1].
    """
    r_in, r_out = float(fade[0]), float(fade[1])
    if not 0 < r_in < r_out:
        raise ValueError(f"floor fade radii must satisfy 0 < r_in < r_out, got {fade}")
    rgb = frame.rgb.astype(np.float32) / 255.0
    x = np.clip((r_out - frame.floor_radius) / (r_out - r_in), 0.0, 1.0)
    alpha = x * x * (3.0 - 2.0 * x)  # smoothstep; inf radius -> 0
    alpha = np.where(frame.floor_mask, alpha, 0.0).astype(np.float32)
    alpha[frame.object_mask] = 1.0
    a = alpha[..., None]
    return a * rgb + (1.0 - a) * background.astype(np.float32)


def develop(rng: np.random.Generator, image: np.ndarray, dev: Development) -> np.ndarray:
    """Apply exposure, white balance, contrast, gamma, vignetting, blur and sensor noise.

    Parameters
    ----------
    rng
        Generator for the noise (it picks the noise's offset in a fixed bank of normals).
    image : (H, W, 3) float array in [0, 1]
    dev
        The camera parameters.

    Returns
    -------
    (H, W, 3) uint8 RGB array.
    """
    h, w = image.shape[:2]
    img = image.astype(np.float32) * (dev.exposure * np.asarray(dev.white_balance, np.float32))
    if dev.vignette:
        yy, xx = np.ogrid[-1 : 1 : h * 1j, -1 : 1 : w * 1j]
        img *= (1.0 - dev.vignette * 0.5 * (xx**2 + yy**2)).astype(np.float32)[..., None]
    img = np.clip(img, 0.0, 1.0) ** np.float32(dev.gamma)
    img = (img - 0.5) * np.float32(dev.contrast) + 0.5
    if dev.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), dev.blur)
    img = img * 255.0
    if dev.noise > 0:
        img += _sensor_noise(rng, img.shape) * np.float32(dev.noise)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def encode_jpeg(rgb: np.ndarray, quality: int = 92) -> bytes:
    """JPEG bytes of an ``(H, W, 3)`` uint8 RGB image."""
    ok, buf = cv2.imencode(
        ".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    )
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def encode_png(mask: np.ndarray) -> bytes:
    """PNG bytes of a boolean ``(H, W)`` mask, stored as 0/255 grey levels."""
    ok, buf = cv2.imencode(".png", np.where(mask, 255, 0).astype(np.uint8))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()
