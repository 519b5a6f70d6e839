"""The view grid and relative viewpoint (`scrppl.views`), checked against brute force and known answers."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from scrppl.views import (
    SAVARESE_GRID,
    ViewGrid,
    angular_distance,
    azimuth_degrees,
    degrees_to_azimuth,
    object_azimuth,
    relative_azimuth,
    wrap_degrees,
)


# -- relative azimuth -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("robot", "pose", "expected"),
    [
        (0, 0, 0),
        (3, 1, 2),
        (1, 3, 6),  # robot "behind" the pose wraps counter-clockwise
        (0, 7, 1),
        (-1, 0, 7),  # negative robot azimuth
        (-9, 0, 7),  # more than one turn negative
        (17, 0, 1),  # more than one turn positive
        (2, -3, 5),  # negative pose
        (8, 8, 0),
    ],
)
def test_relative_azimuth_known_answers(robot, pose, expected):
    assert relative_azimuth(robot, pose) == expected
    assert object_azimuth(robot, expected) == pose % 8


def test_relative_azimuth_matches_angle_arithmetic():
    """(phi - theta) mod A equals the bin of the angle difference in degrees, for every pair."""
    for n in (4, 8, 12):
        phi, theta = np.meshgrid(np.arange(-2 * n, 2 * n), np.arange(-n, 2 * n), indexing="ij")
        rel = relative_azimuth(phi, theta, n)
        deg = (phi * 360.0 / n) - (theta * 360.0 / n)
        assert np.array_equal(rel, degrees_to_azimuth(deg, n))
        assert rel.min() >= 0 and rel.max() < n
        # object_azimuth inverts it: the pose that makes phi see rel is theta (mod A)
        assert np.array_equal(object_azimuth(phi, rel, n), theta % n)


def test_relative_azimuth_works_under_jit():
    f = jax.jit(lambda p, t: relative_azimuth(p, t, 8))
    out = f(jnp.array([-1, 0, 9]), jnp.array([0, 3, 0]))
    assert out.tolist() == [7, 5, 1]


# -- degrees <-> bins -------------------------------------------------------------------------------
def test_azimuth_degrees_and_wrap():
    assert azimuth_degrees(np.arange(8)).tolist() == [0, 45, 90, 135, 180, 225, 270, 315]
    assert azimuth_degrees(-1) == 315.0
    assert azimuth_degrees(9) == 45.0
    assert azimuth_degrees(3, 12) == 90.0
    assert wrap_degrees(-30.0) == 330.0
    assert wrap_degrees(725.0) == 5.0
    assert SAVARESE_GRID.azimuth_degrees.tolist() == azimuth_degrees(np.arange(8)).tolist()
    assert SAVARESE_GRID.step_degrees == 45.0


@pytest.mark.parametrize(
    ("deg", "expected"),
    [
        (0.0, 0),
        (22.4, 0),
        (22.6, 1),
        (44.0, 1),
        (-22.4, 0),
        (-22.6, 7),
        (-45.0, 7),
        (337.6, 0),
        (359.9, 0),
        (360.0, 0),
        (405.0, 1),
        (-720.0 + 90.0, 2),
    ],
)
def test_degrees_to_azimuth_nearest_bin(deg, expected):
    assert int(degrees_to_azimuth(deg)) == expected


def test_degrees_to_azimuth_is_nearest_by_brute_force():
    rng = np.random.default_rng(0)
    deg = rng.uniform(-1000, 1000, size=2000)
    for n in (3, 8, 16):
        centres = np.arange(n) * 360.0 / n
        diff = np.abs((deg[:, None] - centres[None, :] + 180.0) % 360.0 - 180.0)
        assert np.array_equal(degrees_to_azimuth(deg, n), diff.argmin(axis=1))
        # round trip from bin centres
        assert np.array_equal(degrees_to_azimuth(azimuth_degrees(np.arange(n), n), n), np.arange(n))


# -- angular distance -------------------------------------------------------------------------------
def test_angular_distance_brute_force():
    for n in (1, 2, 5, 8, 9):
        for a, b in itertools.product(range(-n, 2 * n), repeat=2):
            # shortest number of single-bin steps from a to b, either way around the circle
            steps = min(k for k in range(n + 1) if (a + k - b) % n == 0 or (a - k - b) % n == 0)
            assert angular_distance(a, b, n) == steps, (n, a, b)


def test_angular_distance_properties_and_jit():
    a, b = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    d = angular_distance(a, b)
    assert np.array_equal(d, d.T)
    assert np.all(np.diag(d) == 0)
    assert d.max() == 4
    assert angular_distance(0, 4) == 4 and angular_distance(1, 7) == 2
    jd = jax.jit(angular_distance, static_argnums=2)(jnp.asarray(a), jnp.asarray(b), 8)
    assert np.array_equal(np.asarray(jd), d)


# -- the grid -------------------------------------------------------------------------------------
def test_default_grid_shape():
    g = ViewGrid()
    assert g.shape == (8, 3, 3)
    assert g.n_views == 72
    assert g.n_elevation == 3 and g.n_scale == 3
    assert g == SAVARESE_GRID


@pytest.mark.parametrize("grid", [ViewGrid(), ViewGrid(4, (0.0,), (1.0, 2.0)), ViewGrid(5, (1, 2))])
def test_view_index_round_trip(grid):
    views = grid.all_views()
    assert views.shape == (grid.n_views, 3)
    flat = grid.view_index(views[:, 0], views[:, 1], views[:, 2])
    # all_views is in flat-index order and the index is a bijection onto 0..n_views-1
    assert np.array_equal(flat, np.arange(grid.n_views))
    a, e, s = grid.view_from_index(np.arange(grid.n_views))
    assert np.array_equal(np.stack([a, e, s], 1), views)
    # azimuth-major: matches C-order ravel of an (A, E, S) array
    cube = np.arange(grid.n_views).reshape(grid.shape)
    assert np.array_equal(cube[views[:, 0], views[:, 1], views[:, 2]], flat)
    for i in (0, grid.n_views - 1):
        assert grid.view_index(*grid.view_from_index(i)) == i


@pytest.mark.parametrize(
    ("a", "e", "s", "word"),
    [
        (8, 0, 0, "azimuth"),
        (-1, 0, 0, "azimuth"),
        (0, 3, 0, "elevation"),
        (0, 0, 3, "scale"),
        (np.array([0, 9]), 0, 0, "azimuth"),
        (0.0, 0, 0, "integer"),
    ],
)
def test_check_rejects_out_of_grid(a, e, s, word):
    with pytest.raises(ValueError, match=word):
        SAVARESE_GRID.check(a, e, s)
    with pytest.raises(ValueError, match=word):
        SAVARESE_GRID.view_index(a, e, s)


def test_check_accepts_grid_values_and_empty():
    SAVARESE_GRID.check(np.arange(8), np.array([0, 2]), np.array([2, 1]))
    SAVARESE_GRID.check(np.array([], dtype=int), np.array([], dtype=int), np.array([], dtype=int))


@pytest.mark.parametrize("index", [-1, 72, np.array([0, 80])])
def test_view_from_index_out_of_range(index):
    with pytest.raises(ValueError, match="out of range"):
        SAVARESE_GRID.view_from_index(index)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_azimuth": 0},
        {"n_azimuth": 2.5},
        {"elevations": ()},
        {"scales": ()},
    ],
)
def test_grid_validation(kwargs):
    with pytest.raises(ValueError):
        ViewGrid(**kwargs)


@pytest.mark.parametrize("n", [8.0, np.int64(8), np.float32(8)])
def test_integral_non_int_azimuth_count_is_stored_as_int(n):
    """ViewGrid(8.0) or a NumPy integer must behave exactly like ViewGrid(8) (and serialise to JSON)."""
    import json

    g = ViewGrid(n)
    assert type(g.n_azimuth) is int and g == ViewGrid(8)
    views = g.all_views()
    assert views.dtype.kind == "i"
    assert np.array_equal(g.view_index(views[:, 0], views[:, 1], views[:, 2]), np.arange(72))
    assert json.loads(json.dumps(g.to_dict()))["n_azimuth"] == 8


def test_grid_dict_round_trip_and_float_coercion():
    g = ViewGrid(6, (5, 15), (1, 2, 3))
    assert g.elevations == (5.0, 15.0) and all(isinstance(x, float) for x in g.scales)
    assert ViewGrid.from_dict(g.to_dict()) == g
    import json

    assert ViewGrid.from_dict(json.loads(json.dumps(g.to_dict()))) == g
