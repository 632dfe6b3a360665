"""Camera, laser and in-water plane geometry."""

import numpy as np
import pytest
from conftest import plane_grid
from numpy.testing import assert_allclose

from workers.setup.geometry import (
    LaserRays,
    PinholeCamera,
    fast_length,
    flat_sea_point,
    footprint_length,
    pan_tilt_rotation,
)

N_WATER = 1.34


def camera(*, nadir_deg=0.0, azimuth_deg=0.0, altitude=34.0, pixels=16, fov_deg=6.7):
    nadir, azimuth = np.radians(nadir_deg), np.radians(azimuth_deg)
    reach = altitude * np.tan(nadir)
    return PinholeCamera(
        position=(-reach * np.sin(azimuth), -reach * np.cos(azimuth), altitude),
        nadir=nadir,
        azimuth=azimuth,
        field_of_view=np.radians(fov_deg),
        pixels=pixels,
    )


def test_footprint_at_nadir_is_the_pinhole_closed_form():
    alpha = np.radians(6.7)
    assert_allclose(
        footprint_length(altitude=34.0, field_of_view=alpha, nadir=0.0),
        2 * 34.0 * np.tan(alpha / 2),
        rtol=1e-12,
    )


@pytest.mark.parametrize("nadir_deg", [10.0, 30.0, 60.0], ids=lambda d: f"nadir{d:g}")
def test_footprint_solves_the_papers_equations(nadir_deg):
    # Paper §4.2: alpha = atan((L1 - x)/h) + atan(x/h) with tan(theta) = (L1/2 - x)/h.
    h, alpha, theta = 34.0, np.radians(6.7), np.radians(nadir_deg)
    L1 = footprint_length(altitude=h, field_of_view=alpha, nadir=theta)
    x = L1 / 2 - h * np.tan(theta)
    assert_allclose(np.arctan((L1 - x) / h) + np.arctan(x / h), alpha, rtol=1e-10)


def test_footprint_paper_formula_underestimates_the_exact_strip_at_60_deg():
    h, alpha, theta = 34.0, np.radians(6.7), np.radians(60.0)
    exact = h * (np.tan(theta + alpha / 2) - np.tan(theta - alpha / 2))
    paper = footprint_length(altitude=h, field_of_view=alpha, nadir=theta)
    assert 0.97 < paper / exact < 0.99  # the 2 % bias stated in the docstring


def test_rotation_is_proper_orthogonal():
    R = pan_tilt_rotation(pan=0.3, tilt=2.1)
    assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert_allclose(np.linalg.det(R), 1.0, rtol=1e-14)


@pytest.mark.parametrize(
    ("nadir_deg", "azimuth_deg"), [(0, 0), (20, 45), (60, 200)], ids=["nadir", "20-45", "60-200"]
)
def test_projection_matches_the_papers_explicit_formula(nadir_deg, azimuth_deg):
    cam = camera(nadir_deg=nadir_deg, azimuth_deg=azimuth_deg)
    rng = np.random.default_rng(1)
    points = rng.uniform(-3, 3, (50, 3)) + np.array([0.0, 0.0, -2.0])
    pan, tilt, lam = -cam.azimuth, np.pi + cam.nadir, cam.focal_length
    X0, Y0, Z0 = np.asarray(cam.position) - lam * cam.rotation[2]
    X, Y, Z = points.T
    den = (
        -(X - X0) * np.sin(pan) * np.sin(tilt)
        + (Y - Y0) * np.cos(pan) * np.sin(tilt)
        - (Z - Z0) * np.cos(tilt)
        + lam
    )
    x = lam * ((X - X0) * np.cos(pan) + (Y - Y0) * np.sin(pan)) / den
    y = (
        lam
        * (
            -(X - X0) * np.sin(pan) * np.cos(tilt)
            + (Y - Y0) * np.cos(pan) * np.cos(tilt)
            + (Z - Z0) * np.sin(tilt)
        )
        / den
    )
    px, py = cam.project(points)
    assert_allclose(px, x, rtol=1e-10, atol=1e-15)
    assert_allclose(py, y, rtol=1e-10, atol=1e-15)


@pytest.mark.parametrize(
    ("nadir_deg", "azimuth_deg"), [(0, 0), (35, 120)], ids=["nadir", "oblique"]
)
def test_pixel_rays_project_back_to_their_pixels(nadir_deg, azimuth_deg):
    cam = camera(nadir_deg=nadir_deg, azimuth_deg=azimuth_deg, pixels=8)
    points = np.asarray(cam.position) + 20.0 * cam.pixel_directions()
    row, col = cam.pixel_of(*cam.project(points))
    rows, cols = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    assert_allclose(row, rows, atol=1e-9)
    assert_allclose(col, cols, atol=1e-9)


def test_nadir_image_is_a_map_north_up_east_right():
    d = camera(pixels=8).pixel_directions()
    assert d[0, 4, 1] > 0 > d[-1, 4, 1]  # top row looks north
    assert d[4, -1, 0] > 0 > d[4, 0, 0]  # right column looks east
    assert np.all(d[..., 2] < 0)


@pytest.mark.parametrize("azimuth_deg", [0.0, 90.0, 225.0], ids=lambda a: f"az{a:g}")
def test_central_ray_has_the_requested_nadir_and_azimuth(azimuth_deg):
    cam = camera(nadir_deg=40.0, azimuth_deg=azimuth_deg)
    axis = cam.rotation[2]
    assert_allclose(np.degrees(np.arccos(-axis[2])), 40.0, rtol=1e-12)
    assert_allclose(np.degrees(np.arctan2(axis[0], axis[1])) % 360, azimuth_deg % 360, atol=1e-9)
    # it meets mean sea level at the world origin
    hit = flat_sea_point(origin=cam.position, direction=axis, depth=0.0, refractive_index=N_WATER)
    assert_allclose(hit, [0, 0, 0], atol=1e-12)


def test_flat_sea_point_obeys_snell():
    origin = np.array([0.0, 0.0, 10.0])
    theta = np.radians(30.0)
    d = np.array([np.sin(theta), 0.0, -np.cos(theta)])
    p = flat_sea_point(origin=origin, direction=d, depth=5.0, refractive_index=N_WATER)
    entry = 10.0 * np.tan(theta)
    theta_w = np.arctan((p[0] - entry) / 5.0)
    assert_allclose(np.sin(theta), N_WATER * np.sin(theta_w), rtol=1e-12)


@pytest.mark.parametrize("beam", ["divergent", "parallel"])
def test_laser_profile_and_power(beam):
    cam = camera(pixels=8)
    rays = 64
    fov = cam.field_of_view
    laser = LaserRays.from_platform(
        position=cam.position,
        rotation=cam.rotation,
        beam=beam,
        field_of_view=fov,
        rays=rays,
        reference_range=34.0,
    )
    # Each ray carries J exp(-r²/a²) times its cross-section cell at the reference range.
    cell = (34.0 * 2 * np.tan(fov / 2) / rays) ** 2
    assert_allclose(laser.power.max(), cell * np.exp(-2 * (0.5 / rays * 2) ** 2), rtol=1e-3)
    # r = a at the middle of the field's edge: the profile is e^-1 there (to half a ray).
    grid = laser.power.reshape(rays, rays) / cell
    assert_allclose(grid[rays // 2, 0], np.exp(-1), rtol=0.05)
    assert np.all(laser.directions[:, 2] < 0)
    if beam == "parallel":
        assert_allclose(laser.directions, np.broadcast_to(cam.rotation[2], laser.directions.shape))
    else:
        assert_allclose(laser.origins, np.broadcast_to(cam.position, laser.origins.shape))


def test_plane_grid_cells_match_central_pixel_and_cover_the_footprint():
    cam = camera(pixels=32)
    grid = plane_grid(cam, depth=5.0)
    rows, cols = grid.shape
    assert rows % 2 == 0 and cols % 2 == 0 and rows >= 32 + 8
    rays = cam.pixel_directions().reshape(-1, 3)
    hits = flat_sea_point(origin=cam.position, direction=rays, depth=5.0, refractive_index=N_WATER)
    r, c = grid.cell_coordinates(hits[:, 0], hits[:, 1])
    assert r.min() > 3 and c.min() > 3 and r.max() < rows - 4 and c.max() < cols - 4
    # neighbouring pixels land one cell apart at the image centre
    assert_allclose(np.diff(c.reshape(32, 32)[16, 15:17]), 1.0, rtol=1e-4)


def test_splat_conserves_power_and_gather_is_exact_on_linear_fields():
    cam = camera(pixels=16)
    grid = plane_grid(cam, depth=3.0)
    x0, y0 = grid.cell_centres()
    rng = np.random.default_rng(3)
    x = rng.uniform(x0.min() + 0.1, x0.max() - 0.1, 1000)
    y = rng.uniform(y0.min() + 0.1, y0.max() - 0.1, 1000)
    power = rng.uniform(0.5, 1.5, 1000)
    field = grid.splat(grid.locate(x, y), power)
    assert_allclose(field.sum() * grid.spacing_u * grid.spacing_v, power.sum(), rtol=1e-5)
    linear = (2.0 * x0 - 3.0 * y0 + 1.0).astype(np.float32)
    assert_allclose(
        grid.gather(linear, grid.locate(x, y)), 2.0 * x - 3.0 * y + 1.0, rtol=1e-4, atol=1e-4
    )


@pytest.mark.parametrize("rays", [32, 33], ids=["even", "odd"])
def test_the_traced_lattice_and_the_beam_tail_carry_the_whole_beam(rays):
    # I0 = J e^(-r²/a²) carries π a² J in all (J = 1 at the reference range); the traced
    # lattice and its tail tile the tangent plane, so together they carry it but for the
    # share beyond the tail's extent (e^(-ext²) at most, for a disc of that radius).
    cam = camera(pixels=rays)
    common = dict(
        position=cam.position,
        rotation=cam.rotation,
        beam="divergent",
        field_of_view=cam.field_of_view,
        reference_range=cam.position[2],
    )
    traced = LaserRays.from_platform(**common, rays=rays, margin=8)
    step = 2 * np.tan(0.5 * cam.field_of_view) / rays
    tail = LaserRays.beam_tail(
        **common,
        inner=(0.5 * rays + 8) * step,
        step=(2 if rays % 2 == 0 else 1) * step,
        extent=3.0,
    )
    a = cam.position[2] * np.tan(0.5 * cam.field_of_view)
    total = traced.power.sum() + tail.power.sum()
    assert_allclose(total, np.pi * a**2, rtol=2e-3)


@pytest.mark.parametrize("offset", [0.0, 0.25, 0.5])
@pytest.mark.parametrize("rays", [32, 33], ids=["even", "odd"])
def test_an_offset_lattice_and_its_tail_tile_the_beam(rays, offset):
    # shifted by `offset` steps (workers.setup.sensor.lattice_offset), the traced square's cells
    # end where the tail's begin, on every side
    cam = camera(pixels=rays)
    common = dict(
        position=cam.position,
        rotation=cam.rotation,
        beam="divergent",
        field_of_view=cam.field_of_view,
        reference_range=cam.position[2],
    )
    step = 2 * np.tan(0.5 * cam.field_of_view) / rays
    tail_step = (2 if rays % 2 == 0 else 1) * step
    traced = LaserRays.from_platform(**common, rays=rays, margin=8, offset=offset)
    tail = LaserRays.beam_tail(
        **common,
        inner=(0.5 * rays + 8) * step,
        step=tail_step,
        extent=3.0,
        centre=offset * step,
    )

    def tangents(lattice):
        local = lattice.directions @ cam.rotation.T
        return local[:, :2] / local[:, 2:] - offset * step

    inner = (0.5 * rays + 8) * step
    assert_allclose(np.abs(tangents(traced)).max(axis=0) + 0.5 * step, inner, rtol=1e-9)
    assert_allclose(np.abs(tangents(tail)).max(axis=1).min() - 0.5 * tail_step, inner, rtol=1e-9)
    for axis in (0, 1):
        shifted = tangents(traced)[:, axis]
        assert_allclose(shifted.max(), -shifted.min(), rtol=1e-9)


@pytest.mark.parametrize("beam", ["divergent", "parallel"])
@pytest.mark.parametrize("rays", [16, 17], ids=["even", "odd"])
def test_the_central_rays_are_those_of_the_lattice(beam, rays):
    cam = camera(pixels=16, nadir_deg=20.0, azimuth_deg=40.0)
    common = dict(
        position=cam.position,
        rotation=cam.rotation,
        beam=beam,
        field_of_view=cam.field_of_view,
        rays=rays,
        reference_range=40.0,
    )
    lattice = LaserRays.from_platform(**common)
    n = rays
    index = [n // 2 * n + n // 2, n // 2 * n + n // 2 + 1, (n // 2 + 1) * n + n // 2]
    origins, directions = LaserRays.central(**common)
    assert_allclose(origins, np.asarray(lattice.origins)[index], atol=1e-12)
    assert_allclose(directions, np.asarray(lattice.directions)[index], atol=1e-12)


def five_smooth(m):
    for p in (2, 3, 5):
        while m % p == 0:
            m //= p
    return m == 1


def test_fast_lengths_are_the_smallest_even_5_smooth_lengths():
    # the planes' FFT lengths (scipy's next_fast_len of half the length, doubled) are
    # what a plain search gives: they set the grids' shapes, so the stored bytes
    def search(n):
        m = max(n, 2)
        while m % 2 or not five_smooth(m):
            m += 1
        return m

    assert [fast_length(n) for n in range(5000)] == [search(n) for n in range(5000)]
    assert fast_length(np.float64(13.0)) == 16
