"""Body-shaped categories: head (a bust) and shoe.

A head's face looks along +x (eyes, nose and mouth only there; hair or a bare crown behind); a shoe's
toe points to +x and its heel to -x, with a low rounded toe and a high heel counter and foot opening at
the back, so the front and back views differ clearly.
"""

from __future__ import annotations

import numpy as np

from scrppl.datasets.synthetic import textures as tx
from scrppl.datasets.synthetic.categories import _mesh as m
from scrppl.datasets.synthetic.categories.devices import _mean_color, _pick, _seed
from scrppl.datasets.synthetic.shapes import Part

__all__ = ["head", "shoe"]

_SKIN = (
    (0.96, 0.8, 0.69),
    (0.9, 0.72, 0.58),
    (0.78, 0.57, 0.42),
    (0.6, 0.42, 0.3),
    (0.42, 0.28, 0.2),
    (0.93, 0.9, 0.86),  # a white mannequin
)
_HAIR = (
    (0.08, 0.06, 0.05),
    (0.3, 0.18, 0.08),
    (0.55, 0.35, 0.15),
    (0.85, 0.7, 0.4),
    (0.6, 0.6, 0.6),
    (0.5, 0.15, 0.05),
)
_CLOTH = (
    (0.15, 0.2, 0.4),
    (0.5, 0.1, 0.1),
    (0.2, 0.2, 0.2),
    (0.8, 0.8, 0.78),
    (0.25, 0.4, 0.25),
    (0.55, 0.45, 0.3),
)


def head(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A head and shoulders bust: face texture and nose on +x, ears on +-y, hair behind.

    Proportions (head width, height and depth, jaw, nose), skin tone, hair colour and style, and
    the clothing vary with the seed.
    """
    ax = rng.uniform(0.095, 0.11)  # half depth (front-back)
    ay = ax * rng.uniform(0.75, 0.88)  # half width
    az = ax * rng.uniform(1.15, 1.32)  # half height
    jaw = rng.uniform(0.7, 0.85)  # width of the jaw relative to the skull
    nose_len = rng.uniform(0.018, 0.03)
    neck_h = rng.uniform(0.05, 0.08)
    shoulder_h = rng.uniform(0.09, 0.13)
    shoulder_w = rng.uniform(0.2, 0.24)
    skin = _pick(rng, _SKIN)
    hair = _pick(rng, _HAIR)
    style = _pick(rng, ("short", "short", "long", "bald"))
    # the skull: an ellipsoid narrowed towards the jaw, with a nose bump at the front (+x)
    nu, nv = 36, 20
    phi = np.linspace(-np.pi, np.pi, nu, endpoint=False)
    theta = np.linspace(-0.5 * np.pi, 0.5 * np.pi, nv)
    P, T = np.meshgrid(phi, theta, indexing="ij")
    narrow = 1.0 - (1.0 - jaw) * np.clip(np.sin(-T), 0.0, 1.0) ** 1.5
    X = ax * np.cos(T) * np.cos(P) * narrow
    Y = ay * np.cos(T) * np.sin(P) * narrow
    Z = az * np.sin(T)
    # nose: a ridge at phi = 0 between the eyes and the mouth (texture v about 0.45)
    t_nose = np.pi * (0.45 - 0.5)
    bump = np.exp(-((P / 0.14) ** 2) - ((T - t_nose) / 0.16) ** 2)
    X = X + nose_len * bump
    # flatten the face slightly (a less spherical front)
    X = np.where(X > 0.8 * ax, 0.8 * ax + 0.7 * (X - 0.8 * ax), X)
    z_head = shoulder_h + neck_h + 0.8 * az
    pts = np.stack([X, Y, Z + z_head], -1)
    skull, uv = m.grid_surface(pts, close_u=True)
    face_tex = tx.face(tex_seed, skin, hair, style, 128, 256)
    parts = [
        Part(
            skull,
            _mean_color(face_tex),
            texture=face_tex,
            uv=uv,
            specular=0.25,
            smooth=True,
            name="face",
        )
    ]
    # ears at +-y
    ears = []
    for sgn in (-1, 1):
        ear, _ = m.ellipsoid((0.0, sgn * ay * 0.98, z_head + 0.0), (0.014, 0.01, 0.028), 10, 6)
        ears.append(ear)
    neck, _ = m.lathe(
        np.array(
            [[0.045, shoulder_h - 0.01], [0.042, shoulder_h + neck_h], [0.04, z_head - 0.3 * az]]
        )
        * [rng.uniform(0.9, 1.1), 1],
        18,
    )
    parts.append(
        Part(
            m.concat(ears + [neck]),
            tuple(np.asarray(skin) * 0.95),
            specular=0.2,
            smooth=True,
            name="skin",
        )
    )
    if style != "bald":  # hair volume: a shell around the skull, from the hairline to the nape
        cap_nu, cap_nv = 28, 7
        cphi = np.linspace(-np.pi, np.pi, cap_nu, endpoint=False)
        hairline = np.deg2rad(rng.uniform(45.0, 55.0))
        nape = np.deg2rad(rng.uniform(-30.0, -10.0) if style == "short" else -40.0)
        low = hairline - (hairline - nape) * (np.abs(cphi) / np.pi) ** 0.8  # (nu,)
        frac = np.linspace(0.0, 1.0, cap_nv)
        CT = low[:, None] + (0.5 * np.pi - low[:, None]) * frac[None, :]
        CP = np.broadcast_to(cphi[:, None], CT.shape)
        bulk = rng.uniform(1.05, 1.12)  # a concentric, larger ellipsoid never cuts the skull
        cap_pts = np.stack(
            [
                ax * bulk * np.cos(CT) * np.cos(CP),
                ay * bulk * np.cos(CT) * np.sin(CP),
                z_head + az * bulk * np.sin(CT),
            ],
            -1,
        )
        cap, cap_uv = m.grid_surface(cap_pts, close_u=True)
        hair_tex = tx.fabric(_seed(rng), hair, 32, 64)
        parts.append(
            Part(
                cap,
                _mean_color(hair_tex),
                texture=hair_tex,
                uv=cap_uv,
                specular=0.3,
                smooth=True,
                name="hair_cap",
            )
        )
    if style == "long":  # hair falling behind the head onto the shoulders
        hair_mesh = m.loft(
            m.superellipse(0.04, ay * 0.95, 16, 2.5),
            [0.9, 1.0, 1.0, 0.85],
            [shoulder_h + 0.01, shoulder_h + 0.05, z_head - 0.2 * az, z_head + 0.3 * az],
            offsets=np.array([[-0.6 * ax, 0], [-0.7 * ax, 0], [-0.75 * ax, 0], [-0.55 * ax, 0]]),
        )
        parts.append(Part(hair_mesh, hair, specular=0.3, smooth=True, name="hair"))
    # shoulders and chest: a lofted superellipse, wide along y
    levels = np.linspace(0.0, 1.0, 6)
    sc = np.column_stack(
        [
            1.0 - 0.15 * levels**2,
            np.sqrt(np.clip(1.0 - levels**2.5, 0.0, 1.0)) * 0.8 + 0.2 * (1 - levels),
        ]
    )
    sc[-1] = [0.5, 0.28]
    torso = m.loft(
        m.superellipse(0.08 * rng.uniform(0.9, 1.1), shoulder_w, 24, 3.0), sc, levels * shoulder_h
    )
    parts.append(Part(torso, _pick(rng, _CLOTH), specular=0.15, smooth=True, name="torso"))
    if rng.random() < 0.25:  # glasses
        lens = [
            m.polyline_tube(
                np.array(
                    [
                        [
                            0.83 * ax + nose_len * 0.5,
                            sgn * ay * 0.33 + 0.022 * np.cos(a),
                            z_head + 0.17 * az + 0.015 * np.sin(a),
                        ]
                        for a in np.linspace(0, 2 * np.pi, 12)
                    ]
                ),
                0.003,
                4,
            )
            for sgn in (-1, 1)
        ]
        arms = [
            m.cylinder(
                (0.8 * ax, sgn * ay * 0.6, z_head + 0.17 * az),
                (0.0, sgn * ay * 1.02, z_head + 0.17 * az),
                0.003,
                4,
            )
            for sgn in (-1, 1)
        ]
        parts.append(Part(m.concat(lens + arms), (0.05, 0.05, 0.05), specular=0.7, name="glasses"))
    return parts


def _shoe_halfwidth(s: np.ndarray, W: float, toe: str) -> np.ndarray:
    """Half width of the footprint along the shoe, s in [0, 1] from heel to toe."""
    ball = np.exp(-(((s - 0.68) / 0.3) ** 2))
    heel = 0.72 + 0.1 * np.exp(-(((s - 0.12) / 0.1) ** 2))
    w = 0.5 * W * np.where(s < 0.68, heel + (1 - heel) * ball, ball * 0 + 1.0)
    tip = {"round": 0.35, "pointed": 1.0, "square": 0.15}[toe]
    end = np.clip((s - 0.72) / 0.28, 0.0, 1.0)
    w = w * (1.0 - end ** (2.0 - tip)) ** (0.5 + 0.5 * tip)
    w = w * np.clip(s / 0.06, 0.0, 1.0) ** 0.5
    return np.maximum(w, 1e-4)


def shoe(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A shoe: sneaker, boot, high heel or loafer; toe at +x, heel at -x.

    The upper is a lofted surface over the footprint (low at the toe, rising to the collar at the
    back) with a dark foot opening near the heel; the sole follows the footprint; boots add a shaft,
    heels raise the back on a heel block.
    """
    style = _pick(rng, ("sneaker", "sneaker", "boot", "heel", "loafer"))
    L = rng.uniform(0.26, 0.3)
    W = L * rng.uniform(0.34, 0.4) * (0.85 if style == "heel" else 1.0)
    toe = (
        "pointed"
        if style == "heel" and rng.random() < 0.7
        else _pick(rng, ("round", "round", "square"))
    )
    sole_t = {
        "sneaker": rng.uniform(0.02, 0.03),
        "boot": rng.uniform(0.02, 0.03),
        "heel": 0.008,
        "loafer": 0.012,
    }[style]
    heel_rise = rng.uniform(0.06, 0.09) if style == "heel" else 0.0
    collar = {"sneaker": 0.075, "boot": 0.09, "heel": 0.04, "loafer": 0.05}[style] * rng.uniform(
        0.9, 1.15
    )
    instep = collar * (0.85 if style != "heel" else 0.8)
    toe_h = rng.uniform(0.035, 0.05) * (0.7 if style == "heel" else 1.0)
    base = _pick(
        rng,
        (
            (0.9, 0.9, 0.9),
            (0.08, 0.08, 0.08),
            (0.35, 0.2, 0.1),
            (0.6, 0.1, 0.1),
            (0.15, 0.25, 0.55),
            (0.55, 0.5, 0.45),
            (0.75, 0.6, 0.4),
        ),
    )
    accent = _pick(
        rng,
        ((0.9, 0.1, 0.1), (0.1, 0.3, 0.9), (0.95, 0.95, 0.95), (0.1, 0.1, 0.1), (0.95, 0.7, 0.1)),
    )
    sole_color = (
        _pick(rng, ((0.95, 0.95, 0.93), (0.1, 0.1, 0.1), (0.5, 0.35, 0.2)))
        if style != "heel"
        else (0.1, 0.1, 0.1)
    )
    nu, nv = 26, 13
    s = np.linspace(0.0, 1.0, nu)
    x = -0.5 * L + L * s
    half = _shoe_halfwidth(s, W, toe)
    # sole bottom height along the shoe: flat, or raised at the back for a heel
    lift = heel_rise * np.clip((0.62 - s) / 0.4, 0.0, 1.0) ** 0.8
    sole_top = lift + sole_t
    # upper height profile: collar at the heel, dipping at the opening, instep, low toe
    h = np.interp(
        s,
        [0.0, 0.08, 0.4, 0.6, 0.85, 1.0],
        [collar, collar, instep, 0.8 * instep, toe_h, 0.5 * toe_h],
    )
    h = h * np.clip(1.0 - ((s - 1.0) / 0.05) ** 2 * (s > 0.95), 0.2, 1.0)
    t = np.linspace(0.0, np.pi, nv)
    Y = -half[:, None] * np.cos(t)[None, :] * 0.98
    Z = sole_top[:, None] + h[:, None] * np.sin(t)[None, :] ** 0.6
    X = np.broadcast_to(x[:, None], Y.shape)
    upper, uv = m.grid_surface(np.stack([X, Y, Z], -1))
    up_tex = tx.shoe_upper(tex_seed, base, accent, style)
    parts = [
        Part(
            upper,
            _mean_color(up_tex),
            texture=up_tex,
            uv=uv,
            specular=0.35 if style != "heel" else 0.8,
            smooth=True,
            name="upper",
        )
    ]
    # the foot opening: a dark ellipse just above the upper at the back
    i0, i1 = np.searchsorted(s, 0.1), np.searchsorted(s, 0.38)
    xo = 0.5 * (x[i0] + x[i1])
    zo = sole_top[i0:i1].mean() + 0.5 * (collar + instep) * 0.97
    hole = m.extrude(m.superellipse(0.5 * (x[i1] - x[i0]), 0.36 * W, 20, 2.2), 0.0, 0.004)
    tilt = np.arctan2(collar - instep, x[i1] - x[i0])
    hole = m.translate(m.rotate(hole, tilt, (0, 1, 0)), (xo, 0.0, zo))
    parts.append(Part(hole, (0.05, 0.04, 0.04), specular=0.0, name="opening"))
    # sole: footprint outline, lofted so it follows the heel lift
    foot = np.concatenate(
        [np.column_stack([x, -half]), np.column_stack([x[::-1], half[::-1]])[1:-1]]
    )
    if style == "heel":
        # a thin sole under the front, raised along the arch, and a heel block at the back
        front = s > 0.55
        fo = np.concatenate(
            [
                np.column_stack([x[front], -half[front]]),
                np.column_stack([x[front][::-1], half[front][::-1]])[1:-1],
            ]
        )
        sole = [m.extrude(fo, 0.0, sole_t)]
        arch = m.polyline_tube(
            np.column_stack([x[3:17], np.zeros(14), sole_top[3:17] - 0.004]), 0.006, 6
        )
        heel_w = rng.uniform(0.012, 0.03)  # stiletto to block heel
        heel_block = m.loft(
            m.rounded_rect(0.035, 0.04, 0.012, 4),
            [heel_w / 0.035, 1.0],
            [0.0, heel_rise + 0.001],
            offsets=np.array([[x[2] + 0.012, 0.0], [x[2] + 0.018, 0.0]]),
        )
        sole += [arch, heel_block]
        parts.append(Part(m.concat(sole), sole_color, specular=0.6, name="sole"))
    else:
        sole = m.extrude(foot * np.array([1.0, 1.03]), 0.0, sole_t)
        sole_tex = tx.tread(_seed(rng), 32, 256)
        vs = np.asarray(sole.vertices)
        suv = np.column_stack([(vs[:, 0] - x[0]) / L, vs[:, 2] / sole_t]).clip(0, 1)
        parts.append(
            Part(
                sole,
                sole_color,
                texture=(sole_tex.astype(float) * 0.3 + 255 * 0.7 * np.asarray(sole_color)).astype(
                    np.uint8
                ),
                uv=suv,
                specular=0.2,
                name="sole",
            )
        )
        if style == "sneaker":  # a heel tab and a toe bumper in the accent colour
            tab = m.box((0.012, 0.03, 0.035), (x[0] - 0.001, 0.0, sole_top[0] + collar - 0.01))
            parts.append(Part(tab, accent, specular=0.3, name="heel_tab"))
    if style == "boot":  # a shaft rising from the collar
        shaft_h = rng.uniform(0.06, 0.12)
        shaft = m.loft(
            m.superellipse(0.34 * L * 0.5, 0.42 * W, 18, 2.2),
            [1.0, 1.0, 1.02],
            [collar * 0.5, collar + 0.5 * shaft_h, collar + shaft_h],
            offsets=np.array([[x[6], 0.0], [x[6] - 0.005, 0.0], [x[6] - 0.01, 0.0]]),
            cap_top=False,
        )
        rim = m.loft(
            m.superellipse(0.34 * L * 0.5, 0.42 * W, 18, 2.2),
            [0.92, 0.92],
            [collar + shaft_h - 0.01, collar + shaft_h + 0.001],
            offsets=np.array([[x[6] - 0.01, 0.0], [x[6] - 0.01, 0.0]]),
        )
        parts.append(Part(shaft, base, specular=0.35, smooth=True, name="shaft"))
        parts.append(Part(rim, (0.05, 0.04, 0.04), name="shaft_opening"))
    return parts
