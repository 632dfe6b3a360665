"""The renderer's air-to-water interface: its hits on the sea (numpy and torch), and its
refraction against the reference optics functions."""

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from workers.backends import kernels
from workers.backends.backend import get_backend, moved
from workers.optics.fresnel import fresnel_reflectance, refract
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup
from workers.setup.interface import (
    SURFACE_ITERATIONS,
    SURFACE_TOLERANCE,
    ray_components,
    surface_hit,
    through_surface,
    through_surface_and_resolved,
)

N_WATER = 1.34

U = 2.0**-24
"""float32's unit roundoff."""


class TiltedFacets:
    """A sea of zero elevation whose facet under ray i has slopes (sx[i], sy[i])."""

    def __init__(self, sx, sy):
        self.sx, self.sy = sx, sy

    def elevation_at(self, x, y, frame=0):
        return np.zeros_like(np.asarray(x, dtype=np.float32))

    def slopes_at(self, x, y, frame=0):
        return self.sx, self.sy


@pytest.mark.parametrize("seed", [0, 1, 2], ids=lambda s: f"seed{s}")
def test_the_inline_refraction_and_fresnel_equal_the_reference_functions(seed):
    # Random downward rays (up to 40° off nadir) on random facets (slopes up to ±0.5):
    # the in-water slopes, secant and transmittance of `through_surface` are those of
    # vector Snell (`optics.refract`) and unpolarised Fresnel (`optics.fresnel_reflectance`)
    # at the facet's upward normal (-sx, -sy, 1)/√(1 + s²).
    rng = np.random.default_rng(seed)
    count = 2000
    theta = np.radians(rng.uniform(0.0, 40.0, count))
    phi = rng.uniform(0.0, 2 * np.pi, count)
    direction = np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)], axis=-1
    )
    origin = np.tile([0.0, 0.0, 30.0], (count, 1))
    sx = rng.uniform(-0.5, 0.5, count).astype(np.float32)
    sy = rng.uniform(-0.5, 0.5, count).astype(np.float32)
    got = through_surface(ray_components(origin, direction), TiltedFacets(sx, sy), 0, N_WATER)
    normal = np.stack([-sx, -sy, np.ones(count)], axis=-1).astype(np.float64)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    transmitted, _ = refract(direction, normal, n1=1.0, n2=N_WATER)
    cos_incidence = -(direction * normal).sum(axis=-1)
    facing = cos_incidence > 0
    assert facing.mean() > 0.95
    down = -transmitted[facing, 2]
    assert_allclose(got.tan_x[facing], transmitted[facing, 0] / down, rtol=1e-4, atol=1e-5)
    assert_allclose(got.tan_y[facing], transmitted[facing, 1] / down, rtol=1e-4, atol=1e-5)
    assert_allclose(got.secant[facing], 1 / down, rtol=1e-5)
    expected = 1 - fresnel_reflectance(cos_incidence[facing], n1=1.0, n2=N_WATER)
    assert_allclose(got.transmittance[facing], expected, rtol=1e-5)
    assert np.all(got.transmittance[~facing] == 0)
    assert_allclose(got.air, 30.0 / np.cos(theta), rtol=1e-5)


def sea(*, wind, root=3):
    """A drawn multi-scale sea (three cascades over a 64² finest grid, sub-grid slopes)."""
    scene = Scene.model_validate(
        {"surface": {"grid_size": 64, "spacing": 0.064, "wind_speed": wind}}
    )
    return scene_setup(scene).surface(SampleSeed(root=root), (0.0,))


def fan(nadir_deg, *, count=40, altitude=34.0):
    """``count``² float32 rays from `altitude` [m], 8° wide around `nadir_deg` off nadir."""
    tangents = np.tan(np.radians(np.linspace(-4.0, 4.0, count)))
    u, v = np.meshgrid(tangents, tangents)
    tilt = np.radians(nadir_deg)
    along = (np.sin(tilt) + u * np.cos(tilt), v, -np.cos(tilt) + u * np.sin(tilt))
    directions = np.stack(along, axis=-1).reshape(-1, 3)
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    return ray_components([0.0, 0.0, altitude], directions)


def stepped_hit(rays, surface):
    """The hit as `through_surface` found it before issue #39: numpy steps, a host test."""
    ox, oy, oz, dx, dy, dz = rays
    travel = -oz / dz
    eta = surface.elevation_at(ox + travel * dx, oy + travel * dy, 0)
    for _ in range(SURFACE_ITERATIONS):
        travel = (eta - oz) / dz
        height = surface.elevation_at(ox + travel * dx, oy + travel * dy, 0)
        converged = bool(np.max(np.abs(height - eta)) < SURFACE_TOLERANCE)
        eta = height
        if converged:
            break
    return travel, eta


class Elevation:
    """Any sea with an ``elevation_at``: `surface_hit`'s steps written with array operations."""

    def __init__(self, surface):
        self.elevation_at = surface.elevation_at


@pytest.mark.parametrize(("wind", "nadir"), [(5.0, 0.0), (15.0, 40.0), (10.0, 60.0)])
def test_the_compiled_hits_are_the_numpy_steps_bit_for_bit(wind, nadir):
    # one kernel pass a step, the cascades summed in it (`kernels.surface_hits`), against the
    # steps written with numpy (main's loop, kept here): the same bytes whether the steps
    # converge (nadir: 2 of them, 40°: 4–6) or stop at SURFACE_ITERATIONS (60°), for float32
    # rays and for the Monte Carlo's float64 rays, and the same for any sea with an
    # `elevation_at` (array steps, no host test)
    surface = sea(wind=wind)
    rays32 = fan(nadir)
    rays64 = tuple(np.float64(v) if np.ndim(v) == 0 else v.astype(np.float64) for v in rays32)
    for rays in (rays32, rays64):
        expected = stepped_hit(rays, surface)
        for got in (surface_hit(rays, surface, 0), surface_hit(rays, Elevation(surface), 0)):
            for value, reference in zip(got, expected, strict=True):
                assert value.dtype == reference.dtype
                assert value.tobytes() == reference.tobytes()


def test_the_hits_lie_on_the_surface_within_the_tolerance():
    # after the last step the ray's height is the elevation under its previous point: where
    # the steps converged it is within SURFACE_TOLERANCE of the elevation under the hit
    for wind, nadir in [(5.0, 0.0), (15.0, 0.0), (15.0, 40.0)]:
        surface, rays = sea(wind=wind, root=4), fan(nadir)
        travel, eta = surface_hit(rays, surface, 0)
        ox, oy, oz, dx, dy, dz = rays
        assert np.abs(oz + travel * dz - eta).max() < SURFACE_TOLERANCE
        assert_array_equal(eta, surface.elevation_at(ox + travel * dx, oy + travel * dy, 0))
        assert eta.std() > 0.01  # a rough sea: the hits are not those of z = 0


def test_the_kernels_steps_after_convergence_change_no_byte():
    # float32 steps past the fixed point still move the hits by 1e-7 m; the kernel's last
    # step is the first that converged, whatever the count allowed beyond it
    surface, rays = sea(wind=10.0), fan(20.0)
    rays = tuple(np.broadcast_to(np.asarray(v, np.float32), rays[5].shape) for v in rays)
    grids = tuple(c._wrapped_fields(0)[:1] for c in surface.cascades)
    sizes = tuple(c.grid_size for c in surface.cascades)
    inverses = tuple(np.float32(1.0 / c.spacing) for c in surface.cascades)
    results = []
    for iterations in (SURFACE_ITERATIONS, 9, 30, 31):  # float32 steps may cycle
        travel = np.empty(rays[5].shape, np.float32)
        eta = np.empty(rays[5].shape, np.float32)
        tolerance = np.float32(SURFACE_TOLERANCE)
        kernels.surface_hits(grids, sizes, inverses, rays, tolerance, iterations, travel, eta)
        results.append((travel.tobytes(), eta.tobytes()))
    assert all(result == results[0] for result in results)
    assert results[0] == tuple(v.tobytes() for v in stepped_hit(rays, surface))
    travel, eta = stepped_hit(rays, surface)  # one more step would move them
    step = (eta - rays[2]) / rays[5]
    assert step.tobytes() != travel.tobytes()


def test_the_full_and_resolved_seas_share_hits_and_slopes_to_the_byte():
    # the lines of sight through the sea and through its resolved part (the target's
    # reading) meet it at the same points with the same cascades' slopes: found once, the
    # bytes of tracing each
    surface = sea(wind=8.0)
    resolved = dataclasses.replace(surface, subgrid=None)
    rays = fan(10.0)
    both = through_surface_and_resolved(rays, surface, 0, N_WATER)
    for got, sea_ in zip(both, (surface, resolved), strict=True):
        alone = through_surface(rays, sea_, 0, N_WATER)
        for field in dataclasses.fields(alone):
            value, expected = getattr(got, field.name), getattr(alone, field.name)
            assert value.tobytes() == expected.tobytes(), field.name
    assert both[0].tan_x.tobytes() != both[1].tan_x.tobytes()  # the sub-grid slopes differ


def torch_backend(device):
    """The torch backend on `device` (the test skips without torch or without the device)."""
    torch = pytest.importorskip("torch")
    if device == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device here")
    return get_backend("torch", device)


@pytest.fixture(params=["cpu", "cuda"])
def device(request):
    """The torch backend on each device there is."""
    return torch_backend(request.param)


def seas(backend, *, wind, root=3):
    """One drawn sea on numpy and on `backend` (three cascades, sub-grid slopes)."""
    scene = Scene.model_validate(
        {"surface": {"grid_size": 64, "spacing": 0.064, "wind_speed": wind}}
    )
    setup, seed = scene_setup(scene), SampleSeed(root=root)
    return setup.surface(seed, (0.0,)), setup.surface(seed, (0.0,), backend=backend)


def host_reads():
    """A dispatch mode counting (``count``) the reads of a tensor's value on the host.

    ``.item()``, ``bool(tensor)``, ``float(tensor)``: each one ``aten::_local_scalar_dense``.
    """
    torch = pytest.importorskip("torch")
    from torch.utils._python_dispatch import TorchDispatchMode

    class HostReads(TorchDispatchMode):
        count = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if func is torch.ops.aten._local_scalar_dense.default:
                self.count += 1
            return func(*args, **(kwargs or {}))

    return HostReads()


@pytest.mark.parametrize(("wind", "nadir"), [(5.0, 0.0), (10.0, 60.0)])
def test_the_rays_cross_the_sea_with_no_read_on_the_host(wind, nadir):
    # issue #39: the hits' steps ran until a host test of their largest change (one read a
    # step: 2 at nadir, 8 at 60°); now a fixed count on the device
    backend = torch_backend("cpu")
    _, surface = seas(backend, wind=wind)
    rays = moved(fan(nadir), backend)
    with host_reads() as reads:
        through_surface(rays, surface, 0, N_WATER)
    assert reads.count == 0


@pytest.mark.parametrize(("wind", "nadir"), [(5.0, 0.0), (15.0, 40.0), (10.0, 60.0)])
def test_the_device_hits_are_numpys(wind, nadir, device):
    # all SURFACE_ITERATIONS steps on the device, the rays held once converged: numpy's
    # hits (its loop stops at the first converged step), to float32 rounding of the sums
    host_sea, device_sea = seas(device, wind=wind)
    rays = fan(nadir)
    travel, eta = surface_hit(rays, host_sea, 0)
    got = surface_hit(moved(rays, device), device_sea, 0)
    # a hit's travel is ~40–70 m, its height below 1 m, moved by a few rounded sums
    np.testing.assert_allclose(got[0].cpu().numpy(), travel, rtol=16 * U, atol=0)
    np.testing.assert_allclose(got[1].cpu().numpy(), eta, rtol=0, atol=1e-5)


def test_surface_hits_stop_moving_the_rays_once_all_converged(device):
    # float32 steps past convergence still move the hits by ~1e-7 m: the device's steps
    # beyond the first converged one leave every byte as it was
    _, surface = seas(device, wind=10.0)
    rays = moved(fan(20.0), device)
    grids = tuple(c._wrapped_fields(0)[:1] for c in surface.cascades)
    sizes = tuple(c.grid_size for c in surface.cascades)
    inverses = tuple(np.float32(1.0 / c.spacing) for c in surface.cascades)
    results = []
    for iterations in (SURFACE_ITERATIONS, 9, 30, 31):  # float32 steps may cycle
        travel, eta = (rays[5].new_empty(rays[5].shape) for _ in range(2))
        device.kernels.surface_hits(
            grids, sizes, inverses, rays, SURFACE_TOLERANCE, iterations, travel, eta
        )
        results.append((travel.cpu().numpy().tobytes(), eta.cpu().numpy().tobytes()))
    assert all(result == results[0] for result in results)
