"""Electronic devices: monitor, cellphone, mouse.

Screens are textured quads facing +x only; the backs carry no screen, so a detector trained on screen
content responds to the front views alone (the viewpoint dependence of Meger et al. 2010, Fig. 2).
"""

from __future__ import annotations

import numpy as np

from scrppl.datasets.synthetic import textures as tx
from scrppl.datasets.synthetic.categories import _mesh as m
from scrppl.datasets.synthetic.shapes import Part

__all__ = ["cellphone", "monitor", "mouse"]

_DARK_PLASTICS = ((0.08, 0.08, 0.09), (0.15, 0.15, 0.16), (0.22, 0.22, 0.24), (0.12, 0.12, 0.18))
_LIGHT_PLASTICS = ((0.85, 0.85, 0.83), (0.78, 0.79, 0.8), (0.93, 0.92, 0.88))


def _pick(rng: np.random.Generator, options):
    """One of ``options``; colours (RGB tuples) get a small seeded jitter so no two match exactly."""
    choice = options[int(rng.integers(len(options)))]
    if isinstance(choice, tuple) and len(choice) == 3 and all(isinstance(c, float) for c in choice):
        jitter = rng.normal(0.0, 0.03, 3) + rng.normal(0.0, 0.04)
        return tuple(float(c) for c in np.clip(np.asarray(choice) + jitter, 0.0, 1.0))
    return choice


def _seed(rng: np.random.Generator) -> int:
    return int(rng.integers(2**31))


def _mean_color(tex: np.ndarray) -> tuple[float, float, float]:
    return tuple(float(c) for c in tex.reshape(-1, 3).mean(0) / 255.0)


def monitor(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A computer monitor: flat panel (or CRT) on a pedestal, plate or V-shaped stand.

    The screen quad faces +x; the back is a plain housing with the stand's neck.
    """
    aspect = _pick(rng, (4 / 3, 16 / 10, 16 / 9, 2.0))
    crt = rng.random() < 0.2
    if crt:
        aspect = 4 / 3
    W = rng.uniform(0.5, 0.62)
    H = W / aspect
    bezel = rng.uniform(0.008, 0.04) if not crt else rng.uniform(0.04, 0.06)
    depth = rng.uniform(0.018, 0.04)
    z0 = rng.uniform(0.07, 0.16)  # height of the panel's lower edge
    body = (
        _pick(rng, _DARK_PLASTICS + _LIGHT_PLASTICS[:1]) if not crt else _pick(rng, _LIGHT_PLASTICS)
    )
    accent = tuple(np.clip(np.asarray(body) + rng.uniform(-0.05, 0.1), 0, 1))
    pw, ph = W + 2 * bezel, H + 2 * bezel + (rng.uniform(0.0, 0.03))
    zc = z0 + 0.5 * ph
    panel = m.box((depth, pw, ph), (0.0, 0.0, zc))
    shell, vents = [panel], []
    if crt:
        back_depth = rng.uniform(0.28, 0.4) * W
        tube = m.extrude_profile_y(
            np.array(
                [
                    [-depth / 2, z0 + 0.05 * ph],
                    [-depth / 2 - back_depth, z0 + 0.25 * ph],
                    [-depth / 2 - back_depth, z0 + 0.8 * ph],
                    [-depth / 2, z0 + 0.95 * ph],
                ]
            ),
            0.7 * pw,
        )
        shell.append(tube)
    else:
        back = m.box((0.03, 0.6 * pw, 0.55 * ph), (-depth / 2 - 0.015, 0.0, zc - 0.05 * ph))
        shell.append(back)
        # ventilation slots along the top of the back housing
        n_vents = int(rng.integers(5, 12))
        for yv in np.linspace(-0.22 * pw, 0.22 * pw, n_vents):
            vents.append(
                m.box(
                    (0.003, 0.25 * pw / n_vents, 0.1 * ph),
                    (-depth / 2 - 0.0315, yv, zc + 0.12 * ph),
                )
            )
    # the stand
    stand_kind = "crt" if crt else _pick(rng, ("pedestal", "plate", "vshape", "arm"))
    neck_x = -depth / 2 - (0.03 if not crt else 0.2 * W)
    stand = []
    if stand_kind == "crt":
        stand.append(m.box((0.35 * W, 0.45 * W, z0), (neck_x, 0.0, z0 / 2)))
    else:
        neck_w = rng.uniform(0.04, 0.09)
        neck_top = zc
        if stand_kind == "arm":
            stand.append(
                m.polyline_tube(
                    np.array(
                        [[neck_x, 0, 0.01], [neck_x - 0.06, 0, 0.6 * zc], [neck_x, 0, neck_top]]
                    ),
                    0.018,
                    8,
                )
            )
        else:
            stand.append(m.box((0.02, neck_w, neck_top), (neck_x - 0.01, 0.0, neck_top / 2)))
        if stand_kind == "pedestal":
            mesh, _ = m.lathe(
                np.array(
                    [[0.0, 0.0], [0.13 * W + 0.05, 0.0], [0.13 * W + 0.05, 0.012], [0.0, 0.02]]
                ),
                24,
            )
            stand.append(m.translate(mesh, (neck_x + 0.04, 0.0, 0.0)))
        elif stand_kind == "plate":
            stand.append(
                m.box((0.22, rng.uniform(0.3, 0.5) * W, 0.014), (neck_x + 0.05, 0.0, 0.007))
            )
        else:  # V-shaped feet pointing forward
            for sgn in (-1, 1):
                foot = m.polyline_tube(
                    np.array([[neck_x, 0.0, 0.008], [neck_x + 0.16, sgn * 0.22 * W, 0.008]]),
                    0.01,
                    6,
                )
                stand.append(foot)
            stand.append(m.box((0.06, 0.06, 0.016), (neck_x, 0.0, 0.008)))
    screen_tex = tx.screen(tex_seed, 120, int(120 * aspect))
    quad, uv = m.quad((depth / 2 + 0.002, 0.0, z0 + bezel + 0.5 * H), "+x", W, H)
    parts = [
        Part(m.concat(shell), body, specular=0.3, name="housing"),
        Part(m.concat(stand), accent, specular=0.4, name="stand"),
        Part(quad, _mean_color(screen_tex), texture=screen_tex, uv=uv, specular=0.6, name="screen"),
    ]
    if vents:
        parts.append(
            Part(m.concat(vents), tuple(0.3 * np.asarray(body) + 0.02), specular=0.1, name="vents")
        )
    if bezel > 0.015 and rng.random() < 0.8:  # brand name on the lower bezel
        lab = tx.label(_seed(rng), body, (0.8, 0.8, 0.82), 24, 96, logo=False)
        lq, luv = m.quad(
            (depth / 2 + 0.002, 0.0, z0 + 0.5 * bezel), "+x", 0.8 * bezel * 4, 0.8 * bezel
        )
        parts.append(Part(lq, _mean_color(lab), texture=lab, uv=luv, name="logo"))
    led = m.box((0.004, 0.008, 0.008), (depth / 2 + 0.002, 0.4 * pw, z0 + 0.5 * bezel))
    parts.append(
        Part(
            led,
            _pick(rng, ((0.2, 0.9, 0.3), (0.3, 0.6, 1.0), (1.0, 0.6, 0.1))),
            specular=0.8,
            name="led",
        )
    )
    return parts


def cellphone(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A phone standing in a desk dock, leaning back, its screen (or keypad) facing +x.

    Styles: a smartphone (screen over nearly the whole front) or a keypad phone (small screen above
    the keys). The back is plain apart from a camera lens.
    """
    style = "smartphone" if rng.random() < 0.65 else "keypad"
    if style == "smartphone":
        w, h, t = rng.uniform(0.062, 0.08), rng.uniform(0.13, 0.165), rng.uniform(0.007, 0.01)
        corner = rng.uniform(0.004, 0.012)
    else:
        w, h, t = rng.uniform(0.045, 0.055), rng.uniform(0.1, 0.125), rng.uniform(0.013, 0.02)
        corner = rng.uniform(0.003, 0.01)
    body = _pick(
        rng,
        _DARK_PLASTICS
        + ((0.75, 0.75, 0.78), (0.8, 0.7, 0.55), (0.55, 0.1, 0.12), (0.1, 0.25, 0.5)),
    )
    # the slab: a rounded rectangle in (y, z), extruded along x
    slab = m.extrude(m.rounded_rect(w, h, corner, 5), -t / 2, t / 2)
    v = np.asarray(slab.vertices)
    slab = m.make_mesh(np.column_stack([v[:, 2], v[:, 0], v[:, 1] + h / 2]), slab.faces)
    if style == "smartphone":
        border = rng.uniform(0.002, 0.005)
        tex = tx.phone_screen(tex_seed, 160, int(160 * (w - 2 * border) / (h - 4 * border)))
        front, uv = m.quad((t / 2 + 0.0004, 0.0, h / 2), "+x", w - 2 * border, h - 4 * border)
    else:
        tex = tx.keypad_phone(tex_seed, body, 160, int(160 * w / h))
        front, uv = m.quad((t / 2 + 0.0004, 0.0, h / 2), "+x", w * 0.94, h * 0.96)
    lens_r = rng.uniform(0.003, 0.006)
    lens_y = rng.uniform(-0.3, 0.3) * w
    lens = m.cylinder(
        (-t / 2 - 0.001, lens_y, h - 0.02), (-t / 2 + 0.001, lens_y, h - 0.02), lens_r, 12
    )
    tilt = np.deg2rad(rng.uniform(8.0, 20.0))
    # the dock: a base with a front lip; the phone rests on it, tilted back about the y axis
    dock_h = rng.uniform(0.008, 0.015)
    dock_d = rng.uniform(0.06, 0.09)
    wood_dock = rng.random() < 0.2
    dock_color = _pick(rng, _DARK_PLASTICS + _LIGHT_PLASTICS)
    phone_parts = []
    for mesh in (slab, front, lens):
        mesh = m.rotate(mesh, -tilt, (0, 1, 0))
        phone_parts.append(m.translate(mesh, (0.0, 0.0, dock_h)))
    x_phone = -0.5 * t
    dock = [
        m.box((dock_d, w * 1.15, dock_h), (x_phone - 0.25 * dock_d, 0.0, dock_h / 2)),
        m.box(
            (0.006, w * 1.15, 0.012),
            (x_phone + 0.5 * t / np.cos(tilt) + 0.004, 0.0, dock_h + 0.006),
        ),
        m.rotate(
            m.box((0.006, w * 0.5, 0.6 * h), (x_phone - t / 2 - 0.003, 0.0, dock_h + 0.3 * h)),
            -tilt,
            (0, 1, 0),
            (x_phone, 0, dock_h),
        ),
    ]
    parts = [
        Part(phone_parts[0], body, specular=0.5, name="body"),
        Part(phone_parts[1], _mean_color(tex), texture=tex, uv=uv, specular=0.7, name="screen"),
        Part(phone_parts[2], (0.03, 0.03, 0.04), specular=0.9, name="lens"),
    ]
    if wood_dock:
        d = m.concat(dock)
        wood_tex = tx.wood(_seed(rng))
        vv = np.asarray(d.vertices)
        duv = np.column_stack(
            [
                (vv[:, 0] - vv[:, 0].min()) / np.ptp(vv[:, 0]),
                (vv[:, 1] - vv[:, 1].min()) / np.ptp(vv[:, 1]),
            ]
        )
        parts.append(Part(d, _mean_color(wood_tex), texture=wood_tex, uv=duv, name="dock"))
    else:
        parts.append(Part(m.concat(dock), dock_color, specular=0.3, name="dock"))
    return parts


def mouse(rng: np.random.Generator, tex_seed: int) -> list[Part]:
    """A computer mouse: a domed body, highest towards the back, with buttons and wheel at the front.

    The front is +x; most instances have a cable leaving the front.
    """
    L = rng.uniform(0.1, 0.125)
    W = L * rng.uniform(0.5, 0.62)
    Hm = L * rng.uniform(0.3, 0.4)
    peak = rng.uniform(-0.25, -0.05)  # position of the highest point along the length
    front_w = rng.uniform(0.7, 0.95)  # front width relative to the back
    body = _pick(
        rng,
        _DARK_PLASTICS + _LIGHT_PLASTICS + ((0.6, 0.1, 0.1), (0.15, 0.3, 0.6), (0.7, 0.7, 0.72)),
    )
    nu, nv = 28, 14
    s = np.linspace(-1.0, 1.0, nu)  # back to front
    x = 0.5 * L * s
    halfw = 0.5 * W * (1 - np.abs(s) ** 3.0) ** 0.4 * np.where(s > 0, 1 - (1 - front_w) * s, 1.0)
    height = Hm * np.clip(1 - ((s - peak) / (1.0 + np.sign(s - peak) * peak)) ** 2, 0, 1) ** 0.5
    height = np.maximum(height, 1e-4) * (1 - np.abs(s) ** 8) ** 0.3
    t = np.linspace(0.0, np.pi, nv)
    base_z = 0.004
    Y = -halfw[:, None] * np.cos(t)[None, :]
    Z = base_z + height[:, None] * np.sin(t)[None, :] ** 0.7
    X = np.broadcast_to(x[:, None], Y.shape)
    shell, uv = m.grid_surface(np.stack([X, Y, Z], -1))
    top_tex = tx.mouse_top(tex_seed, body)
    foot = m.extrude(
        np.column_stack([np.concatenate([x, x[::-1]]), np.concatenate([-halfw, halfw[::-1]])]),
        0.0,
        base_z,
    )
    wheel_x = 0.5 * L * rng.uniform(0.45, 0.6)
    iz = np.argmin(np.abs(x - wheel_x))
    wheel_z = base_z + height[iz]
    wheel = m.cylinder(
        (wheel_x, -0.004, wheel_z - 0.002), (wheel_x, 0.004, wheel_z - 0.002), 0.008, 12
    )
    parts = [
        Part(
            shell,
            _mean_color(top_tex),
            texture=top_tex,
            uv=uv,
            specular=0.5,
            smooth=True,
            name="shell",
        ),
        Part(foot, (0.05, 0.05, 0.05), name="base"),
        Part(
            wheel,
            (0.1, 0.1, 0.1) if np.mean(body) > 0.3 else (0.5, 0.5, 0.5),
            specular=0.3,
            name="wheel",
        ),
    ]
    if rng.random() < 0.8:  # a cable from the front, curving to one side on the table
        side = rng.choice([-1.0, 1.0])
        reach = rng.uniform(0.35, 0.6) * L
        tt = np.linspace(0.0, 1.0, 14)
        cx = 0.5 * L + reach * tt
        cy = side * 0.35 * L * tt**2 * rng.uniform(0.3, 1.0)
        cz = base_z + 0.3 * Hm * (1 - tt) ** 2 + 0.003
        cable = m.polyline_tube(np.column_stack([cx, cy, cz]), 0.0025, 6)
        parts.append(
            Part(
                cable,
                (0.05, 0.05, 0.05) if np.mean(body) < 0.5 else (0.85, 0.85, 0.85),
                name="cable",
            )
        )
    return parts
