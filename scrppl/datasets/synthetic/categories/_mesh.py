"""Mesh-building helpers shared by the procedural categories.

Every helper returns a `trimesh.Trimesh` built with ``process=False`` so that vertex order is kept and,
for textured surfaces, the texture coordinates stay aligned with the vertices. Texture coordinates
follow the OpenGL convention used by VTK: ``u`` runs left to right across the image and ``v`` from the
bottom row (``v = 0``) to the top row (``v = 1``).
"""

from __future__ import annotations

import numpy as np

from scrppl._extras import require

trimesh = require("render", "trimesh")

__all__ = [
    "box",
    "concat",
    "cylinder",
    "disc_y",
    "ellipsoid",
    "extrude",
    "grid_surface",
    "lathe",
    "make_mesh",
    "polyline_tube",
    "quad",
    "rotate",
    "rounded_rect",
    "superellipse",
    "torus",
    "translate",
]


def make_mesh(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    """A mesh that keeps its vertices as given (no merging, no reordering).

    Parameters
    ----------
    vertices : (V, 3) float array
    faces : (F, 3) int array

    Returns
    -------
    trimesh.Trimesh
    """
    return trimesh.Trimesh(
        vertices=np.asarray(vertices, dtype=np.float64),
        faces=np.asarray(faces, dtype=np.int64),
        process=False,
    )


def translate(mesh: trimesh.Trimesh, offset) -> trimesh.Trimesh:
    """Return a translated copy of ``mesh`` by ``offset`` (3,)."""
    out = mesh.copy()
    out.apply_translation(np.asarray(offset, dtype=float))
    return out


def rotate(mesh: trimesh.Trimesh, angle: float, axis, point=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Return a copy of ``mesh`` rotated by ``angle`` radians about ``axis`` through ``point``."""
    out = mesh.copy()
    out.apply_transform(trimesh.transformations.rotation_matrix(angle, axis, point))
    return out


def concat(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Concatenate meshes into one, keeping every vertex (offsets faces accordingly)."""
    vertices, faces, offset = [], [], 0
    for m in meshes:
        vertices.append(np.asarray(m.vertices))
        faces.append(np.asarray(m.faces) + offset)
        offset += len(m.vertices)
    return make_mesh(np.concatenate(vertices), np.concatenate(faces))


def box(extents, center=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Axis-aligned box with ``extents`` (3,) centred on ``center`` (3,); 12 triangles."""
    m = trimesh.creation.box(extents=np.asarray(extents, dtype=float))
    return translate(make_mesh(m.vertices, m.faces), center)


def cylinder(p0, p1, radius: float, sections: int = 16) -> trimesh.Trimesh:
    """Closed cylinder from point ``p0`` (3,) to ``p1`` (3,)."""
    m = trimesh.creation.cylinder(
        radius=float(radius), segment=np.array([p0, p1], dtype=float), sections=int(sections)
    )
    return make_mesh(m.vertices, m.faces)


def disc_y(center, radius: float, facing: int, n: int = 16) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Flat disc in an xz plane facing +y (``facing = 1``) or -y (``facing = -1``), with uv coordinates.

    The texture's right is the viewer's right, its up is +z (see `quad`).

    Returns
    -------
    mesh : trimesh.Trimesh (a fan of ``n`` triangles)
    uv : (n + 1, 2) float array
    """
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ring = np.column_stack([radius * np.cos(a), np.zeros(n), radius * np.sin(a)])
    verts = np.concatenate([[[0.0, 0.0, 0.0]], ring]) + np.asarray(center, float)
    i = np.arange(1, n + 1)
    j = np.where(i == n, 1, i + 1)
    # viewer at +y looks along -y, their right is -x; at -y their right is +x
    u = 0.5 - 0.5 * facing * np.concatenate([[0.0], np.cos(a)])
    v = 0.5 + 0.5 * np.concatenate([[0.0], np.sin(a)])
    faces = (
        np.stack([np.zeros(n, int), j, i], 1)
        if facing > 0
        else np.stack([np.zeros(n, int), i, j], 1)
    )
    return make_mesh(verts, faces), np.column_stack([u, v])


def grid_surface(points: np.ndarray, close_u: bool = False) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Triangulate a parametric grid of points into a surface with texture coordinates.

    Parameters
    ----------
    points : (nu, nv, 3) float array
        Surface points; the first index runs along ``u`` (texture left to right), the second along
        ``v`` (texture bottom to top). Faces are wound so that ``d/du x d/dv`` is the outward normal.
    close_u : bool
        If true, the last column is joined to the first (the seam vertices are duplicated so that the
        texture wraps without a jump: the grid gets one extra column at ``u = 1``).

    Returns
    -------
    mesh : trimesh.Trimesh
    uv : (nu * nv, 2) float array in [0, 1]
        (or ``(nu + 1) * nv`` when ``close_u``).
    """
    pts = np.asarray(points, dtype=float)
    if close_u:
        pts = np.concatenate([pts, pts[:1]], axis=0)
    nu, nv = pts.shape[:2]
    u = np.linspace(0.0, 1.0, nu)
    v = np.linspace(0.0, 1.0, nv)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    idx = np.arange(nu * nv).reshape(nu, nv)
    a = idx[:-1, :-1].ravel()
    b = idx[1:, :-1].ravel()
    c = idx[1:, 1:].ravel()
    d = idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    verts = pts.reshape(-1, 3)
    tri = verts[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    faces = faces[area2 > 1e-12 * max(1.0, float(np.ptp(verts, axis=0).max()) ** 2)]
    uv = np.stack([uu.ravel(), vv.ravel()], 1)
    return make_mesh(verts, faces), uv


def superellipse(
    a: float, b: float, n: int, exponent: float = 2.0, phase: float = 0.0
) -> np.ndarray:
    """Closed superellipse ``|x/a|^p + |y/b|^p = 1`` sampled at ``n`` points counter-clockwise.

    Returns
    -------
    (n, 2) float array
    """
    t = phase + np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    c, s = np.cos(t), np.sin(t)
    e = 2.0 / exponent
    return np.stack([a * np.sign(c) * np.abs(c) ** e, b * np.sign(s) * np.abs(s) ** e], 1)


def rounded_rect(w: float, h: float, r: float, n_corner: int = 4) -> np.ndarray:
    """Rounded rectangle ``w`` x ``h`` with corner radius ``r``, centred, counter-clockwise.

    Returns
    -------
    (4 * n_corner, 2) float array
    """
    r = float(min(r, 0.5 * w - 1e-6, 0.5 * h - 1e-6))
    cx, cy = 0.5 * w - r, 0.5 * h - r
    pts = []
    for k, (sx, sy) in enumerate([(1, 1), (-1, 1), (-1, -1), (1, -1)]):
        t = np.linspace(0.0, 0.5 * np.pi, n_corner) + k * 0.5 * np.pi
        pts.append(np.stack([sx * cx + r * np.cos(t), sy * cy + r * np.sin(t)], 1))
    return np.concatenate(pts)


def _ear_clip(poly: np.ndarray) -> np.ndarray:
    """Triangulate a simple counter-clockwise polygon (n, 2) by ear clipping; returns (n-2, 3)."""
    idx = list(range(len(poly)))
    tris = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10 * len(poly) ** 2:
        guard += 1
        n = len(idx)
        for k in range(n):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % n]
            p0, p1, p2 = poly[i0], poly[i1], poly[i2]
            if cross(p0, p1, p2) <= 1e-14:
                continue
            inside = False
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                q = poly[j]
                if cross(p0, p1, q) >= 0 and cross(p1, p2, q) >= 0 and cross(p2, p0, q) >= 0:
                    inside = True
                    break
            if not inside:
                tris.append((i0, i1, i2))
                idx.pop(k)
                break
        else:  # no ear found (degenerate input): fall back to a fan
            break
    for k in range(1, len(idx) - 1):
        tris.append((idx[0], idx[k], idx[k + 1]))
    return np.asarray(tris, dtype=np.int64)


def extrude(polygon: np.ndarray, z0: float, z1: float) -> trimesh.Trimesh:
    """Extrude a simple polygon in the xy plane from ``z = z0`` to ``z = z1`` (closed prism).

    Parameters
    ----------
    polygon : (n, 2) float array
        A simple polygon (either orientation; it is made counter-clockwise).
    z0, z1 : float
        Bottom and top heights, ``z0 < z1``.

    Returns
    -------
    trimesh.Trimesh
    """
    p = np.asarray(polygon, dtype=float)
    area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    if area < 0:
        p = p[::-1]
    n = len(p)
    tris = _ear_clip(p)
    bottom = np.column_stack([p, np.full(n, z0)])
    top = np.column_stack([p, np.full(n, z1)])
    verts = np.concatenate([bottom, top])
    faces = [tris[:, ::-1], tris + n]
    i = np.arange(n)
    j = (i + 1) % n
    faces.append(np.stack([i, j, j + n], 1))
    faces.append(np.stack([i, j + n, i + n], 1))
    return make_mesh(verts, np.concatenate(faces))


def extrude_profile_y(profile: np.ndarray, width: float) -> trimesh.Trimesh:
    """Extrude a side profile given in the xz plane symmetrically along y over ``width``.

    Parameters
    ----------
    profile : (n, 2) float array
        Points ``(x, z)`` of a simple polygon.
    width : float
        Total extent along y.
    """
    m = extrude(profile, -0.5 * width, 0.5 * width)
    # (x, y', z') -> (x, -z', y'): maps the polygon plane onto xz and the extrusion onto y.
    v = np.asarray(m.vertices)
    return make_mesh(np.column_stack([v[:, 0], -v[:, 2], v[:, 1]]), m.faces)


def quad(center, normal: str, width: float, height: float) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Rectangle facing along an axis, with texture coordinates spanning [0, 1]^2.

    Parameters
    ----------
    center : (3,) array
    normal : {"+x", "-x", "+y", "-y", "+z"}
        Direction the visible face looks at. The texture's up is +z (for "+z": +x); its right is
        the viewer's right when looking at the face.
    width, height : float
        Size along the texture's right and up directions.

    Returns
    -------
    mesh : trimesh.Trimesh (2 triangles)
    uv : (4, 2) float array
    """
    right, up = {
        "+x": ([0, 1, 0], [0, 0, 1]),
        "-x": ([0, -1, 0], [0, 0, 1]),
        "+y": ([-1, 0, 0], [0, 0, 1]),
        "-y": ([1, 0, 0], [0, 0, 1]),
        "+z": ([0, -1, 0], [1, 0, 0]),
    }[normal]
    r = np.asarray(right, float) * 0.5 * width
    u = np.asarray(up, float) * 0.5 * height
    c = np.asarray(center, float)
    verts = np.array([c - r - u, c + r - u, c + r + u, c - r + u])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return make_mesh(verts, faces), uv


def ellipsoid(
    center, radii, nu: int = 24, nv: int = 12, exponent: float = 2.0
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Superellipsoid with texture coordinates (u: azimuth from -x through +x, v: bottom to top).

    ``u = 0.5`` is the +x direction, so a texture's centre column is the object's front.
    """
    phi = np.linspace(-np.pi, np.pi, nu, endpoint=False)
    theta = np.linspace(-0.5 * np.pi, 0.5 * np.pi, nv)
    P, T = np.meshgrid(phi, theta, indexing="ij")
    e = 2.0 / exponent

    def sp(x):
        return np.sign(x) * np.abs(x) ** e

    x = radii[0] * sp(np.cos(T)) * sp(np.cos(P))
    y = radii[1] * sp(np.cos(T)) * sp(np.sin(P))
    z = radii[2] * sp(np.sin(T))
    pts = np.stack([x, y, z], -1) + np.asarray(center, float)
    return grid_surface(pts, close_u=True)


def lathe(
    profile: np.ndarray, sections: int = 24, center=(0.0, 0.0, 0.0)
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Surface of revolution about the vertical axis of a profile ``(r, z)`` ordered bottom to top.

    Returns
    -------
    mesh : trimesh.Trimesh
    uv : (V, 2) float array (u: azimuth starting at -x, v: along the profile)
    """
    prof = np.asarray(profile, float)
    phi = np.linspace(-np.pi, np.pi, sections, endpoint=False)
    P, R = np.meshgrid(phi, prof[:, 0], indexing="ij")
    Z = np.broadcast_to(prof[:, 1], P.shape)
    pts = np.stack([R * np.cos(P), R * np.sin(P), Z], -1) + np.asarray(center, float)
    return grid_surface(pts, close_u=True)


def torus(
    center, major: float, minor: float, axis: str = "y", nu: int = 32, nv: int = 8
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Torus (a tyre) around ``axis`` ("y" or "z"); u runs around the ring, v around the tube."""
    a = np.linspace(0.0, 2.0 * np.pi, nu, endpoint=False)
    b = np.linspace(0.0, 2.0 * np.pi, nv + 1)
    A, B = np.meshgrid(a, b, indexing="ij")
    rr = major + minor * np.cos(B)
    if axis == "y":
        pts = np.stack([rr * np.cos(A), minor * np.sin(B), rr * np.sin(A)], -1)
        pts = pts[:, :, [0, 1, 2]]
        # wind outward: for axis y the (u, v) order above gives inward normals; flip v.
        pts = pts[:, ::-1]
    elif axis == "z":
        pts = np.stack([rr * np.cos(A), rr * np.sin(A), minor * np.sin(B)], -1)
    else:
        raise ValueError(f"torus axis must be 'y' or 'z', got {axis!r}")
    return grid_surface(pts + np.asarray(center, float), close_u=True)


def polyline_tube(
    points: np.ndarray, radius: float, sections: int = 8, caps: bool = True
) -> trimesh.Trimesh:
    """Tube of constant ``radius`` along a polyline ``points`` (n, 3) (cables, handlebars, frames)."""
    pts = np.asarray(points, float)
    n = len(pts)
    tang = np.gradient(pts, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    ref = np.array([0.0, 0.0, 1.0]) if abs(tang[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    normal = np.cross(tang[0], ref)
    normal /= np.linalg.norm(normal)
    rings = []
    ang = np.linspace(0.0, 2.0 * np.pi, sections, endpoint=False)
    for k in range(n):
        t = tang[k]
        normal = normal - np.dot(normal, t) * t  # parallel transport (projection)
        normal /= np.linalg.norm(normal)
        binormal = np.cross(t, normal)
        ring = pts[k] + radius * (np.cos(ang)[:, None] * normal + np.sin(ang)[:, None] * binormal)
        rings.append(ring)
    verts = np.concatenate(rings)
    faces = []
    for k in range(n - 1):
        i = k * sections + np.arange(sections)
        j = k * sections + (np.arange(sections) + 1) % sections
        faces.append(np.stack([i, j, j + sections], 1))
        faces.append(np.stack([i, j + sections, i + sections], 1))
    faces = np.concatenate(faces)
    if caps:
        c0 = len(verts)
        verts = np.concatenate([verts, pts[:1], pts[-1:]])
        i = np.arange(sections)
        j = (i + 1) % sections
        last = (n - 1) * sections
        faces = np.concatenate(
            [
                faces,
                np.stack([np.full(sections, c0), j, i], 1),
                np.stack([np.full(sections, c0 + 1), last + i, last + j], 1),
            ]
        )
    mesh = make_mesh(verts, faces)
    if caps and mesh.volume < 0:
        mesh.invert()
    return mesh


def loft(
    polygon: np.ndarray, scales, zs, offsets=None, cap_bottom: bool = True, cap_top: bool = True
) -> trimesh.Trimesh:
    """Loft a horizontal polygon through scaled, shifted copies at increasing heights.

    Parameters
    ----------
    polygon : (n, 2) float array
        Simple polygon in the xy plane (made counter-clockwise).
    scales : (k,) or (k, 2) array
        Scale of the polygon at each level (per axis when (k, 2)); a level of scale 0 closes the
        surface to a point.
    zs : (k,) array
        Increasing heights of the levels.
    offsets : (k, 2) array, optional
        xy shift of each level.
    cap_bottom, cap_top : bool
        Close the first / last level with a flat polygon.

    Returns
    -------
    trimesh.Trimesh
    """
    p = np.asarray(polygon, float)
    area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    if area < 0:
        p = p[::-1]
    zs = np.asarray(zs, float)
    k = len(zs)
    sc = np.asarray(scales, float)
    sc = np.broadcast_to(sc[:, None] if sc.ndim == 1 else sc, (k, 2))
    off = np.zeros((k, 2)) if offsets is None else np.asarray(offsets, float)
    pts = p[:, None, :] * sc[None, :, :] + off[None, :, :]
    grid = np.concatenate([pts, np.broadcast_to(zs[None, :, None], (len(p), k, 1))], -1)
    side, _ = grid_surface(grid, close_u=True)
    meshes = [side]
    tris = _ear_clip(p)
    n = len(p)
    if cap_bottom and np.all(sc[0] > 0):
        verts = np.column_stack([pts[:, 0], np.full(n, zs[0])])
        meshes.append(make_mesh(verts, tris[:, ::-1]))
    if cap_top and np.all(sc[-1] > 0):
        verts = np.column_stack([pts[:, -1], np.full(n, zs[-1])])
        meshes.append(make_mesh(verts, tris))
    return concat(meshes)
