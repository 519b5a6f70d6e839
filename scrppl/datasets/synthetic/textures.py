"""Procedural textures for the synthetic categories, drawn with NumPy and OpenCV.

Every function takes an explicit integer ``seed`` first and returns an ``(H, W, 3)`` ``uint8`` RGB
image; the same seed gives the same pixels. Row 0 is the *top* of the image (it maps to ``v = 1`` in
the texture coordinates of `scrppl.datasets.synthetic.shapes.Part`).

Colours are RGB triples in [0, 1]. OpenCV is only used as a drawing library here (its channel order
does not matter because colours are passed in the image's own order).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "brand_name",
    "brushed_metal",
    "face",
    "fabric",
    "grille",
    "hubcap",
    "keypad_phone",
    "label",
    "license_plate",
    "mouse_top",
    "phone_screen",
    "plastic",
    "screen",
    "shoe_upper",
    "tread",
    "value_noise",
    "wood",
]

_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_TRIPLEX)


def _c(color) -> tuple[int, int, int]:
    """RGB in [0, 1] -> integer 0..255 triple for OpenCV drawing."""
    return tuple(int(round(255 * float(np.clip(v, 0.0, 1.0)))) for v in color)


def _canvas(height: int, width: int, color) -> np.ndarray:
    img = np.empty((height, width, 3), dtype=np.uint8)
    img[:] = _c(color)
    return img


def _to_uint8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)


def value_noise(seed: int, height: int, width: int, cells: int = 8, octaves: int = 3) -> np.ndarray:
    """Smooth fractal value noise.

    Parameters
    ----------
    seed : int
    height, width : int
        Output size.
    cells : int
        Number of random lattice cells across the smaller side at the coarsest octave.
    octaves : int
        Octaves summed with halving amplitude.

    Returns
    -------
    (height, width) float array in [0, 1]
    """
    rng = np.random.default_rng(seed)
    out = np.zeros((height, width))
    amp, total = 1.0, 0.0
    for k in range(octaves):
        n = cells * 2**k
        ny = max(2, int(round(n * height / min(height, width))))
        nx = max(2, int(round(n * width / min(height, width))))
        grid = rng.random((ny, nx)).astype(np.float32)
        out += amp * cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.5
    out /= total
    lo, hi = out.min(), out.max()
    return (out - lo) / max(hi - lo, 1e-9)


def _tint(noise: np.ndarray, color, amount: float) -> np.ndarray:
    base = np.asarray(color, float)[None, None, :]
    return _to_uint8(base * (1.0 + amount * (noise[..., None] - 0.5)))


def plastic(seed: int, color, height: int = 64, width: int = 64) -> np.ndarray:
    """Slightly mottled plastic of the given colour."""
    return _tint(value_noise(seed, height, width, cells=6), color, 0.12)


def brushed_metal(
    seed: int, color=(0.75, 0.76, 0.78), height: int = 64, width: int = 128
) -> np.ndarray:
    """Brushed metal: fine horizontal streaks over a soft vertical gradient."""
    rng = np.random.default_rng(seed)
    streaks = rng.random((height, 1)) * 0.6 + rng.random((height, width)) * 0.15
    streaks = cv2.GaussianBlur(streaks.astype(np.float32), (0, 0), sigmaX=6.0, sigmaY=0.5)
    grad = np.linspace(1.1, 0.85, height)[:, None]
    return _tint(streaks * grad, color, 0.35)


def wood(seed: int, color=(0.55, 0.36, 0.2), height: int = 128, width: int = 128) -> np.ndarray:
    """Wood grain: distorted growth rings along the image's horizontal axis."""
    n = value_noise(seed, height, width, cells=3, octaves=2)
    y = np.linspace(0.0, 1.0, height)[:, None]
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (9.0 * y + 2.5 * n))
    return _tint(0.7 * rings + 0.3 * n, color, 0.5)


def fabric(seed: int, color, height: int = 64, width: int = 64) -> np.ndarray:
    """Woven fabric: a fine checker of threads with noise."""
    yy, xx = np.mgrid[0:height, 0:width]
    weave = 0.5 + 0.25 * np.sin(xx * 1.6) * np.sin(yy * 1.6)
    n = value_noise(seed, height, width, cells=10, octaves=1)
    return _tint(0.7 * weave + 0.3 * n, color, 0.4)


_SYLLABLES = (
    "ka",
    "ze",
    "to",
    "ri",
    "no",
    "va",
    "lu",
    "mi",
    "xo",
    "pe",
    "sa",
    "do",
    "ne",
    "ro",
    "ti",
)


def brand_name(seed: int, n_syllables: int | None = None) -> str:
    """A made-up, pronounceable brand name in capitals (e.g. "ZENORI")."""
    rng = np.random.default_rng(seed)
    n = int(n_syllables or rng.integers(2, 4))
    return "".join(_SYLLABLES[int(i)] for i in rng.integers(0, len(_SYLLABLES), n)).upper()


def _put_text_fit(img, text, box, color, font, thickness=2):
    """Draw ``text`` scaled to fit ``box`` = (x0, y0, x1, y1) in pixels, centred."""
    x0, y0, x1, y1 = box
    (tw, th), base = cv2.getTextSize(text, font, 1.0, thickness)
    scale = min((x1 - x0) / max(tw, 1), (y1 - y0) / max(th + base, 1))
    (tw, th), base = cv2.getTextSize(text, font, scale, thickness)
    org = (int(x0 + (x1 - x0 - tw) / 2), int(y0 + (y1 - y0 + th) / 2))
    cv2.putText(img, text, org, font, scale, _c(color), thickness, cv2.LINE_AA)


def label(
    seed: int,
    background,
    foreground,
    height: int = 64,
    width: int = 192,
    text: str | None = None,
    logo: bool = True,
) -> np.ndarray:
    """A brand label: a made-up name, optionally beside a simple geometric logo."""
    rng = np.random.default_rng(seed)
    img = _canvas(height, width, background)
    text = text or brand_name(int(rng.integers(2**31)))
    font = _FONTS[int(rng.integers(len(_FONTS)))]
    x_text = 0
    if logo:
        r = int(0.32 * height)
        cx, cy = int(0.5 * height), height // 2
        kind = int(rng.integers(3))
        if kind == 0:
            cv2.circle(img, (cx, cy), r, _c(foreground), -1, cv2.LINE_AA)
            cv2.circle(img, (cx, cy), r // 2, _c(background), -1, cv2.LINE_AA)
        elif kind == 1:
            pts = np.array([[cx, cy - r], [cx + r, cy + r], [cx - r, cy + r]], np.int32)
            cv2.fillPoly(img, [pts], _c(foreground), cv2.LINE_AA)
        else:
            cv2.rectangle(img, (cx - r, cy - r), (cx + r, cy + r), _c(foreground), -1)
            cv2.line(img, (cx - r, cy + r), (cx + r, cy - r), _c(background), max(2, r // 3))
        x_text = height
    _put_text_fit(img, text, (x_text + 4, 6, width - 6, height - 6), foreground, font, 2)
    return img


def _window(img, rng, x0, y0, x1, y1):
    """Draw an application window with a title bar and content lines."""
    accent = rng.random(3) * 0.6 + 0.2
    cv2.rectangle(img, (x0 + 2, y0 + 2), (x1 + 2, y1 + 2), (30, 30, 30), -1)  # shadow
    cv2.rectangle(img, (x0, y0), (x1, y1), (245, 245, 245), -1)
    bar = max(4, (y1 - y0) // 8)
    cv2.rectangle(img, (x0, y0), (x1, y0 + bar), _c(accent), -1)
    kind = int(rng.integers(3))
    if kind == 0:  # text lines
        y = y0 + bar + 5
        while y < y1 - 4:
            w = int((x1 - x0 - 10) * (0.4 + 0.6 * rng.random()))
            cv2.line(img, (x0 + 5, y), (x0 + 5 + w, y), (60, 60, 60), 1)
            y += 4 + int(rng.integers(2))
    elif kind == 1:  # bar chart
        n = int(rng.integers(4, 9))
        bw = max(2, (x1 - x0 - 10) // n)
        for k in range(n):
            h = int((y1 - y0 - bar - 10) * rng.uniform(0.2, 1.0))
            cv2.rectangle(
                img,
                (x0 + 5 + k * bw, y1 - 5 - h),
                (x0 + 4 + (k + 1) * bw - 2, y1 - 5),
                _c(accent),
                -1,
            )
    else:  # picture
        g = np.linspace(0, 1, y1 - y0 - bar)[:, None, None]
        c0, c1 = rng.random(3), rng.random(3)
        img[y0 + bar : y1, x0:x1] = _to_uint8(
            np.broadcast_to(c0 * (1 - g) + c1 * g, (y1 - y0 - bar, x1 - x0, 3))
        )
        cv2.circle(
            img,
            (int(rng.integers(x0 + 5, x1 - 4)), int(rng.integers(y0 + bar + 3, y1 - 2))),
            max(3, (x1 - x0) // 8),
            _c(rng.random(3)),
            -1,
        )


def screen(seed: int, height: int = 120, width: int = 192, kind: str | None = None) -> np.ndarray:
    """Screen content of a monitor: a desktop with windows, a photo, a document or a dashboard.

    Parameters
    ----------
    seed : int
    height, width : int
    kind : {"desktop", "photo", "document", "dashboard"} or None
        Chosen by the seed when None.
    """
    rng = np.random.default_rng(seed)
    kinds = ("desktop", "photo", "document", "dashboard")
    kind = kind or kinds[int(rng.integers(len(kinds)))]
    if kind not in kinds:
        raise ValueError(f"unknown screen kind {kind!r}; expected one of {kinds}")
    g = np.linspace(0, 1, height)[:, None, None]
    if kind == "desktop":
        c0, c1 = rng.random(3) * 0.7, rng.random(3) * 0.7 + 0.3
        img = _to_uint8(np.broadcast_to(c0 * (1 - g) + c1 * g, (height, width, 3)))
        for _ in range(int(rng.integers(4, 9))):  # icons
            x, y = int(rng.integers(4, width // 5)), int(rng.integers(4, height - 20))
            cv2.rectangle(img, (x, y), (x + 10, y + 10), _c(rng.random(3)), -1)
        for _ in range(int(rng.integers(1, 4))):
            x0, y0 = int(rng.integers(width // 5, width // 2)), int(rng.integers(5, height // 3))
            _window(
                img,
                rng,
                x0,
                y0,
                min(width - 4, x0 + int(rng.integers(width // 3, width // 2))),
                min(height - 16, y0 + int(rng.integers(height // 3, height // 2))),
            )
        cv2.rectangle(img, (0, height - 12), (width, height), (25, 25, 35), -1)  # task bar
        for k in range(int(rng.integers(3, 8))):
            cv2.rectangle(
                img, (6 + 14 * k, height - 10), (16 + 14 * k, height - 2), _c(rng.random(3)), -1
            )
    elif kind == "photo":
        sky0, sky1 = (
            np.array([0.25, 0.45, 0.85]) * rng.uniform(0.7, 1.1),
            np.array([0.85, 0.75, 0.6]),
        )
        img = _to_uint8(np.broadcast_to(sky0 * (1 - g) + sky1 * g, (height, width, 3)))
        cv2.circle(
            img,
            (int(rng.integers(width)), int(rng.integers(height // 3))),
            height // 10,
            (255, 230, 150),
            -1,
            cv2.LINE_AA,
        )
        x = np.arange(width)
        rows = np.arange(height)[:, None]
        for k, col in enumerate(([0.2, 0.35, 0.25], [0.25, 0.5, 0.2], [0.45, 0.4, 0.25])):
            ph, fr = rng.uniform(0, 6), rng.uniform(0.01, 0.04)
            top = height * (0.45 + 0.15 * k) + 10 * np.sin(fr * x + ph)
            img[rows >= top[None, :]] = _c(np.asarray(col) * rng.uniform(0.9, 1.1))
    elif kind == "document":
        img = _canvas(height, width, (0.93, 0.93, 0.95))
        cv2.rectangle(img, (0, 0), (width, 10), _c(rng.random(3) * 0.5 + 0.2), -1)
        x0, x1 = width // 6, 5 * width // 6
        cv2.rectangle(img, (x0 - 4, 14), (x1 + 4, height), (255, 255, 255), -1)
        y = 20
        while y < height - 4:
            if rng.random() < 0.12:
                y += 5
                continue
            w = int((x1 - x0) * (0.5 + 0.5 * rng.random()))
            cv2.line(img, (x0, y), (x0 + w, y), (70, 70, 80), 1)
            y += 5
    else:  # dashboard
        img = _canvas(height, width, (0.12, 0.13, 0.16))
        for k in range(4):
            x0 = 6 + k * (width - 12) // 4
            cv2.rectangle(
                img,
                (x0, 6),
                (x0 + (width - 12) // 4 - 6, height // 3),
                _c(rng.random(3) * 0.7 + 0.3),
                -1,
            )
        pts = np.column_stack(
            [np.linspace(8, width - 8, 20), height - 12 - rng.random(20).cumsum() * (height / 25)]
        ).astype(np.int32)
        cv2.polylines(img, [pts], False, (90, 220, 120), 2, cv2.LINE_AA)
    return img


def phone_screen(seed: int, height: int = 160, width: int = 80) -> np.ndarray:
    """Smartphone screen in portrait: wallpaper, status bar, a grid of app icons and a dock."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0, 1, height)[:, None, None]
    c0, c1 = rng.random(3), rng.random(3) * 0.5
    img = _to_uint8(np.broadcast_to(c0 * (1 - g) + c1 * g, (height, width, 3)))
    cv2.rectangle(img, (0, 0), (width, 8), (10, 10, 10), -1)
    cv2.putText(
        img,
        f"12:{int(rng.integers(60)):02d}",
        (3, 7),
        cv2.FONT_HERSHEY_PLAIN,
        0.5,
        (255, 255, 255),
        1,
    )
    cols, rows = 4, int(rng.integers(3, 6))
    s = width // (cols + 1)
    for r in range(rows):
        for c in range(cols):
            x, y = int((c + 0.5) * width / cols - s / 2), 16 + r * int(1.4 * s)
            cv2.rectangle(img, (x, y), (x + s, y + s), _c(rng.random(3) * 0.8 + 0.2), -1)
    cv2.rectangle(img, (2, height - s - 8), (width - 2, height - 3), (220, 220, 225), -1)
    for c in range(cols):
        x = int((c + 0.5) * width / cols - s / 2)
        cv2.rectangle(img, (x, height - s - 5), (x + s, height - 6), _c(rng.random(3)), -1)
    return img


def keypad_phone(seed: int, body, height: int = 160, width: int = 80) -> np.ndarray:
    """Front of a classic keypad phone: a small lit screen above a 4 x 3 grid of keys."""
    rng = np.random.default_rng(seed)
    img = _canvas(height, width, body)
    sx0, sy0, sx1, sy1 = 8, 10, width - 8, int(0.45 * height)
    cv2.rectangle(img, (sx0 - 2, sy0 - 2), (sx1 + 2, sy1 + 2), (15, 15, 15), -1)
    img[sy0:sy1, sx0:sx1] = screen(int(rng.integers(2**31)), sy1 - sy0, sx1 - sx0, "desktop")
    key_color = _c(np.asarray(body) * 0.6 + 0.35)
    kw, kh = (width - 16) // 3, (height - sy1 - 24) // 5
    for r in range(5):
        for c in range(3):
            x, y = 8 + c * kw, sy1 + 10 + r * kh
            col = ((60, 170, 70), key_color, (200, 60, 60))[c] if r == 0 else key_color
            cv2.rectangle(img, (x + 2, y + 2), (x + kw - 2, y + kh - 2), col, -1)
            if r > 0:
                cv2.putText(
                    img,
                    str((r - 1) * 3 + c + 1 if r < 4 else "*0#"[c]),
                    (x + kw // 2 - 3, y + kh - 4),
                    cv2.FONT_HERSHEY_PLAIN,
                    0.7,
                    (30, 30, 30),
                    1,
                )
    return img


def tread(seed: int, height: int = 32, width: int = 256, kind: str | None = None) -> np.ndarray:
    """Tyre tread (the tyre's circumference runs along the image's width).

    ``kind`` is one of "blocks", "chevron", "ribs" (chosen by the seed when None).
    """
    rng = np.random.default_rng(seed)
    kinds = ("blocks", "chevron", "ribs")
    kind = kind or kinds[int(rng.integers(len(kinds)))]
    img = _tint(
        value_noise(int(rng.integers(2**31)), height, width, cells=4, octaves=2),
        (0.1, 0.1, 0.1),
        0.4,
    )
    dark = (8, 8, 8)
    period = int(rng.integers(8, 14))
    if kind == "blocks":
        for x in range(0, width, period):
            off = (x // period) % 2 * (period // 2)
            cv2.rectangle(
                img,
                (x + 1, height // 4 + off // 3),
                (x + period // 2, 3 * height // 4 - off // 3),
                (35, 35, 35),
                -1,
            )
            cv2.line(img, (x, 0), (x, height), dark, 1)
    elif kind == "chevron":
        for x in range(-period, width + period, period):
            pts = np.array([[x, 0], [x + period // 2, height // 2], [x, height]], np.int32)
            cv2.polylines(img, [pts], False, (40, 40, 40), 2)
    else:
        for y in (height // 4, height // 2, 3 * height // 4):
            cv2.line(img, (0, y), (width, y), dark, 2)
    return img


def grille(seed: int, color=(0.08, 0.08, 0.09), height: int = 32, width: int = 96) -> np.ndarray:
    """Car radiator grille: horizontal bars or a mesh, with a round badge in the middle."""
    rng = np.random.default_rng(seed)
    img = _canvas(height, width, color)
    bar = _c(np.asarray(color) + 0.35)
    if rng.random() < 0.5:
        for y in range(3, height, 5):
            cv2.line(img, (2, y), (width - 3, y), bar, 1)
    else:
        for x in range(0, width, 6):
            cv2.line(img, (x, 0), (x + height, height), bar, 1)
            cv2.line(img, (x + height, 0), (x, height), bar, 1)
    cv2.circle(img, (width // 2, height // 2), height // 5, (200, 200, 205), -1, cv2.LINE_AA)
    return img


def hubcap(seed: int, color=(0.75, 0.75, 0.78), size: int = 64) -> np.ndarray:
    """A wheel's face: a metal disc with 5 to 10 spokes (dark gaps between them) and a centre badge."""
    rng = np.random.default_rng(seed)
    img = _canvas(size, size, (0.05, 0.05, 0.05))
    c, r = size // 2, size // 2 - 1
    cv2.circle(img, (c, c), r, _c(color), -1, cv2.LINE_AA)
    n = int(rng.integers(5, 11))
    gap = _c(np.asarray(color) * 0.15)
    phase = rng.uniform(0, 2 * np.pi)
    for k in range(n):
        a = phase + 2 * np.pi * (k + 0.5) / n
        pts = []
        for rad, da in (
            (0.35, -0.25),
            (0.85, -0.5 * np.pi / n),
            (0.85, 0.5 * np.pi / n),
            (0.35, 0.25),
        ):
            pts.append([c + rad * r * np.cos(a + da * 0.6), c + rad * r * np.sin(a + da * 0.6)])
        cv2.fillPoly(img, [np.asarray(pts, np.int32)], gap, cv2.LINE_AA)
    cv2.circle(img, (c, c), int(0.92 * r), _c(np.asarray(color) * 0.6), 1, cv2.LINE_AA)
    cv2.circle(img, (c, c), max(2, r // 6), _c(rng.random(3) * 0.5 + 0.3), -1, cv2.LINE_AA)
    return img


def license_plate(seed: int, height: int = 24, width: int = 96) -> np.ndarray:
    """A licence plate: dark letters on a light background with a border."""
    rng = np.random.default_rng(seed)
    bg = (0.95, 0.95, 0.92) if rng.random() < 0.6 else (0.95, 0.85, 0.2)
    img = _canvas(height, width, bg)
    cv2.rectangle(img, (1, 1), (width - 2, height - 2), (20, 20, 20), 1)
    letters = "".join(chr(int(c)) for c in rng.integers(65, 91, 3))
    digits = "".join(str(int(d)) for d in rng.integers(0, 10, 3))
    _put_text_fit(
        img,
        f"{letters} {digits}",
        (4, 3, width - 4, height - 3),
        (0.05, 0.05, 0.05),
        cv2.FONT_HERSHEY_DUPLEX,
        1,
    )
    return img


def mouse_top(seed: int, body, height: int = 64, width: int = 128) -> np.ndarray:
    """Top of a computer mouse (front of the mouse at the image's right): button split and a logo.

    Mapped along the mouse's length (u from back to front) and width (v from right to left).
    """
    rng = np.random.default_rng(seed)
    img = plastic(int(rng.integers(2**31)), body, height, width)
    dark = _c(np.asarray(body) * 0.35)
    x_split = int(width * rng.uniform(0.5, 0.62))
    cv2.line(img, (x_split, height // 5), (x_split, 4 * height // 5), dark, 2)  # buttons end here
    cv2.line(img, (x_split, height // 2), (width, height // 2), dark, 2)  # left/right buttons
    cv2.line(img, (x_split, height // 5), (width, height // 6), dark, 1)
    cv2.line(img, (x_split, 4 * height // 5), (width, 5 * height // 6), dark, 1)
    if rng.random() < 0.7:
        bx = int(width * 0.3)
        _put_text_fit(
            img,
            brand_name(int(rng.integers(2**31)), 2),
            (bx - 18, height // 2 - 6, bx + 18, height // 2 + 6),
            np.asarray(body) * 0.5 + 0.4,
            cv2.FONT_HERSHEY_SIMPLEX,
            1,
        )
    return img


def face(
    seed: int, skin, hair, hair_style: str = "short", height: int = 128, width: int = 256
) -> np.ndarray:
    """Equirectangular head texture: the face at the image's centre column, hair around the back.

    Mapped onto a head whose texture coordinate ``u = 0.5`` looks along +x (the face) and ``u = 0``,
    ``u = 1`` at the back; ``v`` runs from the chin (bottom) to the crown (top).

    Parameters
    ----------
    seed : int
    skin, hair : RGB in [0, 1]
    hair_style : {"short", "long", "bald"}
    """
    if hair_style not in ("short", "long", "bald"):
        raise ValueError(f"unknown hair style {hair_style!r}")
    rng = np.random.default_rng(seed)
    noise = value_noise(int(rng.integers(2**31)), height, width, cells=8, octaves=2)
    img = _tint(noise, skin, 0.08)
    H, W = height, width
    cx = W // 2

    def row(v):  # texture v (0 bottom .. 1 top) -> image row
        return int(round((1.0 - v) * (H - 1)))

    du = lambda u: int(round(u * W))  # noqa: E731 (a width in u to pixels)
    # hair: covers the crown and the back, with a hairline above the forehead
    if hair_style != "bald":
        hairline = rng.uniform(0.76, 0.84)
        hair_img = _tint(
            value_noise(int(rng.integers(2**31)), H, W, cells=16, octaves=2), hair, 0.35
        )
        uu = np.linspace(0, 1, W)[None, :]
        vv = np.linspace(1, 0, H)[:, None]
        side = np.abs(uu - 0.5)  # 0 at the face, 0.5 at the back
        bottom = 0.42 if hair_style == "short" else 0.05  # how low the hair reaches at the back
        # hairline descends from the forehead to the nape around the sides
        limit = np.where(
            side < 0.13,
            hairline,
            hairline - (hairline - bottom) * np.clip((side - 0.13) / 0.17, 0, 1),
        )
        mask = vv > limit
        img[mask] = hair_img[mask]
    else:
        # a bald head: slightly shinier skin on the crown
        vv = np.linspace(1, 0, H)[:, None]
        img = _to_uint8(img / 255.0 * (1.0 + 0.08 * np.clip(vv - 0.7, 0, 1))[..., None])
    skin_dark = np.asarray(skin) * 0.6
    # eyes
    eye_v, eye_du, eye_w = (
        rng.uniform(0.55, 0.62),
        rng.uniform(0.05, 0.065),
        rng.uniform(0.022, 0.03),
    )
    iris = (np.array([0.3, 0.2, 0.1]), np.array([0.2, 0.35, 0.6]), np.array([0.25, 0.4, 0.25]))[
        int(rng.integers(3))
    ]
    for sgn in (-1, 1):
        ex, ey = cx + sgn * du(eye_du), row(eye_v)
        cv2.ellipse(
            img,
            (ex, ey),
            (du(eye_w), max(2, du(eye_w) // 2)),
            0,
            0,
            360,
            (245, 245, 240),
            -1,
            cv2.LINE_AA,
        )
        cv2.circle(img, (ex, ey), max(2, du(eye_w) // 2), _c(iris), -1, cv2.LINE_AA)
        cv2.circle(img, (ex, ey), max(1, du(eye_w) // 4), (10, 10, 10), -1, cv2.LINE_AA)
        brow_c = _c(np.asarray(hair) * 0.8) if hair_style != "bald" else _c(skin_dark)
        by = row(eye_v + rng.uniform(0.07, 0.09))
        cv2.line(
            img,
            (ex - du(eye_w) - 1, by + 1),
            (ex + du(eye_w) + 1, by - 1 if sgn < 0 else by + 1),
            brow_c,
            max(2, H // 50),
            cv2.LINE_AA,
        )
    # nose shading and nostrils
    nose_v = rng.uniform(0.42, 0.46)
    cv2.line(
        img, (cx - 2, row(eye_v - 0.02)), (cx - 3, row(nose_v)), _c(skin_dark * 1.3), 1, cv2.LINE_AA
    )
    for sgn in (-1, 1):
        cv2.circle(
            img, (cx + sgn * du(0.012), row(nose_v)), max(1, H // 90), _c(skin_dark * 0.7), -1
        )
    # mouth
    mouth_v, mouth_w = rng.uniform(0.3, 0.35), rng.uniform(0.03, 0.045)
    lip = _c(np.asarray(skin) * np.array([0.85, 0.5, 0.5]))
    smile = int(rng.integers(0, 4))
    cv2.ellipse(
        img,
        (cx, row(mouth_v) - smile),
        (du(mouth_w), max(2, smile + 2)),
        0,
        0,
        180,
        lip,
        2,
        cv2.LINE_AA,
    )
    # ears (at u = 0.25 and 0.75, i.e. -y and +y)
    for u in (0.25, 0.75):
        cv2.ellipse(
            img,
            (du(u), row(0.5)),
            (du(0.02), H // 12),
            0,
            0,
            360,
            _c(skin_dark * 1.25),
            2,
            cv2.LINE_AA,
        )
    return img


def shoe_upper(
    seed: int, base, accent, style: str = "sneaker", height: int = 64, width: int = 128
) -> np.ndarray:
    """Texture of a shoe's upper.

    Mapped with u along the shoe (heel at u = 0, toe at u = 1) and v around its cross-section (right
    edge of the sole at v = 0, over the top at v = 0.5, left edge at v = 1). Draws the dark foot opening near the heel, laces over the instep (sneakers and boots), stitching
    along the toe cap and a side stripe or logo.
    """
    if style not in ("sneaker", "boot", "heel", "loafer"):
        raise ValueError(f"unknown shoe style {style!r}")
    rng = np.random.default_rng(seed)
    if style == "boot":
        img = _tint(value_noise(int(rng.integers(2**31)), height, width, cells=10), base, 0.3)
    else:
        img = plastic(int(rng.integers(2**31)), base, height, width)
    H, W = height, width
    mid = H // 2
    acc = _c(accent)
    # toe cap seam
    cv2.ellipse(
        img, (int(0.92 * W), mid), (int(0.14 * W), int(0.45 * H)), 0, 90, 270, acc, 1, cv2.LINE_AA
    )
    if style in ("sneaker", "boot"):
        x0, x1 = int(0.38 * W), int(0.7 * W)
        cv2.rectangle(
            img, (x0, mid - H // 14), (x1, mid + H // 14), _c(np.asarray(base) * 0.55), -1
        )
        for x in range(x0 + 3, x1, max(4, (x1 - x0) // 6)):
            cv2.line(img, (x, mid - H // 9), (x + 3, mid + H // 9), (235, 235, 230), 2)
            cv2.line(img, (x + 3, mid - H // 9), (x, mid + H // 9), (235, 235, 230), 2)
    if style == "sneaker":  # side stripes on both sides
        for v0 in (0.2, 0.8):
            y = int((1 - v0) * H)
            pts = np.array(
                [[int(0.3 * W), y + 6], [int(0.55 * W), y - 4], [int(0.75 * W), y + 2]], np.int32
            )
            cv2.polylines(img, [pts], False, acc, 3, cv2.LINE_AA)
    # stitching along the sole line
    for y in (2, H - 3):
        for x in range(0, W, 6):
            cv2.line(img, (x, y), (x + 3, y), _c(np.asarray(base) * 0.6 + 0.3), 1)
    return img
