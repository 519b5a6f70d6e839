"""The image operations of the robot's domain and the catalogue's studio (`~.domain`).

Each function does one thing to one image and is deterministic given its arguments; the random values
come from :func:`draw_nuisance`, which draws every effect of a :class:`NuisanceDraw` from a child
generator of its own (so changing one parameter of a `~.domain.Nuisance` changes no other effect's
draw).

Order of the effects in an image (`scrppl.datasets.synthetic.generate.render_view`): key light (before
rendering) -> truncation (the rendered frame is shifted past the border) -> background and floor ->
distractors behind, the object, distractors in front -> occluder -> colour cast -> defocus, motion blur
and far-distance resolution (optics) -> the camera's development and noise -> additional sensor noise ->
JPEG.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from scrppl.datasets.synthetic.domain import Nuisance

__all__ = [
    "NuisanceDraw",
    "DistractorDraw",
    "Sprite",
    "draw_nuisance",
    "relight_direction",
    "truncate_frame",
    "paste_sprites",
    "occlude",
    "optics",
    "add_noise",
    "studio_backdrop",
    "plain_floor",
]


class DistractorDraw(NamedTuple):
    """One distractor: which sprite, how tall (relative to the object's box), where, in front or not."""

    sprite: int
    size: float
    x: float  # horizontal centre, in object-box widths from the box's left edge
    y: float  # foot, in object-box heights below the box's bottom edge (negative: above it)
    front: bool
    flip: bool


class NuisanceDraw(NamedTuple):
    """The random values of one robot image (:func:`draw_nuisance`)."""

    light_azimuth: float  # radians, added to the instance light's azimuth
    light_elevation: float  # radians, absolute (used when light_direction > 0)
    light_gain: float
    light_kelvin: float | None
    color_gain: tuple[float, float, float]
    truncation: tuple[int, float] | None  # (side: -1 left / +1 right, fraction)
    distractors: tuple[DistractorDraw, ...]
    occluder: tuple[float, float, float] | None  # (edge normal angle, fraction, extra width)
    occluder_texture: tuple[int, float, float, float]  # (source index, crop x, crop y, gain)
    defocus: float
    motion: tuple[float, float]  # (length px, angle radians)
    noise: float
    noise_seed: int
    resolution: float
    jpeg_quality: int | None


def _u(rng: np.random.Generator, r: tuple[float, float]) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def draw_nuisance(
    rng: np.random.Generator, nuisance: Nuisance, scale: float, n_sprites: int
) -> NuisanceDraw:
    """Draw the nuisances of one image.

    Each effect draws from its own child generator (``rng.spawn``), so the values of one effect do not
    depend on the other parameters: an image with only sensor noise has the noise of the same image with
    every nuisance.

    Parameters
    ----------
    rng
        The image's nuisance generator (seeded by its identity).
    nuisance
        The parameters.
    scale
        The view's distance multiplier (``grid.scales[s]``), for the far-distance resolution.
    n_sprites
        Size of the distractor sprite pool.
    """
    n = nuisance
    r_light, r_color, r_trunc, r_dist, r_occ, r_optics, r_noise, r_jpeg = rng.spawn(8)
    light_azimuth = n.light_direction * float(r_light.uniform(-np.pi, np.pi))
    light_elevation = float(np.deg2rad(r_light.uniform(10.0, 80.0)))
    lo, hi = np.log(n.light_intensity[0]), np.log(n.light_intensity[1])
    light_gain = float(np.exp(r_light.uniform(lo, hi))) if hi > lo else float(np.exp(lo))
    kelvin_u = float(r_light.uniform())
    light_kelvin = (
        None
        if n.light_kelvin is None
        else n.light_kelvin[0] + kelvin_u * (n.light_kelvin[1] - n.light_kelvin[0])
    )
    color_gain = tuple(float(np.exp(n.color_cast * g)) for g in r_color.uniform(-1.0, 1.0, 3))
    trunc_on = bool(r_trunc.random() < n.truncation)
    trunc_side = -1 if r_trunc.random() < 0.5 else 1
    trunc_frac = _u(r_trunc, n.truncation_fraction)
    truncation = (trunc_side, trunc_frac) if trunc_on and trunc_frac > 0 else None
    count = int(r_dist.integers(n.distractors[0], n.distractors[1] + 1))
    distractors = []
    for _ in range(count):
        d = DistractorDraw(
            sprite=int(r_dist.integers(max(n_sprites, 1))),
            size=_u(r_dist, n.distractor_size),
            x=float(r_dist.uniform(-0.45, 1.45)),
            y=float(r_dist.uniform(-0.3, 0.05)),
            front=bool(r_dist.random() < n.distractor_front),
            flip=bool(r_dist.random() < 0.5),
        )
        if d.front:  # a distractor in front stands nearer: lower in the image
            d = d._replace(y=float(0.05 + 0.5 * (d.y + 0.3)))
        distractors.append(d)
    occ_on = bool(r_occ.random() < n.occlusion)
    occ_side = int(r_occ.integers(3))  # 0: from the left, 1: from the right, 2: from below
    occ_angle = [0.0, np.pi, -np.pi / 2][occ_side] + float(r_occ.uniform(-0.35, 0.35))
    occ_frac = _u(r_occ, n.occlusion_fraction)
    occ_extra = float(r_occ.uniform(0.15, 0.6))
    occluder = (occ_angle, occ_frac, occ_extra) if occ_on and occ_frac > 0 else None
    occluder_texture = (
        int(r_occ.integers(1 << 30)),
        float(r_occ.uniform()),
        float(r_occ.uniform()),
        float(r_occ.uniform(0.35, 0.9)),
    )
    defocus = _u(r_optics, n.defocus)
    motion = (_u(r_optics, n.motion_blur), float(r_optics.uniform(0.0, np.pi)))
    noise = _u(r_noise, n.noise)
    noise_seed = int(r_noise.integers(2**31))
    resolution = float(n.far_resolution ** max(0.0, np.log2(float(scale))))
    jpeg_quality = (
        None
        if n.jpeg_quality is None
        else int(r_jpeg.integers(n.jpeg_quality[0], n.jpeg_quality[1] + 1))
    )
    return NuisanceDraw(
        light_azimuth,
        light_elevation,
        light_gain,
        light_kelvin,
        color_gain,
        truncation,
        tuple(distractors),
        occluder,
        occluder_texture,
        defocus,
        motion,
        noise,
        noise_seed,
        resolution,
        jpeg_quality,
    )


def relight_direction(direction: np.ndarray, draw: NuisanceDraw, strength: float) -> np.ndarray:
    """The key light's direction: the instance's, turned by ``strength`` of the drawn departure.

    ``strength = 0`` returns ``direction``; 1 turns its azimuth by a uniform angle on the circle and sets
    its elevation to the drawn one.
    """
    d = np.asarray(direction, dtype=float)
    if strength == 0:
        return d
    az = float(np.arctan2(d[1], d[0])) + draw.light_azimuth
    el0 = float(np.arcsin(np.clip(d[2] / np.linalg.norm(d), -1.0, 1.0)))
    el = el0 + strength * (draw.light_elevation - el0)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _shift(a: np.ndarray, dx: int, fill) -> np.ndarray:
    out = np.full_like(a, fill)
    w = a.shape[1]
    if dx >= 0:
        out[:, dx:] = a[:, : w - dx]
    else:
        out[:, : w + dx] = a[:, -dx:]
    return out


def truncate_frame(frame, side: int, fraction: float):
    """Shift a rendered frame sideways so that ``fraction`` of the object's pixels leave the image.

    Parameters
    ----------
    frame : Frame
        The rendered view (`scrppl.datasets.synthetic.render.Frame`).
    side
        ``+1``: the object is cut by the right border; ``-1``: by the left border.
    fraction
        Share of the object's mask pixels that end up outside the image (exact up to whole columns).

    Returns
    -------
    Frame
        The shifted frame; floor and object pixels shifted in from outside are empty (the background
        shows there).
    """
    mask = frame.object_mask
    cols = mask.sum(axis=0).astype(np.int64)
    total = int(cols.sum())
    if total == 0 or fraction <= 0:
        return frame
    w = mask.shape[1]
    want = fraction * total
    if side > 0:  # columns from the right end leave through the right border
        tail = np.cumsum(cols[::-1])  # tail[j]: pixels in the last j+1 columns
        j = int(np.argmin(np.abs(tail - want)))
        x_cut = w - 1 - j  # this column and those right of it leave
        dx = w - x_cut
    else:
        head = np.cumsum(cols)
        j = int(np.argmin(np.abs(head - want)))
        dx = -(j + 1)
    return type(frame)(
        _shift(frame.rgb, dx, 0),
        _shift(frame.object_mask, dx, False),
        _shift(frame.floor_mask, dx, False),
        _shift(frame.floor_radius, dx, np.inf),
    )


class Sprite(NamedTuple):
    """A cut-out rendered object of a distractor.

    Attributes
    ----------
    rgb : (h, w, 3) float array in [0, 1]
    alpha : (h, w) bool array
        The object's pixels.
    category : str
        Its category (an image never gets distractors of its own category).
    """

    rgb: np.ndarray
    alpha: np.ndarray
    category: str


def _place(sprite: Sprite, d: DistractorDraw, box: tuple[int, int, int, int]):
    """Resize ``sprite`` for draw ``d`` beside ``box``; returns ``(rgb, alpha, x0, y0)``."""
    bx0, by0, bx1, by1 = box
    bw, bh = max(bx1 - bx0, 1), max(by1 - by0, 1)
    h = max(int(round(d.size * bh)), 6)
    sh, sw = sprite.alpha.shape
    w = max(int(round(sw * h / sh)), 3)
    rgb = cv2.resize(sprite.rgb, (w, h), interpolation=cv2.INTER_AREA)
    alpha = cv2.resize(sprite.alpha.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) > 0.5
    if d.flip:
        rgb, alpha = rgb[:, ::-1], alpha[:, ::-1]
    cx = bx0 + d.x * bw
    foot = by1 + d.y * bh
    return rgb, alpha, int(round(cx - w / 2)), int(round(foot - h))


def paste_sprites(
    image: np.ndarray,
    mask: np.ndarray,
    sprites: list[Sprite],
    draws: tuple[DistractorDraw, ...],
    *,
    min_visible: float = 0.3,
) -> tuple[np.ndarray, np.ndarray]:
    """Add distractor objects to a composited image around the object's box.

    Distractors behind the object are drawn only where the object is not; one in front is drawn over
    everything and removes the pixels it covers from the object's mask -- unless the object would keep
    less than ``min_visible`` of its pixels, in which case that distractor stands behind instead.

    Parameters
    ----------
    image : (H, W, 3) float array in [0, 1]
    mask : (H, W) bool array
        The object's visible pixels.
    sprites
        The sprite pool.
    draws
        The distractors (:class:`DistractorDraw`).

    Returns
    -------
    image, mask
        New arrays.
    """
    image, mask = image.copy(), mask.copy()
    if not draws or not mask.any() or not sprites:
        return image, mask
    ys, xs = np.nonzero(mask)
    box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    total = int(mask.sum())
    hh, ww = mask.shape
    # behind first, then in front, each group in draw order
    for d in sorted(draws, key=lambda d: d.front):
        rgb, alpha, x0, y0 = _place(sprites[d.sprite % len(sprites)], d, box)
        h, w = alpha.shape
        ix0, iy0, ix1, iy1 = max(x0, 0), max(y0, 0), min(x0 + w, ww), min(y0 + h, hh)
        if ix0 >= ix1 or iy0 >= iy1:
            continue
        a = alpha[iy0 - y0 : iy1 - y0, ix0 - x0 : ix1 - x0]
        c = rgb[iy0 - y0 : iy1 - y0, ix0 - x0 : ix1 - x0]
        region_mask = mask[iy0:iy1, ix0:ix1]
        kept = int(mask.sum()) - int((region_mask & a).sum())
        front = d.front and kept >= min_visible * total
        paint = a if front else a & ~region_mask
        image[iy0:iy1, ix0:ix1][paint] = c[paint]
        if front:
            mask[iy0:iy1, ix0:ix1] = region_mask & ~a
    return image, mask


def occlude(
    image: np.ndarray,
    mask: np.ndarray,
    angle: float,
    fraction: float,
    extra: float,
    texture: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hide ``fraction`` of the object behind a foreground occluder with a straight edge.

    The occluder covers the pixels ``p`` with ``t - b <= p . n <= t``, ``n = (cos angle, sin angle)``
    pointing from where it enters into the object; ``t`` is the ``fraction`` quantile of the object
    pixels' projections (so it hides that share of them) and its far edge lies ``extra`` object sizes
    beyond the object's first pixel (a post or ledge, not a wall).

    Parameters
    ----------
    image : (H, W, 3) float array in [0, 1]
    mask : (H, W) bool array
        The object's visible pixels (non-empty).
    angle
        Direction of ``n`` in radians (image x right, y down): 0 enters from the left, pi from the right,
        -pi/2 from below.
    fraction
        Share of the object's pixels to hide, in [0, 1).
    extra
        Width of the occluder beyond the object's first pixel, in units of the object's extent along n.
    texture : (H, W, 3) float array
        The occluder's surface.

    Returns
    -------
    image, mask, covered
        The new image and visible mask, and the occluder's pixels.
    """
    hh, ww = mask.shape
    yy, xx = np.mgrid[0:hh, 0:ww]
    n = np.array([np.cos(angle), -np.sin(angle)])  # y grows downwards: "from below" means n.y < 0
    p = xx * n[0] + yy * n[1]
    obj = p[mask]
    lo, hi = float(obj.min()), float(obj.max())
    t = float(np.quantile(obj, fraction, method="lower"))
    covered = (p <= t) & (p >= lo - extra * max(hi - lo, 1.0))
    if fraction <= 0:
        covered[:] = False
    out = image.copy()
    # a little shading towards the edge, so the occluder reads as a solid in front
    shade = np.clip(0.75 + 0.25 * (t - p) / max(extra * (hi - lo), 1.0), 0.75, 1.0)
    out[covered] = (texture * shade[..., None])[covered]
    return out, mask & ~covered, covered


def optics(
    image: np.ndarray, defocus: float, motion: tuple[float, float], resolution: float
) -> np.ndarray:
    """Defocus (Gaussian), linear motion blur and reduced effective resolution of a float image.

    Parameters
    ----------
    image : (H, W, 3) float array
    defocus
        Gaussian sigma in pixels (0: none).
    motion
        ``(length, angle)``: a line kernel of ``length`` pixels at ``angle`` radians (length < 1: none).
    resolution
        Linear resolution factor in (0, 1]: the image is downsampled to that size (area averaging) and
        enlarged back (bilinear); 1: unchanged.
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    if defocus > 0:
        img = cv2.GaussianBlur(img, (0, 0), float(defocus))
    length, angle = motion
    if length >= 1.0:
        k = int(np.ceil(length)) | 1
        kernel = np.zeros((k, k), np.float32)
        c = (k - 1) / 2.0
        for t in np.linspace(-length / 2, length / 2, 4 * k):
            kernel[int(round(c + t * np.sin(angle))), int(round(c + t * np.cos(angle)))] += 1.0
        kernel /= kernel.sum()
        img = cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT)
    if resolution < 1.0:
        h, w = img.shape[:2]
        small = (max(int(round(w * resolution)), 8), max(int(round(h * resolution)), 8))
        img = cv2.resize(
            cv2.resize(img, small, interpolation=cv2.INTER_AREA),
            (w, h),
            interpolation=cv2.INTER_LINEAR,
        )
    return img


def add_noise(seed: int, image: np.ndarray, sigma: float) -> np.ndarray:
    """Add Gaussian sensor noise of ``sigma`` grey levels to a uint8 image (rounded and clipped)."""
    if sigma <= 0:
        return image
    rng = np.random.default_rng(seed)
    noisy = image.astype(np.float32) + rng.standard_normal(
        image.shape, dtype=np.float32
    ) * np.float32(sigma)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


def studio_backdrop(
    rng: np.random.Generator, tone: np.ndarray, width: int, height: int
) -> np.ndarray:
    """A plain studio backdrop: ``tone`` at the bottom, a gentle vertical gradient, ``(H, W, 3)`` float32."""
    top = float(rng.uniform(0.9, 1.05))
    bottom = 1.0
    y = np.linspace(0.0, 1.0, height, dtype=np.float32)[:, None, None]
    img = np.asarray(tone, np.float32) * (top + (bottom - top) * y)
    return np.clip(np.broadcast_to(img, (height, width, 3)), 0.0, 1.0).astype(np.float32)


def plain_floor(tone: np.ndarray):
    """A seamless, untextured studio floor of one tone (`scrppl.datasets.synthetic.floors.Floor`)."""
    from scrppl.datasets.synthetic.floors import Floor

    tex = np.empty((16, 16, 3), np.uint8)
    tex[:] = np.clip(np.round(np.asarray(tone) * 255), 0, 255).astype(np.uint8)
    return Floor(tex, 1.0, "studio")
