"""Procedural category instances: API, determinism, variation, frame conventions and the viewpoint
structure of each category, measured on the geometry (no rendering)."""

import numpy as np
import pytest

from scrppl.datasets.synthetic import textures as tx
from scrppl.datasets.synthetic.shapes import CATEGORIES, Part, build_instance, instance_bounds

SEEDS = (0, 1, 2, 3, 4, 5)


def _by_name(parts, name):
    found = [p for p in parts if p.name == name]
    assert found, f"no part named {name!r} in {[p.name for p in parts]}"
    return found


def _verts(parts):
    return np.concatenate([np.asarray(p.mesh.vertices)[np.unique(p.mesh.faces)] for p in parts])


@pytest.fixture(scope="module")
def instances():
    return {(c, s): build_instance(c, s) for c in CATEGORIES for s in SEEDS}


def test_categories_are_the_savarese_ten():
    assert CATEGORIES == (
        "bicycle",
        "car",
        "cellphone",
        "head",
        "iron",
        "monitor",
        "mouse",
        "shoe",
        "stapler",
        "toaster",
    )


def test_unknown_category_and_bad_seed_raise():
    with pytest.raises(ValueError, match="unknown category 'airplane'"):
        build_instance("airplane", 0)
    with pytest.raises(ValueError, match="seed"):
        build_instance("car", -1)


@pytest.mark.parametrize("category", CATEGORIES)
def test_deterministic_from_seed(category, instances):
    a, b = instances[(category, 3)], build_instance(category, 3)
    assert [p.name for p in a] == [p.name for p in b]
    for pa, pb in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa.mesh.vertices, pb.mesh.vertices)
        np.testing.assert_array_equal(pa.mesh.faces, pb.mesh.faces)
        assert pa.color == pb.color and pa.specular == pb.specular
        if pa.texture is not None:
            np.testing.assert_array_equal(pa.texture, pb.texture)
            np.testing.assert_array_equal(pa.uv, pb.uv)


@pytest.mark.parametrize("category", CATEGORIES)
def test_instances_vary_with_seed(category, instances):
    """Different seeds give different proportions (bounding-box aspect ratios) and looks."""
    extents = np.array([np.ptp(instance_bounds(instances[(category, s)]), axis=0) for s in SEEDS])
    # the largest extent is normalised to 1, so variation shows in the other two ratios
    assert np.ptp(extents, axis=0).max() > 0.03, extents
    colors = {tuple(np.round(instances[(category, s)][0].color, 3)) for s in SEEDS}
    textures = {
        p.texture.tobytes()[:4096]
        for s in SEEDS
        for p in instances[(category, s)]
        if p.texture is not None
    }
    assert len(colors) + len(textures) > len(SEEDS), "instances look alike"


@pytest.mark.parametrize("category", CATEGORIES)
def test_frame_conventions(category, instances):
    for seed in SEEDS:
        parts = instances[(category, seed)]
        assert all(isinstance(p, Part) for p in parts)
        lo, hi = instance_bounds(parts)
        assert lo[2] == pytest.approx(0.0, abs=1e-9), "stands on z = 0"
        assert 0.5 * (lo[0] + hi[0]) == pytest.approx(0.0, abs=1e-9)
        assert 0.5 * (lo[1] + hi[1]) == pytest.approx(0.0, abs=1e-9)
        assert np.max(hi - lo) == pytest.approx(1.0, abs=1e-9)
        n_faces = sum(len(p.mesh.faces) for p in parts)
        assert 12 <= n_faces <= 6000, f"{category} {seed}: {n_faces} triangles"
        for p in parts:
            assert len(p.mesh.faces) > 0
            assert np.all(np.isfinite(p.mesh.vertices))
            assert np.all(np.isfinite(p.mesh.face_normals))
            assert np.all(np.isfinite(p.mesh.vertex_normals))
            assert np.all(p.mesh.faces < len(p.mesh.vertices))
            assert 0.0 <= p.specular <= 1.0
            assert len(p.color) == 3 and all(0.0 <= c <= 1.0 for c in p.color)
            if p.texture is not None:
                assert p.texture.dtype == np.uint8 and p.texture.ndim == 3
                assert p.texture.shape[2] == 3 and min(p.texture.shape[:2]) >= 8
                assert p.uv.shape == (len(p.mesh.vertices), 2)
                assert np.all((p.uv >= 0.0) & (p.uv <= 1.0))


@pytest.mark.parametrize("category", CATEGORIES)
def test_parts_face_outward(category, instances):
    """Each part's signed volume is positive: normals point out, so lighting is right.

    Parts are unions of closed surfaces (seam vertices duplicated for texturing) and flat decals;
    an inside-out surface would make the signed volume negative. Volumes are taken about a point
    inside the object, so an outward-facing decal counts positive.
    """
    for seed in SEEDS[:3]:
        parts = instances[(category, seed)]
        inside = _verts(parts).mean(0)  # a point inside the object, seen by every decal's front
        for p in parts:
            tri = np.asarray(p.mesh.vertices)[p.mesh.faces] - inside
            volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
            assert volume > -1e-12, f"{category} {seed} part {p.name!r} is inside out"


def _area_weighted_normal(mesh):
    return (np.asarray(mesh.face_normals) * np.asarray(mesh.area_faces)[:, None]).sum(0)


@pytest.mark.parametrize("category", ["monitor", "cellphone"])
def test_screen_faces_front_only(category, instances):
    for seed in SEEDS:
        parts = instances[(category, seed)]
        (screen,) = _by_name(parts, "screen")
        n = _area_weighted_normal(screen.mesh)
        n /= np.linalg.norm(n)
        assert n[0] > 0.9, n  # looks along +x (a phone leans back a little)
        # the screen sits on the front of the body (the phone's slab, the monitor's housing)
        body = [p for p in parts if p.name in ("body", "housing")][0]
        assert screen.mesh.vertices[:, 0].mean() > body.mesh.vertices[:, 0].mean() + 1e-3
        # no other textured part faces backwards with screen content
        for p in parts:
            if p.texture is not None and p is not screen:
                assert _area_weighted_normal(p.mesh)[0] >= -1e-9 or p.name in ("dock",)


def test_mouse_buttons_and_cable_at_front(instances):
    for seed in SEEDS:
        parts = instances[("mouse", seed)]
        (wheel,) = _by_name(parts, "wheel")
        (shell,) = _by_name(parts, "shell")
        xs = shell.mesh.vertices[:, 0]
        assert wheel.mesh.vertices[:, 0].mean() > 0.5 * (xs.min() + xs.max())
        for cable in [p for p in parts if p.name == "cable"]:
            assert cable.mesh.vertices[:, 0].min() > xs.max() - 0.02
        # the highest point of the body is behind its middle
        top = shell.mesh.vertices[np.argmax(shell.mesh.vertices[:, 2])]
        assert top[0] < 0.5 * (xs.min() + xs.max())


@pytest.mark.parametrize("normal", ["+x", "-x", "+y", "-y"])
def test_decal_quads_are_not_mirrored(normal):
    """A texture on a quad reads correctly for a viewer facing it: u = 0 on the viewer's left,
    v = 0 at the bottom (so labels and screens are never mirrored or upside down)."""
    from scrppl.datasets.synthetic.categories import _mesh

    quad, uv = _mesh.quad((0.0, 0.0, 0.0), normal, 2.0, 1.0)
    n = {"+x": [1, 0, 0], "-x": [-1, 0, 0], "+y": [0, 1, 0], "-y": [0, -1, 0]}[normal]
    np.testing.assert_allclose(quad.face_normals, np.tile(n, (2, 1)), atol=1e-12)
    # a viewer at +n looking back along -n, up +z: their right is (-n) x z
    right = np.cross(-np.asarray(n, float), [0.0, 0.0, 1.0])
    v = np.asarray(quad.vertices)
    np.testing.assert_allclose(np.sign(v @ right), 2 * uv[:, 0] - 1)
    np.testing.assert_allclose(np.sign(v[:, 2]), 2 * uv[:, 1] - 1)


def test_textures_are_deterministic_and_seed_dependent():
    for fn in (
        lambda s: tx.screen(s, 60, 80),
        lambda s: tx.phone_screen(s, 80, 40),
        lambda s: tx.label(s, (1, 1, 1), (0, 0, 0)),
        lambda s: tx.tread(s),
        lambda s: tx.face(s, (0.8, 0.6, 0.5), (0.2, 0.1, 0.05)),
        lambda s: tx.wood(s),
    ):
        a, b, c = fn(7), fn(7), fn(8)
        assert a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] == 3
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)
    with pytest.raises(ValueError, match="screen kind"):
        tx.screen(0, kind="hologram")


def test_face_texture_puts_the_face_at_the_centre_column():
    """u = 0.5 is the face (+x): skin with dark pupils there, hair at the back (u = 0 and 1)."""
    skin, hair = np.array([0.8, 0.6, 0.5]), np.array([0.2, 0.1, 0.05])
    img = tx.face(3, skin, hair, "long").astype(float) / 255.0
    h, w = img.shape[:2]
    band = img[h // 3 : 2 * h // 3]  # between the mouth and the eyebrows
    centre = band[:, int(0.4 * w) : int(0.6 * w)].reshape(-1, 3)
    back = np.concatenate([band[:, : int(0.08 * w)], band[:, int(0.92 * w) :]], 1).reshape(-1, 3)
    np.testing.assert_allclose(np.median(centre, 0), skin, atol=0.08)
    np.testing.assert_allclose(np.median(back, 0), hair, atol=0.08)
    assert centre.max(1).min() < 0.15  # pupils


def _extent(parts):
    return np.ptp(_verts(parts), axis=0)


def test_bicycle_is_thin_from_the_front_and_lies_in_the_xz_plane(instances):
    for seed in SEEDS:
        parts = instances[("bicycle", seed)]
        ex = _extent(parts)
        assert ex[0] == pytest.approx(1.0) and ex[1] < 0.45 * ex[0], ex
        # the wheels (tyres) are discs in the xz plane: tiny y extent, large x and z extents
        (tyres,) = _by_name(parts, "tyres")
        tex = np.ptp(tyres.mesh.vertices, axis=0)
        assert tex[1] < 0.1 * tex[2] and tex[0] > 0.9
        # the handlebar (fittings) is at the front, the saddle behind the middle
        (saddle,) = _by_name(parts, "saddle")
        assert saddle.mesh.vertices[:, 0].min() < 0.0
        (fittings,) = _by_name(parts, "fittings")
        assert fittings.mesh.vertices[:, 0].max() > 0.1


def _mirror_x_similarity(parts, bins=12):
    """How alike the silhouettes seen from +x and -x are: 1 = the object is front/back symmetric.

    Compares the occupancy of (y, z) cells by the front half and by the back half of the object.
    """
    v = _verts(parts)
    front, back = v[v[:, 0] > 0], v[v[:, 0] < 0]
    lo, hi = v[:, 1:].min(0), v[:, 1:].max(0) + 1e-9
    occ = []
    for half in (front, back):
        cells = np.floor((half[:, 1:] - lo) / (hi - lo) * bins).astype(int)
        grid = np.zeros((bins, bins), bool)
        grid[cells[:, 0], cells[:, 1]] = True
        occ.append(grid)
    return (occ[0] & occ[1]).sum() / (occ[0] | occ[1]).sum()


def test_car_front_and_back_alike_but_unlike_the_side(instances):
    for seed in SEEDS:
        parts = instances[("car", seed)]
        ex = _extent(parts)
        assert ex[0] == pytest.approx(1.0) and 0.3 < ex[1] < 0.55 and ex[2] < 0.5
        # lights at both ends, at similar heights, lateral positions mirrored
        (heads,) = _by_name(parts, "headlights")
        (tails,) = _by_name(parts, "taillights")
        assert heads.mesh.vertices[:, 0].min() > 0.45 and tails.mesh.vertices[:, 0].max() < -0.45
        np.testing.assert_allclose(
            np.ptp(heads.mesh.vertices[:, 1]), np.ptp(tails.mesh.vertices[:, 1]), rtol=0.05
        )
        # plates on both ends, wheels and mirrors on the sides
        _by_name(parts, "front_plate"), _by_name(parts, "rear_plate")
        (tyres,) = _by_name(parts, "tyres")
        ty = tyres.mesh.vertices
        assert (ty[:, 1] > 0.1).any() and (ty[:, 1] < -0.1).any()
        assert (ty[:, 0] > 0.2).any() and (ty[:, 0] < -0.2).any()
        assert _mirror_x_similarity(parts) > 0.7  # 0.75-1.0 over 30 seeds; shoes 0.08-0.47


def test_iron_cord_on_one_side_and_pointed_front(instances):
    for seed in SEEDS:
        parts = instances[("iron", seed)]
        (cord,) = _by_name(parts, "cord")
        (sole,) = _by_name(parts, "soleplate")
        v = sole.mesh.vertices
        cy = 0.5 * (v[:, 1].min() + v[:, 1].max())  # the iron's midline
        assert cord.mesh.vertices[:, 1].max() - cy > 0.1  # the cord leaves to the left (+y) ...
        assert cord.mesh.vertices[:, 1].mean() - cy > 0.03  # ... and never to the right
        assert cord.mesh.vertices[:, 1].min() - cy > -0.07  # (its plug's thickness aside)
        xs = v[:, 0]
        width_front = np.ptp(v[xs > xs.min() + 0.85 * np.ptp(xs), 1])
        width_back = np.ptp(v[xs < xs.min() + 0.15 * np.ptp(xs), 1])
        assert width_front < 0.5 * width_back  # the nose (+x) is pointed, the back flat


def test_toaster_lever_on_one_end_label_on_front(instances):
    for seed in SEEDS:
        parts = instances[("toaster", seed)]
        (lever,) = _by_name(parts, "lever")
        (body,) = _by_name(parts, "body")
        assert lever.mesh.vertices[:, 1].min() > body.mesh.vertices[:, 1].max() - 0.05
        (label,) = _by_name(parts, "label")
        n = _area_weighted_normal(label.mesh)
        assert n[0] > 0.99 * np.linalg.norm(n)


def test_stapler_front_differs_from_back(instances):
    for seed in SEEDS:
        parts = instances[("stapler", seed)]
        (arm,) = _by_name(parts, "arm")
        v = arm.mesh.vertices
        x = v[:, 0]
        h_front = v[x > x.min() + 0.8 * np.ptp(x), 2].max()
        h_back = v[x < x.min() + 0.2 * np.ptp(x), 2].max()
        (base,) = _by_name(parts, "base")
        z0 = base.mesh.vertices[:, 2].max()
        assert h_front - z0 > 1.1 * (h_back - z0)  # the arm climbs from the hinge to the head
        (magazine,) = _by_name(parts, "magazine")  # the anvil at the front
        assert magazine.mesh.vertices[:, 0].max() > x.max() - 0.02


def test_head_faces_plus_x(instances):
    for seed in SEEDS:
        parts = instances[("head", seed)]
        (face,) = _by_name(parts, "face")
        v, uv = np.asarray(face.mesh.vertices), face.uv
        # the nose is the head's most forward point, and the texture's face column (u = 0.5) is there
        tip = np.argmax(v[:, 0])
        assert abs(uv[tip, 0] - 0.5) < 0.05
        cx, cy = 0.5 * (v[:, 0].max() + v[:, 0].min()), 0.5 * (v[:, 1].max() + v[:, 1].min())
        assert v[tip, 0] - cx > 1.05 * (v[:, 1].max() - cy)  # the nose sticks out beyond the skull
        # texture coordinates with u near 0.5 lie on the +x side; near 0 or 1 on the -x side
        front = v[np.abs(uv[:, 0] - 0.5) < 0.2, 0].mean()
        back = v[np.abs(uv[:, 0] - 0.5) > 0.3, 0].mean()
        assert front - back > 0.3 * np.ptp(v[:, 0])
        # shoulders are wide along y (seen from the front), narrow along x
        (torso,) = _by_name(parts, "torso")
        t = np.ptp(torso.mesh.vertices, axis=0)
        assert t[1] > 2 * t[0]


def test_shoe_toe_front_heel_back(instances):
    for seed in SEEDS:
        parts = instances[("shoe", seed)]
        v = _verts(parts)
        x = v[:, 0]
        front = v[x > x.min() + 0.75 * np.ptp(x)]
        back = v[x < x.min() + 0.25 * np.ptp(x)]
        assert back[:, 2].max() > 1.3 * front[:, 2].max()  # low toe, high heel/collar/shaft
        (opening,) = _by_name(parts, "opening")
        assert opening.mesh.vertices[:, 0].mean() < 0.5 * (
            x.min() + x.max()
        )  # the opening is at the back
        assert _mirror_x_similarity(parts) < 0.55  # 0.08-0.47 over 30 seeds; cars 0.75-1.0


@pytest.mark.parametrize("facing", [1, -1])
def test_wheel_discs_face_outward_and_are_not_mirrored(facing):
    from scrppl.datasets.synthetic.categories import _mesh

    disc, uv = _mesh.disc_y((0.0, 0.0, 0.0), 1.0, facing, 12)
    np.testing.assert_allclose(disc.face_normals[:, 1], facing, atol=1e-12)
    right = np.cross([0.0, -facing, 0.0], [0.0, 0.0, 1.0])  # the facing viewer's right
    v = np.asarray(disc.vertices)
    np.testing.assert_allclose(uv[:, 0] - 0.5, 0.5 * (v @ right), atol=1e-12)
    np.testing.assert_allclose(uv[:, 1] - 0.5, 0.5 * v[:, 2], atol=1e-12)
