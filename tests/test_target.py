"""Target impostor: area weights, shading, silhouette."""

import numpy as np
import pytest
from conftest import plane_grid
from numpy.testing import assert_allclose

from workers.settings.target import Target
from workers.setup.geometry import PinholeCamera
from workers.targets.base import shape_named
from workers.targets.impostor import sphere_area_weights


def cells(radius, h):
    n = int(np.ceil(1.2 * radius / h))
    c = (np.arange(-n, n + 1)) * h
    return np.meshgrid(c, c, indexing="ij")


@pytest.mark.parametrize("cells_per_radius", [5, 20, 80])
def test_paper_area_weights_sum_to_the_hemisphere_area(cells_per_radius):
    r = 0.3
    u, w = cells(r, r / cells_per_radius)
    total = sphere_area_weights(
        u=u, w=w, cell_u=r / cells_per_radius, cell_w=r / cells_per_radius, radius=r
    )
    # Exact columns in w; 8-point Gauss in u: the only error is at the two rim columns,
    # where the integrand has a square-root edge. It shrinks with the cell size h like h^1.5.
    rel = abs(total.sum() / (2 * np.pi * r**2) - 1)
    assert rel < 0.02 * (5 / cells_per_radius) ** 1.5


@pytest.mark.parametrize(
    "cell", [(0.2, 0.45, -0.3, -0.1), (0.8, 0.95, 0.2, 0.5)], ids=["interior", "rim"]
)
def test_cell_area_equals_a_monte_carlo_estimate_on_the_sphere(cell):
    # Oracle: points uniform on the unit hemisphere (z = cos polar angle is uniform); the
    # fraction projecting into the cell, times 2π, estimates its area with standard error
    # 2π·sqrt(p(1-p)/n). Allow 5 standard errors.
    u1, u2, w1, w2 = cell
    n = 2_000_000
    rng = np.random.default_rng(4)
    z = rng.uniform(0, 1, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z**2)
    u, w = s * np.cos(phi), s * np.sin(phi)
    p = np.mean((u >= u1) & (u < u2) & (w >= w1) & (w < w2))
    got = sphere_area_weights(
        u=np.array(0.5 * (u1 + u2)),
        w=np.array(0.5 * (w1 + w2)),
        cell_u=u2 - u1,
        cell_w=w2 - w1,
        radius=1.0,
    )
    assert abs(got - 2 * np.pi * p) < 5 * 2 * np.pi * np.sqrt(p * (1 - p) / n)


def nadir_grid(depth, pixels=64, fov_deg=6.7):
    cam = PinholeCamera(
        position=(0.0, 0.0, 34.0),
        nadir=0.0,
        azimuth=0.0,
        field_of_view=np.radians(fov_deg),
        pixels=pixels,
    )
    return plane_grid(cam, depth=depth)


def centred_impostor(grid, *, shape, refracted_nadir, **properties):
    """The shape's `impostor` with the target at the centre of `grid`, at its depth."""
    x, y = grid.cell_centres()
    return shape_named(shape).impostor(
        grid=grid,
        target=Target(shape=shape, depth=grid.depth, **properties),
        centre=(float(x.mean()), float(y.mean())),
        refracted_nadir=refracted_nadir,
    )


def test_lambert_sphere_at_nadir():
    grid = nadir_grid(5.0)
    imp = centred_impostor(
        grid,
        shape="sphere",
        radius=0.6,
        reflectance=0.5,
        shading="lambert",
        refracted_nadir=0.0,
    )
    area = grid.spacing_u * grid.spacing_v
    # silhouette area πr²; ∫ρ cos i dA = ρ·(2/3)πr² for the lit hemisphere seen head-on
    assert_allclose(imp.occupancy.sum() * area, np.pi * 0.36, rtol=0.01)
    assert_allclose(imp.weight.sum() * area, 0.5 * 2 / 3 * np.pi * 0.36, rtol=0.02)
    assert_allclose(imp.surface_depth[imp.occupancy == 1].min(), 5.0 - 0.6, atol=0.01)
    assert imp.top == pytest.approx(4.4) and imp.bottom == pytest.approx(5.6)


def test_paper_shading_sums_to_two_pi_r_squared_times_reflectance():
    grid = nadir_grid(5.0)
    imp = centred_impostor(
        grid,
        shape="sphere",
        radius=0.6,
        reflectance=0.2,
        shading="paper",
        refracted_nadir=0.0,
    )
    area = grid.spacing_u * grid.spacing_v
    assert_allclose(imp.weight.sum() * area, 0.2 * 2 * np.pi * 0.36, rtol=0.01)


def test_oblique_sphere_silhouette_is_stretched_along_the_view():
    theta_t = np.arcsin(np.sin(np.radians(40)) / 1.34)
    grid = nadir_grid(5.0)
    imp = centred_impostor(
        grid,
        shape="sphere",
        radius=0.6,
        reflectance=0.2,
        shading="lambert",
        refracted_nadir=theta_t,
    )
    area = grid.spacing_u * grid.spacing_v
    assert_allclose(imp.occupancy.sum() * area, np.pi * 0.36 / np.cos(theta_t), rtol=0.01)


def test_disk_is_a_flat_lambertian_panel():
    grid = nadir_grid(4.0)
    imp = centred_impostor(
        grid,
        shape="disk",
        radius=1.0,
        reflectance=0.3,  # `shading: paper` is refused for a disk (test_target_shapes)
        refracted_nadir=0.0,
    )
    area = grid.spacing_u * grid.spacing_v
    assert_allclose(imp.occupancy.sum() * area, np.pi, rtol=0.01)
    assert imp.weight.max() == pytest.approx(0.3)
    assert imp.top == imp.bottom == 4.0


@pytest.mark.parametrize("cell", [0.05, 0.45, 0.9, 2.0], ids=lambda c: f"cell{c:g}")
@pytest.mark.parametrize("offset", [0.0, 0.2, 0.45], ids=lambda o: f"offset{o:g}")
def test_disc_cover_keeps_the_area_and_the_lambertian_return_wherever_the_disc_lies(cell, offset):
    # ∑ cover·|C| = π r² and ∑ cosine·|C| = (2/3) π r² (∫∫ √(1 - ρ²/r²) over the disc),
    # whether the disc spans many cells or lies inside one, at any offset.
    from workers.targets.impostor import disc_cover

    r = 0.3
    count = int(np.ceil(2 * r / cell)) + 4
    x = (np.arange(-count, count + 1) * cell) + offset
    u, w = np.meshgrid(x, x)
    cover, cosine = disc_cover(u=u, w=w, cell_u=cell, cell_w=cell, radius=r)
    assert_allclose(cover.sum() * cell**2, np.pi * r**2, rtol=2e-3)
    assert_allclose(cosine.sum() * cell**2, 2 / 3 * np.pi * r**2, rtol=2e-3)
    assert cover.max() <= 1.0
