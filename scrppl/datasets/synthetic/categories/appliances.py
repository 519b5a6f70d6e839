"""Small appliances: iron, toaster, stapler.

Each has a one-sided feature that breaks its left-right symmetry or a front unlike its back: the
iron's pointed nose (+x) and its cord leaving to the left (+y); the toaster's lever, dial and buttons
on its left end (+y) and its brand label on the front; the stapler's nose and anvil at the front and
its hinge at the back.
"""

from __future__ import annotations

import numpy as np

from scrppl.datasets.synthetic import textures as tx
from scrppl.datasets.synthetic.categories import _mesh as m
from scrppl.datasets.synthetic.categories.devices import _mean_color, _pick, _seed
from scrppl.datasets.synthetic.shapes import Part

__all__ = ["iron", "stapler", "toaster"]

_APPLIANCE_COLORS = (
    (0.85, 0.85, 0.85),
    (0.15, 0.35, 0.7),
    (0.55, 0.15, 0.45),
    (0.1, 0.1, 0.1),
    (0.75, 0.1, 0.1),
    (0.2, 0.6, 0.6),
    (0.95, 0.95, 0.93),
    (0.9, 0.55, 0.15),
    (0.3, 0.3, 0.33),
)
_METAL = (0.78, 0.79, 0.8)


def _iron_outline(L: float, W: float, n: int, point: float) -> np.ndarray:
    """Plan view of a soleplate: flat, rounded back at -x, pointed nose at +x (counter-clockwise)."""
    s = np.linspace(0.0, 1.0, n)
    x = -0.5 * L + L * s
    half = (
        0.5
        * W
        * np.minimum(1.0, 6.0 * s + 0.35) ** 0.5
        * (1.0 - np.clip((s - 0.35) / 0.65, 0, 1) ** point)
    )
    half[-1] = 0.0
    right = np.column_stack([x, -half])
    left = np.column_stack([x[::-1], half[::-1]])
    return np.concatenate([right, left[1:-1]])


def iron(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A clothes iron: pointed soleplate, domed body, a handle on top and the cord leaving to +y."""
    L = rng.uniform(0.24, 0.29)
    W = L * rng.uniform(0.4, 0.5)
    sole_t = rng.uniform(0.008, 0.015)
    H = L * rng.uniform(0.22, 0.32)
    outline = _iron_outline(L, W, 18, rng.uniform(1.4, 2.2))
    body_color = _pick(rng, _APPLIANCE_COLORS)
    accent = _pick(rng, _APPLIANCE_COLORS)
    sole = m.extrude(outline, 0.0, sole_t)
    k = 6
    th = np.linspace(0.0, 0.5 * np.pi, k)
    scales = np.cos(th) ** 0.6 * 0.97
    scales[-1] = rng.uniform(0.25, 0.4)
    zs = sole_t + H * np.sin(th)
    offsets = np.column_stack([-(np.linspace(0, 0.12 * L, k) ** 1.0), np.zeros(k)])
    body = m.loft(outline, scales, zs, offsets, cap_bottom=True, cap_top=True)
    # handle: from the rear of the body up, forward, and down onto the front of the body
    closed = rng.random() < 0.7
    hz = sole_t + H + rng.uniform(0.06, 0.09)
    hx0, hx1 = -0.36 * L, rng.uniform(0.12, 0.22) * L
    handle_pts = [
        [hx1 + 0.05 * L, 0, sole_t + 0.6 * H],
        [hx1, 0, hz],
        [0.5 * (hx0 + hx1), 0, hz + 0.005],
        [hx0, 0, hz],
    ]
    if closed:
        handle_pts.append([hx0 - 0.02 * L, 0, sole_t + 0.75 * H])
    handle = m.polyline_tube(np.array(handle_pts), rng.uniform(0.012, 0.017), 8)
    # dial on top of the front of the body, tank window at the nose, buttons on the handle
    dial = m.cylinder(
        (0.05 * L, 0, sole_t + 0.8 * H), (0.05 * L, 0, sole_t + 0.8 * H + 0.012), 0.02, 14
    )
    tank, _ = m.ellipsoid((0.28 * L, 0, sole_t + 0.35 * H), (0.15 * L, 0.28 * W, 0.3 * H), 12, 6)
    buttons = [
        m.box((0.012, 0.012, 0.008), (hx1 - 0.01 - 0.018 * i, 0, hz + 0.014))
        for i in range(int(rng.integers(1, 3)))
    ]
    # cord: leaves the back of the handle, then bends to the left (+y) and falls to the table
    side = 1.0
    c0 = np.array([hx0 - 0.03 * L, 0.0, sole_t + 0.75 * H if closed else hz])
    t = np.linspace(0.0, 1.0, 12)
    reach = rng.uniform(0.25, 0.4) * L
    cord_pts = np.column_stack(
        [
            c0[0] - 0.25 * L * np.sin(0.5 * np.pi * t),
            side * reach * t**1.5,
            0.006 + (c0[2] - 0.006) * (1 - t) ** 2,
        ]
    )
    strain = m.cylinder(c0 + np.array([0.01, 0, 0]), c0 - np.array([0.03, 0, 0]), 0.012, 8)
    cord = m.polyline_tube(cord_pts, 0.0045, 6)
    label_tex = tx.label(
        tex_seed, body_color, tuple(1.0 - np.asarray(body_color)), 32, 96, logo=False
    )
    lq, luv = m.quad((-0.05 * L, 0.5 * W * 0.93, sole_t + 0.35 * H), "+y", 0.3 * L, 0.1 * L)
    return [
        Part(sole, _METAL, specular=0.95, name="soleplate"),
        Part(body, body_color, specular=0.6, smooth=True, name="body"),
        Part(m.concat([handle, dial] + buttons), accent, specular=0.5, smooth=True, name="handle"),
        Part(tank, (0.6, 0.8, 0.95), specular=0.9, smooth=True, name="tank"),
        Part(
            m.concat([strain, cord]),
            (0.12, 0.12, 0.12) if rng.random() < 0.6 else (0.9, 0.9, 0.9),
            specular=0.2,
            name="cord",
        ),
        Part(lq, _mean_color(label_tex), texture=label_tex, uv=luv, name="label"),
    ]


def toaster(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A toaster: a rounded box with slots on top and its controls on one end.

    The brand label is on the front (+x); the lever, dial and buttons on the left end (+y); the cord
    leaves the back.
    """
    n_slots = int(_pick(rng, (2, 2, 4)))
    D = rng.uniform(0.15, 0.2) * (
        1.5 if n_slots == 4 and rng.random() < 0.5 else 1.0
    )  # depth along x
    Wt = rng.uniform(0.26, 0.34)  # length along y
    H = rng.uniform(0.18, 0.22)
    corner = rng.uniform(0.01, 0.06)
    plan = m.rounded_rect(D, Wt, corner, 5)
    round_top = rng.uniform(0.0, 0.03)
    zs = np.array([0.012, H - round_top, H - 0.4 * round_top, H])
    scales = np.array([1.0, 1.0, 1.0 - 0.08 * (round_top > 0), 1.0 - 0.18 * (round_top > 0)])
    body = m.loft(plan, scales, zs)
    chrome = rng.random() < 0.4
    color = _METAL if chrome else _pick(rng, _APPLIANCE_COLORS)
    trim = _pick(rng, ((0.1, 0.1, 0.1), (0.3, 0.3, 0.32), _METAL))
    feet = [
        m.box((0.025, 0.03, 0.012), (sx * (0.5 * D - 0.02), sy * (0.5 * Wt - 0.03), 0.006))
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    # slots (dark), along y, spread over x
    slot_len = 0.62 * Wt
    slot_w = rng.uniform(0.018, 0.028)
    rows = np.linspace(-0.22 * D, 0.22 * D, n_slots if D < 0.25 else 2)
    slots = []
    ys = [0.0] if len(rows) == n_slots else [-0.25 * Wt, 0.25 * Wt]
    for x in rows:
        for y in ys:
            length = slot_len if len(ys) == 1 else 0.4 * Wt
            slots.append(m.box((slot_w, length, 0.004), (x, y - 0.04 * Wt, H + 0.001)))
    # controls on the +y end: lever slot, lever knob, dial, buttons
    y_end = 0.5 * Wt
    lever_z = rng.uniform(0.45, 0.75) * H
    controls = [
        m.box((0.012, 0.004, 0.6 * H), (0.0, y_end + 0.001, 0.5 * H)),  # the lever's slot
    ]
    knob = m.box((0.05, 0.035, 0.025), (0.0, y_end + 0.02, lever_z))
    dial = m.cylinder((0.25 * D, y_end, 0.3 * H), (0.25 * D, y_end + 0.015, 0.3 * H), 0.018, 16)
    buttons = [
        m.box((0.018, 0.008, 0.012), (-0.25 * D, y_end + 0.003, (0.2 + 0.12 * i) * H))
        for i in range(int(rng.integers(1, 4)))
    ]
    # cord out of the back (-x), lying on the table
    t = np.linspace(0, 1, 10)
    cord = m.polyline_tube(
        np.column_stack(
            [
                -0.5 * D - 0.12 * D * np.sin(np.pi * t * 0.5) - 0.001,
                -0.3 * Wt + 0.25 * Wt * t,
                0.03 * (1 - t) ** 2 + 0.005,
            ]
        ),
        0.004,
        6,
    )
    label_tex = tx.label(
        tex_seed, color, (0.1, 0.1, 0.1) if np.mean(color) > 0.5 else (0.95, 0.95, 0.95), 40, 160
    )
    lq, luv = m.quad((0.5 * D + 0.0015, 0.0, 0.3 * H), "+x", 0.55 * Wt, 0.55 * Wt * 40 / 160)
    if chrome:
        metal_tex = tx.brushed_metal(_seed(rng), color)
        v = np.asarray(body.vertices)
        # cylindrical projection: u around the body, v up
        ang = (np.arctan2(v[:, 1], v[:, 0]) + np.pi) / (2 * np.pi)
        body_part = Part(
            body,
            _mean_color(metal_tex),
            texture=metal_tex,
            uv=np.column_stack([ang, v[:, 2] / H]).clip(0, 1),
            specular=0.9,
            smooth=False,
            name="body",
        )
    else:
        body_part = Part(body, color, specular=0.5, name="body")
    return [
        body_part,
        Part(m.concat(slots), (0.04, 0.04, 0.04), specular=0.1, name="slots"),
        Part(m.concat(feet + controls + [cord]), trim, specular=0.4, name="trim"),
        Part(
            m.concat([knob, dial] + buttons),
            _pick(rng, ((0.1, 0.1, 0.1), (0.85, 0.85, 0.85), (0.8, 0.2, 0.1))),
            specular=0.6,
            name="lever",
        ),
        Part(lq, _mean_color(label_tex), texture=label_tex, uv=luv, name="label"),
    ]


def stapler(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A desk stapler: base plate, arched top arm hinged at the back (-x), nose and anvil at the front."""
    L = rng.uniform(0.16, 0.2)
    Wb = L * rng.uniform(0.2, 0.27)
    base_t = rng.uniform(0.008, 0.012)
    base_front = rng.uniform(0.012, 0.03)
    arm_h = rng.uniform(0.035, 0.05)
    arch = rng.uniform(0.0, 0.012)
    color = _pick(
        rng,
        (
            (0.1, 0.1, 0.1),
            (0.75, 0.1, 0.1),
            (0.15, 0.3, 0.7),
            (0.4, 0.4, 0.42),
            (0.1, 0.5, 0.3),
            (0.9, 0.9, 0.9),
        ),
    )
    base_color = _pick(rng, ((0.08, 0.08, 0.08), color))
    # base plate: rounded at the front
    plan = m.rounded_rect(L + base_front, Wb, 0.45 * Wb, 6) + np.array([0.5 * base_front, 0.0])
    base = m.extrude(plan, 0.0, base_t)
    anvil = m.box(
        (0.03 + base_front, 0.45 * Wb, 0.002),
        (0.5 * L - 0.015 + 0.5 * base_front, 0.0, base_t + 0.001),
    )
    # top arm side profile: low at the hinge (back), arched, then a rounded nose at the front
    n = 14
    x = np.linspace(-0.5 * L, 0.5 * L - 0.01, n)
    s = (x - x[0]) / (x[-1] - x[0])
    rise = rng.uniform(0.45, 0.6)  # the arm climbs from the hinge to the head at the front
    top = base_t + 0.015 + arm_h * (1 - rise + rise * s**0.6) + arch * np.sin(np.pi * s)
    # polygon: along the bottom from the nose to the hinge, up, along the top to the nose
    bottom = [(0.5 * L - 0.004, base_t + 0.006), (-0.5 * L + 0.012, base_t + 0.012)]
    topline = list(zip(x, top, strict=True))
    profile = np.array(
        bottom + [(-0.5 * L, base_t + 0.02)] + topline[1:] + [(0.5 * L, 0.5 * (top[-1] + base_t))]
    )
    arm = m.extrude_profile_y(profile, 0.85 * Wb)
    # chrome top strip and the metal magazine under the arm
    front_half = slice(n // 2, n - 1)  # the metal cover runs over the front half of the arm
    strip_prof = np.array(
        list(zip(x[front_half], top[front_half] + 0.003, strict=True))
        + list(zip(x[front_half][::-1], top[front_half][::-1] - 0.004, strict=True))
    )
    strip = m.extrude_profile_y(strip_prof, 0.6 * Wb)
    nose_plate = m.box(
        (0.004, 0.6 * Wb, 0.5 * (top[-1] - base_t)),
        (0.5 * L + 0.001, 0.0, base_t + 0.006 + 0.25 * (top[-1] - base_t)),
    )
    magazine = m.box((0.85 * L, 0.6 * Wb, 0.012), (0.02 * L, 0.0, base_t + 0.012))
    hinge = m.cylinder(
        (-0.5 * L + 0.012, -0.45 * Wb, base_t + 0.014),
        (-0.5 * L + 0.012, 0.45 * Wb, base_t + 0.014),
        0.013,
        14,
    )
    label_tex = tx.label(
        tex_seed,
        color,
        (0.95, 0.95, 0.95) if np.mean(color) < 0.5 else (0.1, 0.1, 0.1),
        24,
        120,
        logo=rng.random() < 0.5,
    )
    i_mid = n // 2
    quads, uvs = [], []
    for sgn, normal in ((1, "+y"), (-1, "-y")):
        q, uv = m.quad(
            (x[i_mid] - 0.05 * L, sgn * (0.425 * Wb + 0.0015), 0.5 * (top[i_mid] + base_t + 0.015)),
            normal,
            0.4 * L,
            0.4 * L * 24 / 120,
        )
        quads.append(q)
        uvs.append(uv)
    return [
        Part(base, base_color, specular=0.3, name="base"),
        Part(m.concat([anvil, magazine]), _METAL, specular=0.9, name="magazine"),
        Part(arm, color, specular=0.6, name="arm"),
        Part(
            m.concat([strip, hinge, nose_plate]),
            _METAL if rng.random() < 0.6 else (0.15, 0.15, 0.15),
            specular=0.9,
            name="cover",
        ),
        Part(
            m.concat(quads),
            _mean_color(label_tex),
            texture=label_tex,
            uv=np.concatenate(uvs),
            name="label",
        ),
    ]
