"""Vehicles: car and bicycle.

A car's front and back are alike (lights, bumper, licence plate on both) and unlike its sides (doors,
windows, wheels); a bicycle's wheels lie in the xz plane, so it is thin from the front and back and
wide from the side — the two classic viewpoint structures of Meger et al. (2010, Fig. 2).
"""

from __future__ import annotations

import numpy as np

from scrppl.datasets.synthetic import textures as tx
from scrppl.datasets.synthetic.categories import _mesh as m
from scrppl.datasets.synthetic.categories.devices import _mean_color, _pick, _seed
from scrppl.datasets.synthetic.shapes import Part

__all__ = ["bicycle", "car"]

_CAR_PAINTS = (
    (0.7, 0.05, 0.05),
    (0.05, 0.15, 0.45),
    (0.9, 0.9, 0.9),
    (0.1, 0.1, 0.1),
    (0.55, 0.56, 0.58),
    (0.1, 0.35, 0.15),
    (0.85, 0.6, 0.05),
    (0.3, 0.15, 0.08),
    (0.2, 0.45, 0.7),
    (0.75, 0.72, 0.6),
)
_FRAME_PAINTS = (
    (0.8, 0.1, 0.1),
    (0.1, 0.2, 0.7),
    (0.1, 0.1, 0.1),
    (0.9, 0.9, 0.9),
    (0.1, 0.55, 0.25),
    (0.95, 0.55, 0.1),
    (0.5, 0.5, 0.55),
    (0.35, 0.75, 0.85),
    (0.55, 0.1, 0.45),
)


def _wheel_y(center, radius: float, width: float, tread_seed: int, sections: int = 28):
    """Tyre (a lathe around the y axis, textured with tread) centred at ``center`` (3,)."""
    w = 0.5 * width
    prof = np.array(
        [
            [0.72 * radius, -w],
            [0.9 * radius, -w * 1.02],
            [radius, -0.6 * w],
            [radius, 0.6 * w],
            [0.9 * radius, w * 1.02],
            [0.72 * radius, w],
        ]
    )
    mesh, uv = m.lathe(prof, sections)
    # lathe revolves about z; rotate so the axis is y (the tyre rolls in the xz plane)
    mesh = m.rotate(mesh, -0.5 * np.pi, (1, 0, 0))
    mesh = m.translate(mesh, center)
    tex = tx.tread(tread_seed, 32, 256)
    return mesh, uv[:, ::-1].copy(), tex


def car(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A car: sedan, hatchback, estate, SUV or van profile; lights, bumpers and plates front and back.

    Built in units where the length is 1: a lower body (the side profile extruded across the width,
    with wheel arches), a glass cabin, a roof, pillars, four wheels, mirrors and door seams.
    """
    kind = _pick(rng, ("sedan", "hatch", "estate", "suv", "van"))
    L = 1.0
    W = rng.uniform(0.4, 0.46) if kind != "van" else rng.uniform(0.4, 0.44)
    r = rng.uniform(0.085, 0.1) if kind not in ("suv", "van") else rng.uniform(0.1, 0.12)
    clear = r * rng.uniform(0.35, 0.6)
    belt = clear + rng.uniform(0.17, 0.21) * (1.15 if kind in ("suv", "van") else 1.0)
    x_fw, x_rw = rng.uniform(0.28, 0.34), -rng.uniform(0.28, 0.34)  # wheel centres
    roof = belt + {"sedan": 0.14, "hatch": 0.15, "estate": 0.15, "suv": 0.18, "van": 0.24}[
        kind
    ] * rng.uniform(0.92, 1.08)
    # lower body: side profile (x, z), counter-clockwise, with wheel arches cut from the bottom
    hood_drop = rng.uniform(0.02, 0.05)
    arch = r * 1.12
    prof = [(-0.5 * L, clear + 0.02), (-0.5 * L + 0.015, clear)]
    for xc in (x_rw, x_fw):
        prof.append((xc - arch, clear))
        for a in np.linspace(np.pi, 0.0, 9)[1:-1]:
            prof.append((xc + arch * np.cos(a), r + 0.01 + (arch - 0.01) * np.sin(a) * 0.95))
        prof.append((xc + arch, clear))
    front_round = rng.uniform(0.02, 0.06)
    prof += [
        (0.5 * L - 0.015, clear),
        (0.5 * L, clear + 0.03),
        (0.5 * L, belt - hood_drop - front_round),
        (0.5 * L - front_round, belt - hood_drop),
        (x_fw - 0.05, belt),
        (-0.5 * L + 0.02, belt + (0.015 if kind == "sedan" else 0.0)),
        (-0.5 * L, belt - 0.03),
    ]
    lower = m.extrude_profile_y(np.array(prof), W)
    # cabin (glass) profile per body type: windshield base -> roof front -> roof back -> rear base
    ws = {"sedan": 0.2, "hatch": 0.22, "estate": 0.2, "suv": 0.24, "van": 0.4}[kind] + rng.uniform(
        -0.03, 0.03
    )
    rf = ws - {"sedan": 0.2, "hatch": 0.2, "estate": 0.2, "suv": 0.15, "van": 0.1}[kind]
    rb = {"sedan": -0.18, "hatch": -0.36, "estate": -0.42, "suv": -0.42, "van": -0.47}[
        kind
    ] + rng.uniform(-0.02, 0.02)
    rear = {"sedan": -0.34, "hatch": -0.43, "estate": -0.46, "suv": -0.47, "van": -0.49}[kind]
    cab = np.array([(rear, belt - 0.005), (ws, belt - 0.005), (rf, roof), (rb, roof)])
    cab_w = W * rng.uniform(0.82, 0.9)
    cabin = m.extrude_profile_y(cab, cab_w)
    roof_slab = m.extrude_profile_y(
        np.array(
            [
                (rb - 0.005, roof - 0.012),
                (rf + 0.005, roof - 0.012),
                (rf + 0.004, roof + 0.006),
                (rb - 0.004, roof + 0.006),
            ]
        ),
        cab_w + 0.008,
    )
    # pillars on both sides (A, B and C) in body colour, slightly proud of the glass
    pillars = []
    for x_bottom, x_top in (
        (ws - 0.01, rf + 0.005),
        (0.5 * (ws + rear) + 0.02, 0.5 * (rf + rb) + 0.02),
        (rear + 0.01, rb - 0.005),
    ):
        pillar = m.extrude_profile_y(
            np.array(
                [
                    (x_bottom - 0.025, belt),
                    (x_bottom + 0.01, belt),
                    (x_top + 0.01, roof),
                    (x_top - 0.025, roof),
                ]
            ),
            0.014,
        )
        pillars += [m.translate(pillar, (0.0, sgn * 0.5 * cab_w, 0.0)) for sgn in (-1, 1)]
    paint = _pick(rng, _CAR_PAINTS)
    glass = (0.12, 0.16, 0.22)
    parts = [
        Part(m.concat([lower, roof_slab] + pillars), paint, specular=0.7, name="body"),
        Part(cabin, glass, specular=0.9, name="windows"),
    ]
    # wheels and hubcaps
    tyre_w = W * rng.uniform(0.17, 0.22)
    tyres, hubs, tyre_uv, hub_uv = [], [], [], []
    tread_seed = _seed(rng)
    hub_color = _pick(rng, ((0.75, 0.75, 0.78), (0.2, 0.2, 0.22), (0.55, 0.55, 0.6)))
    for xc in (x_rw, x_fw):
        for sgn in (-1, 1):
            yc = sgn * (0.5 * W - 0.5 * tyre_w + 0.01)
            mesh, uv, tread_tex = _wheel_y((xc, yc, r), r, tyre_w, tread_seed)
            tyres.append(mesh)
            tyre_uv.append(uv)
            disc, disc_uv = m.disc_y((xc, yc + sgn * (0.5 * tyre_w + 0.003), r), 0.7 * r, sgn, 16)
            hubs.append(disc)
            hub_uv.append(disc_uv)
    parts.append(
        Part(
            m.concat(tyres),
            (0.08, 0.08, 0.08),
            texture=tread_tex,
            uv=np.concatenate(tyre_uv),
            specular=0.1,
            name="tyres",
        )
    )
    hub_tex = tx.hubcap(_seed(rng), hub_color)
    parts.append(
        Part(
            m.concat(hubs),
            _mean_color(hub_tex),
            texture=hub_tex,
            uv=np.concatenate(hub_uv),
            specular=0.8,
            name="hubs",
        )
    )
    # lights: similar arrangement front and back, white/amber at the front, red at the back
    light_w = W * rng.uniform(0.16, 0.25)
    light_h = rng.uniform(0.025, 0.045)
    z_light = belt - hood_drop - light_h * 0.7
    heads, tails = [], []
    for sgn in (-1, 1):
        y = sgn * (0.5 * W - 0.5 * light_w - 0.015)
        heads.append(m.box((0.01, light_w, light_h), (0.5 * L, y, z_light)))
        tails.append(m.box((0.01, light_w, light_h), (-0.5 * L, y, belt - 0.035)))
    parts.append(
        Part(
            m.concat(heads),
            _pick(rng, ((0.95, 0.95, 0.85), (0.9, 0.9, 1.0), (1.0, 0.85, 0.5))),
            specular=0.9,
            name="headlights",
        )
    )
    parts.append(Part(m.concat(tails), (0.8, 0.05, 0.05), specular=0.8, name="taillights"))
    # bumpers front and back
    bump_c = _pick(rng, ((0.1, 0.1, 0.1), paint, (0.3, 0.3, 0.32)))
    bumpers = [
        m.box((0.03, W * 1.01, 0.05), (sx * (0.5 * L - 0.005), 0.0, clear + 0.03)) for sx in (-1, 1)
    ]
    parts.append(Part(m.concat(bumpers), bump_c, specular=0.3, name="bumpers"))
    # grille and plates
    grille_tex = tx.grille(_seed(rng))
    gq, guv = m.quad((0.5 * L + 0.006, 0.0, z_light), "+x", W - 2 * light_w - 0.06, light_h * 1.1)
    parts.append(
        Part(gq, _mean_color(grille_tex), texture=grille_tex, uv=guv, specular=0.5, name="grille")
    )
    plate_seed = _seed(rng)
    for sx, normal, name in ((1, "+x", "front_plate"), (-1, "-x", "rear_plate")):
        ptex = tx.license_plate(plate_seed + (sx > 0))
        pq, puv = m.quad((sx * (0.5 * L + 0.012), 0.0, clear + 0.03), normal, 0.16, 0.04)
        parts.append(Part(pq, _mean_color(ptex), texture=ptex, uv=puv, name=name))
    # side details: mirrors, door seams and handles (sides only)
    side = []
    for sgn in (-1, 1):
        side.append(m.box((0.05, 0.035, 0.03), (ws - 0.02, sgn * (0.5 * W + 0.015), belt + 0.015)))
        n_doors = 1 if kind == "van" else 2
        xs = np.linspace(ws + 0.02, rear + 0.05, n_doors + 1)
        for xd in xs:
            side.append(
                m.box(
                    (0.006, 0.006, belt - clear - 0.04), (xd, sgn * 0.5 * W, 0.5 * (belt + clear))
                )
            )
        for xd in xs[:-1]:
            side.append(m.box((0.04, 0.008, 0.012), (xd - 0.06, sgn * 0.5 * W, belt - 0.03)))
    parts.append(Part(m.concat(side), (0.06, 0.06, 0.06), specular=0.4, name="side_trim"))
    return parts


def _tube(p0, p1, radius, sections=8):
    return m.cylinder(p0, p1, radius, sections)


def bicycle(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A bicycle: diamond or step-through frame, wheel size, handlebar type and colours vary.

    The frame and wheels lie in the xz plane (thin seen from the front, wide from the side); the
    front wheel, fork and handlebar are at +x, the saddle and the rear wheel at -x, and the chain
    ring on the right side (-y).
    """
    R = rng.uniform(0.3, 0.36)  # wheel radius
    frame = _pick(rng, ("diamond", "diamond", "step", "mtb"))
    bars = _pick(rng, ("flat", "drop", "riser", "cruiser"))
    chainstay = rng.uniform(0.4, 0.46)
    bb_drop = rng.uniform(0.05, 0.08)
    seat_angle = np.deg2rad(rng.uniform(70, 75))
    head_angle = np.deg2rad(rng.uniform(69, 74))
    seat_len = rng.uniform(0.48, 0.58)
    reach = rng.uniform(0.55, 0.62)
    rear = np.array([-0.5 * chainstay - 0.3, 0.0, R])
    bb = rear + np.array([np.sqrt(chainstay**2 - bb_drop**2), 0.0, -bb_drop])
    seat_top = bb + seat_len * np.array([-np.cos(seat_angle), 0.0, np.sin(seat_angle)])
    head_top = np.array([bb[0] + reach, 0.0, seat_top[2] - rng.uniform(0.0, 0.06)])
    head_len = rng.uniform(0.12, 0.18)
    head_dir = np.array([np.cos(head_angle), 0.0, -np.sin(head_angle)])
    head_bot = head_top + head_len * head_dir
    # the fork continues the head-tube line down to the front axle (with a little rake)
    t_axle = (head_bot[2] - R) / np.sin(head_angle)
    front = head_bot + t_axle * head_dir + np.array([0.03, 0.0, 0.0])
    front[2] = R
    tube_r = rng.uniform(0.012, 0.02) if frame != "mtb" else rng.uniform(0.018, 0.025)
    tubes = [
        _tube(bb, seat_top, tube_r),  # seat tube
        _tube(head_bot, head_top, tube_r * 1.2),  # head tube
    ]
    if frame == "step":
        low = bb + 0.4 * (seat_top - bb)
        tubes.append(
            m.polyline_tube(
                np.array(
                    [
                        head_bot + 0.3 * (head_top - head_bot),
                        0.5 * (head_bot + low) + np.array([0, 0, -0.08]),
                        low,
                    ]
                ),
                tube_r,
                8,
                caps=True,
            )
        )
        tubes.append(_tube(bb, head_bot, tube_r))
    else:
        tt_start = seat_top - 0.04 * (seat_top - bb) / seat_len
        tubes.append(
            _tube(tt_start, head_top - 0.02 * (head_top - head_bot) / head_len, tube_r * 0.9)
        )  # top tube
        tubes.append(_tube(bb, head_bot, tube_r * 1.1))  # down tube
    for sgn in (-1, 1):
        off = np.array([0.0, sgn * 0.05, 0.0])
        tubes.append(_tube(rear + off, bb + 0.3 * off, tube_r * 0.6, 6))  # chain stays
        tubes.append(
            _tube(rear + off, seat_top - 0.04 * (seat_top - bb) / seat_len, tube_r * 0.55, 6)
        )  # seat stays
        tubes.append(
            _tube(front + np.array([0, sgn * 0.05, 0]), head_bot + 0.3 * off, tube_r * 0.7, 6)
        )  # fork
    paint = _pick(rng, _FRAME_PAINTS)
    parts = [Part(m.concat(tubes), paint, specular=0.6, name="frame")]
    # seat post, saddle (nose to +x), stem and handlebar
    post_top = seat_top + rng.uniform(0.06, 0.16) * np.array(
        [-np.cos(seat_angle), 0, np.sin(seat_angle)]
    )
    saddle_mesh, _ = m.ellipsoid(
        (post_top[0] + 0.02, 0.0, post_top[2] + 0.02),
        (0.13, 0.055 if bars != "cruiser" else 0.09, 0.025),
        12,
        6,
    )
    stem_top = head_top + np.array([0.0, 0.0, rng.uniform(0.03, 0.1)])
    stem_end = stem_top + np.array([rng.uniform(0.05, 0.11), 0.0, 0.01])
    hw = rng.uniform(0.24, 0.32) if bars != "drop" else rng.uniform(0.2, 0.23)
    if bars == "flat":
        bar_pts = np.array([[stem_end[0], -hw, stem_end[2]], [stem_end[0], hw, stem_end[2]]])
    elif bars == "riser":
        bar_pts = np.array(
            [
                [stem_end[0], y, stem_end[2] + 0.05 * (abs(y) / hw) ** 2]
                for y in np.linspace(-hw, hw, 9)
            ]
        )
    elif bars == "cruiser":
        bar_pts = np.array(
            [
                [stem_end[0] - 0.15 * (abs(y) / hw) ** 2, y, stem_end[2] + 0.05 * (abs(y) / hw)]
                for y in np.linspace(-hw, hw, 9)
            ]
        )
    else:  # drop bars: out to each side, then forward and down, then back
        pts = []
        for sgn in (-1, 1):
            side = [
                [stem_end[0] + 0.1 * np.sin(a), sgn * hw, stem_end[2] - 0.06 * (1 - np.cos(a))]
                for a in np.linspace(0, np.pi, 7)
            ]
            side = side + [[side[-1][0] - 0.06, sgn * hw, side[-1][1] * 0 + stem_end[2] - 0.12]]
            pts.append(side[::-1] if sgn < 0 else side)
        bar_pts = np.array(pts[0] + pts[1])
    metal = (0.7, 0.7, 0.72) if rng.random() < 0.6 else (0.12, 0.12, 0.13)
    fittings = [
        _tube(seat_top, post_top, tube_r * 0.7, 6),
        _tube(head_top, stem_top, tube_r * 0.9, 6),
        _tube(stem_top, stem_end, tube_r * 0.8, 6),
        m.polyline_tube(bar_pts, 0.013, 6),
    ]
    grips = [
        _tube(
            bar_pts[0],
            bar_pts[0] + 0.08 * (bar_pts[1] - bar_pts[0]) / np.linalg.norm(bar_pts[1] - bar_pts[0]),
            0.018,
            8,
        ),
        _tube(
            bar_pts[-1],
            bar_pts[-1]
            + 0.08 * (bar_pts[-2] - bar_pts[-1]) / np.linalg.norm(bar_pts[-2] - bar_pts[-1]),
            0.018,
            8,
        ),
    ]
    parts.append(Part(m.concat(fittings), metal, specular=0.8, name="fittings"))
    parts.append(
        Part(
            m.concat([saddle_mesh] + grips),
            _pick(rng, ((0.08, 0.08, 0.08), (0.35, 0.2, 0.1), (0.6, 0.45, 0.3))),
            specular=0.3,
            smooth=True,
            name="saddle",
        )
    )
    # drive train on the right side (-y): chain ring, cranks, pedals, chain
    ring_r = rng.uniform(0.08, 0.11)
    ring = m.cylinder(bb + np.array([0, -0.06, 0]), bb + np.array([0, -0.07, 0]), ring_r, 20)
    crank_a = rng.uniform(0, np.pi)
    drive = [ring]
    for sgn, ang in ((-1, crank_a), (1, crank_a + np.pi)):
        end = bb + np.array([0.17 * np.cos(ang), sgn * 0.08, 0.17 * np.sin(ang)])
        drive.append(_tube(bb + np.array([0, sgn * 0.075, 0]), end, 0.012, 6))
        drive.append(m.box((0.09, 0.09, 0.02), end + np.array([0, sgn * 0.05, 0])))
    drive.append(
        _tube(bb + np.array([0, -0.065, ring_r]), rear + np.array([0, -0.065, 0.04]), 0.006, 4)
    )
    drive.append(
        _tube(bb + np.array([0, -0.065, -ring_r]), rear + np.array([0, -0.065, -0.04]), 0.006, 4)
    )
    parts.append(Part(m.concat(drive), (0.45, 0.45, 0.47), specular=0.7, name="drivetrain"))
    # wheels: tread-textured tyres (tori in the xz plane), rims, hubs and spokes
    tyre_r = rng.uniform(0.018, 0.03) if frame != "mtb" else rng.uniform(0.03, 0.04)
    tyres, tyre_uv, rims, spokes = [], [], [], []
    tread_tex = tx.tread(tex_seed, 16, 256)
    n_spokes = int(_pick(rng, (12, 16, 18)))
    for c in (rear, front):
        mesh, uv = m.torus(c, R - tyre_r, tyre_r, "y", 40, 6)
        tyres.append(mesh)
        tyre_uv.append(uv)
        rim, _ = m.torus(c, R - 2.2 * tyre_r, 0.45 * tyre_r, "y", 32, 4)
        rims.append(rim)
        rims.append(_tube(c + np.array([0, -0.045, 0]), c + np.array([0, 0.045, 0]), 0.02, 8))
        for k in range(n_spokes):
            a = 2 * np.pi * k / n_spokes
            side = 0.03 if k % 2 else -0.03
            spokes.append(
                _tube(
                    c + np.array([0, side, 0]),
                    c + (R - 2.4 * tyre_r) * np.array([np.cos(a), 0, np.sin(a)]),
                    0.0025,
                    3,
                )
            )
    parts.append(
        Part(
            m.concat(tyres),
            (0.08, 0.08, 0.08),
            texture=tread_tex,
            uv=np.concatenate(tyre_uv),
            specular=0.1,
            smooth=True,
            name="tyres",
        )
    )
    parts.append(Part(m.concat(rims + spokes), metal, specular=0.8, name="wheels"))
    if rng.random() < 0.4:  # mudguards or a rear rack
        rack = [
            _tube(
                post_top + np.array([-0.02, sgn * 0.06, -0.06]),
                rear + np.array([-0.05, sgn * 0.06, 0.12]),
                0.007,
                4,
            )
            for sgn in (-1, 1)
        ]
        rack.append(m.box((0.3, 0.13, 0.01), rear + np.array([-0.02, 0, 0.12 + R * 0.0 + 0.02])))
        parts.append(Part(m.concat(rack), (0.15, 0.15, 0.15), specular=0.5, name="rack"))
    return parts
