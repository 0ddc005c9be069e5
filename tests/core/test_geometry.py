"""Sub-sensor arrays: ring, sphere grid and Fibonacci lattice, plate, user arrays."""

from __future__ import annotations

import numpy as np
import pytest

from olsbayes import InputError, Plate, Ring, SensorArray, Sphere, wrap_angle


def test_wrap_angle_range_and_endpoints():
    x = np.linspace(-20, 20, 4001)
    w = wrap_angle(x)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(x), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(x), atol=1e-12)
    assert wrap_angle(np.pi) == np.pi
    assert wrap_angle(-np.pi) == np.pi
    assert wrap_angle(0.0) == 0.0


@pytest.mark.parametrize("n", [1, 7, 64, 65, 4001])
def test_wrap_angle_is_pi_minus_numpy_mod_to_the_bit_few_angles_or_many(n):
    """A few angles take numpy's mod itself, many its in-place equivalent: both give
    pi - mod(pi - x, 2 pi) bit for bit, multiples of 2 pi and huge angles included."""
    x = np.random.default_rng(n).normal(0.0, 50.0, n)
    x[: min(n, 6)] = [np.pi, -np.pi, 4 * np.pi, -3 * np.pi, 1e17, -0.0][: min(n, 6)]
    w = wrap_angle(x)
    assert w.tobytes() == (np.pi - np.mod(np.pi - x, 2 * np.pi)).tobytes()


def test_ring_normals_at_offset_plus_equal_steps():
    ring = Ring(8, offset=0.25)
    assert ring.n_sensors == 8 and len(ring) == 8
    assert ring.source_kind == "angle" and ring.n_source_params == 1
    np.testing.assert_allclose(ring.angles, wrap_angle(0.25 + 2 * np.pi * np.arange(8) / 8))
    np.testing.assert_allclose(np.linalg.norm(ring.normals, axis=1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(np.arctan2(ring.normals[:, 1], ring.normals[:, 0]), ring.angles,
                               atol=1e-15)
    assert ring.spacing == pytest.approx(np.pi / 4)
    assert not ring.normals.flags.writeable


@pytest.mark.parametrize("bad", [2, 0, -5, 3.5, "30", True, None])
def test_ring_rejects_bad_n(bad):
    with pytest.raises(InputError, match="n"):
        Ring(bad)


def test_sphere_grid_of_fig2_convention():
    """Fig. 2: 15 x 20 = 300 sub-sensors within +-pi longitude, +-pi/2.05 latitude."""
    sph = Sphere.grid(15, 20, np.pi / 2.05)
    assert sph.n_sensors == 300 and sph.source_kind == "lonlat"
    lat = np.unique(np.round(sph.lat, 12))
    lon = np.unique(np.round(sph.lon, 12))
    assert lat.size == 15 and lon.size == 20  # no duplicated meridian at +-pi
    assert lat.min() == pytest.approx(-np.pi / 2.05) and lat.max() == pytest.approx(np.pi / 2.05)
    np.testing.assert_allclose(np.diff(np.sort(lon)), 2 * np.pi / 20, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(sph.normals, axis=1), 1.0, rtol=1e-15)
    # latitude-major order: the first n_lon entries share the lowest latitude
    np.testing.assert_allclose(sph.lat[:20], -np.pi / 2.05)


def test_sphere_grid_partial_longitude_range_includes_both_ends():
    sph = Sphere.grid(3, 5, 0.5, lon_range=(-1.0, 1.0))
    np.testing.assert_allclose(np.unique(np.round(sph.lon, 12)), np.linspace(-1, 1, 5))


def test_fibonacci_sphere_is_near_uniform():
    sph = Sphere.fibonacci(2000)
    n = sph.normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-14)
    # the mean of uniformly spread unit vectors vanishes; the second moment is I/3
    assert np.abs(n.mean(axis=0)).max() < 2e-3
    np.testing.assert_allclose(n.T @ n / len(n), np.eye(3) / 3, atol=2e-3)
    assert np.all(np.abs(sph.lat) <= np.pi / 2)


def test_plate_grid_centred_facing_z():
    plate = Plate.grid(3, 4, pitch=0.5)
    assert plate.n_sensors == 12 and plate.source_kind == "position"
    assert plate.n_source_params == 3 and plate.pitch == 0.5
    np.testing.assert_allclose(plate.positions.mean(axis=0), 0.0, atol=1e-15)
    np.testing.assert_allclose(plate.normals, np.tile([0.0, 0.0, 1.0], (12, 1)))
    xs = np.unique(plate.positions[:, 0])
    np.testing.assert_allclose(np.diff(xs), 0.5)


def test_sensor_array_normalises_and_compares():
    a = SensorArray([[2.0, 0.0], [0.0, 3.0], [-1.0, -1.0]])
    np.testing.assert_allclose(np.linalg.norm(a.normals, axis=1), 1.0)
    assert a == SensorArray([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]])
    assert a != Ring(3)
    assert a.source_kind == "angle"
    b = SensorArray(np.eye(3), positions=np.zeros((3, 3)))
    assert b.source_kind == "position" and b.positions.shape == (3, 3)


@pytest.mark.parametrize(
    "normals,positions,match",
    [
        ([[1.0, 0.0], [0.0, 1.0]], None, "n >= 3"),
        ([[1.0, 0.0, 0.0, 0.0]] * 3, None, r"\(N, 2\) or \(N, 3\)"),
        ([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], None, "non-zero"),
        ([[np.nan, 0.0], [1.0, 0.0], [0.0, 1.0]], None, "finite"),
        ([1.0, 0.0, 1.0], None, "dimension"),
        ([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], np.zeros((3, 3)), "3-D normals"),
        (np.eye(3), np.zeros((2, 3)), "positions"),
    ],
)
def test_sensor_array_rejects_bad_input(normals, positions, match):
    with pytest.raises(InputError, match=match):
        SensorArray(normals, positions)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(n_lat=0, n_lon=5), "n_lat"),
        (dict(n_lat=1, n_lon=2), ">= 3"),
        (dict(n_lat=3, n_lon=3, lat_max=2.0), "lat_max"),
        (dict(n_lat=3, n_lon=3, lon_range=(1.0, -1.0)), "lon_range"),
        (dict(n_lat=3, n_lon=3, lon_range=(-4.0, 4.0)), "lon_range"),
    ],
)
def test_sphere_grid_rejects_bad_input(kwargs, match):
    with pytest.raises(InputError, match=match):
        Sphere.grid(**kwargs)


def test_sphere_rejects_latitude_outside_range():
    with pytest.raises(InputError, match="lat"):
        Sphere(np.zeros(3), np.array([0.0, 0.1, 1.6]))


def test_plate_rejects_bad_pitch():
    with pytest.raises(InputError, match="pitch"):
        Plate.grid(3, 3, pitch=0.0)
    with pytest.raises(InputError, match=">= 3"):
        Plate.grid(1, 2)
