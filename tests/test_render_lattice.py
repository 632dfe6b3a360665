"""The fast renderer's rough-sea light does not depend on how its rays sample the sea.

Issue #24 item 1: when each pixel's line of sight was its own laser ray, a pixel read its
own ray's light wherever the waves sent it, and the gates' rough-sea mean depended on the
lattice (1.53 of the flat sea's at the default, 1.22 with 1.5 times the rays, 1.55 with 3
times, clear water, 5 m/s). The model is in docs/model.md §3.
"""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.ndimage import convolve

from workers.render import render_arrays
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup
from workers.setup.geometry import LaserRays
from workers.setup.interface import ray_components, through_surface
from workers.setup.sensor import lattice_offset, sensor_at


def inner_mean(images):
    """Mean over the image's central three quarters (the last two axes)."""
    n = images.shape[-1]
    inner = slice(n // 8, n - n // 8)
    return images[..., inner, inner].mean(axis=(-2, -1))


@pytest.mark.parametrize("rays", [32, 48, 64, 96, 33], ids=["1x", "1.5x", "2x", "3x", "odd"])
def test_no_line_of_sight_is_a_laser_ray(rays):
    fov = np.radians(6.7)
    pixels = 32
    offset = lattice_offset(pixels=pixels, field_of_view=fov, rays=rays, laser_field_of_view=fov)
    lattice = LaserRays.from_platform(
        position=(0.0, 0.0, 34.0),
        rotation=np.diag([1.0, -1.0, -1.0]),
        beam="divergent",
        field_of_view=fov,
        rays=rays,
        reference_range=34.0,
        offset=offset,
    )
    u = lattice.directions[:, 0] / -lattice.directions[:, 2]
    lines = (np.arange(pixels) + 0.5 - 0.5 * pixels) * 2 * np.tan(0.5 * fov) / pixels
    step = 2 * np.tan(0.5 * fov) / rays
    nearest = np.abs(lines[:, None] - np.unique(u)[None, :]).min(axis=1)
    # a commensurate lattice keeps a quarter of a step at least (half a step, midway,
    # when the rays share the pixels' pitch); 33 rays on 32 lines reach every phase, and
    # are kept half of the closest phases' gap away (1/64 of a step)
    least = 0.25 if rays % 16 == 0 else 1 / 64
    assert nearest.min() >= least * step * (1 - 1e-6)
    if rays == pixels:
        assert_allclose(nearest, 0.5 * step, rtol=1e-9)


def clear_sea(*, rays=None, pixels=128, flat=False):
    return Scene.model_validate(
        {
            "water": {"preset": "clear_ocean"},
            "surface": {"spectrum": "flat" if flat else "elfouhaily", "wind_speed": 5.0},
            "target": {"shape": "none"},
            "receiver": {"pixels": pixels},
            "laser": {"rays": rays},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
        }
    )


def test_the_gates_rough_sea_means_converge_with_rays_and_lines():
    # Clear water, 5 m/s, the default 128-pixel scene, four seas: every gate's mean with 1.5
    # and 3 times the rays, and with two lines of sight a pixel and side (twice the pixels,
    # the default's rays, binned 2 x 2), within 2 % of the default's (issue #24's bound;
    # measured 1.3 % at most). Before the fix: 1.53, 1.22 and 1.55 of the flat sea.
    seeds = range(4)

    def means(rays=None, lines=1):
        s = clear_sea(rays=rays, pixels=128 * lines)
        if lines > 1:
            s = s.model_copy(update={"laser": s.laser.model_copy(update={"rays": 128})})
        got = [render_arrays(s, seed=seed)["expected"][0] for seed in seeds]
        if lines > 1:
            got = [g.reshape(len(g), 128, lines, 128, lines).mean(axis=(2, 4)) for g in got]
        return np.mean([inner_mean(g) for g in got], axis=0)

    default = means()
    flat = inner_mean(render_arrays(clear_sea(flat=True), seed=0)["expected"][0])
    assert default[0] / flat[0] > 1.15  # the double passage is there
    for other in (means(rays=192), means(rays=384), means(lines=2)):
        assert_allclose(other, default, rtol=0.02)


def ray_trace(scene, *, seed, per_pixel, bin_size, diameter):
    """Each pixel's light from a gate's plane, unscattered, read at a disc of `diameter`.

    An independent estimate of what the fast renderer computes without scattering: a
    monostatic ray trace on `per_pixel` × `per_pixel` lines a pixel through the same sea,
    the light binned at `bin_size` on the plane at the gate's reference depth, averaged
    over a disc (the scale it is read at) and read by every line, its own light left out;
    the Gaussian beam, Fresnel transmittances both ways (normalised radiometry cancels in
    a wavy/flat ratio).
    """
    setup = scene_setup(scene)
    sensor = sensor_at(setup, 0)
    camera = sensor.camera
    n, half = camera.pixels, np.tan(0.5 * camera.field_of_view)
    tangents = (np.arange(n * per_pixel) + 0.5) * (2 * half / (n * per_pixel)) - half
    u, v = np.meshgrid(tangents, tangents)
    camera_axes = np.stack([u, v, np.ones_like(u)], axis=-1)
    directions = camera_axes / np.linalg.norm(camera_axes, axis=-1, keepdims=True)
    directions = (directions @ camera.rotation).reshape(-1, 3)
    surface = setup.surface(SampleSeed(root=seed), np.zeros(1)) if seed is not None else None
    n_w, depth = setup.water.refractive_index, setup.reference_depths[0]
    rays = through_surface(ray_components(sensor.position, directions), surface, 0, n_w)
    x = rays.x + (rays.z + depth) * rays.tan_x
    y = rays.y + (rays.z + depth) * rays.tan_y
    power = np.exp(-(u**2 + v**2) / half**2).ravel() * rays.transmittance
    extent = 1.5 * half * (sensor.position[2] + depth / n_w)
    bins = int(np.ceil(2 * extent / bin_size))
    column = np.clip(((x + extent) / bin_size).astype(int), 0, bins - 1)
    row = np.clip(((y + extent) / bin_size).astype(int), 0, bins - 1)
    light = np.bincount(row * bins + column, weights=power, minlength=bins * bins)
    radius = 0.5 * diameter / bin_size
    reach = int(np.ceil(radius))
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    offsets = (np.arange(-reach, reach + 1)[:, None] + sub[None, :]).ravel()
    disc = (offsets[:, None] ** 2 + offsets[None, :] ** 2 <= radius**2).reshape(
        2 * reach + 1, 8, 2 * reach + 1, 8
    )
    disc = disc.mean(axis=(1, 3))
    disc /= disc.sum()
    read = convolve(light.reshape(bins, bins), disc, mode="constant")[row, column]
    read -= power * disc[reach, reach]
    seen = rays.transmittance * read
    return seen.reshape(n, per_pixel, n, per_pixel).sum(axis=(1, 3))


def test_the_rough_sea_signal_matches_a_ray_trace_read_at_the_same_scale():
    # Water that neither spreads nor dims the light (b = b_b: no forward scattering), one
    # gate 4-9 m, a 32-pixel corner of the default camera (its pixels, 3.1 cm on the sea,
    # and its sea, 1.6 cm spacing), six seas. The renderer reads the light at the pixel's
    # scale (`workers.fast.planes.read_blur`: variance p²/3 a side, p the pixel pitch on the
    # plane); the trace reads it at a disc of that variance (diameter 4p/√3) from 8 x 8
    # lines a pixel binned at 5 mm. Per sea, renderer over trace, wavy over flat each:
    # their mean is 1 within three standard errors of the six (measured 1.01 ± 0.02;
    # lines on rays read about 1.5 times the trace). At the aperture's scale (1.2 cm) the trace
    # reads 7-10 % more than at the pixel's: docs/model.md §3.
    pixels = 32

    def scene(flat=False):
        return Scene.model_validate(
            {
                "water": {
                    "preset": None,
                    "absorption": 0.05,
                    "scattering": 5e-4,
                    "backscatter": 5e-4,
                    "phase_function": "paper",  # b_b = b: outside the Fournier-Forand fit
                },
                "surface": {
                    "spectrum": "flat" if flat else "elfouhaily",
                    "spacing": 4.0 / 256,
                },
                "target": {"shape": "none"},
                "receiver": {
                    "pixels": pixels,
                    "field_of_view_deg": 6.7 * pixels / 128,
                    "gates": [[4.0, 9.0]],
                },
                "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
            }
        )

    wavy = scene()
    setup = scene_setup(wavy)
    sensor = sensor_at(setup, 0)
    depth = setup.reference_depths[0] / setup.water.refractive_index
    pitch = 2 * np.tan(0.5 * sensor.camera.field_of_view) / pixels
    diameter = 4 * pitch * (sensor.position[2] + depth) / np.sqrt(3)
    traced = {"per_pixel": 8, "bin_size": 0.005, "diameter": diameter}
    flat_render = inner_mean(render_arrays(scene(flat=True), seed=0)["expected"][0, 0])
    flat_trace = inner_mean(ray_trace(wavy, seed=None, **traced))
    ratios = []
    for seed in range(6):
        rendered = inner_mean(render_arrays(wavy, seed=seed)["expected"][0, 0]) / flat_render
        ratios.append(rendered / (inner_mean(ray_trace(wavy, seed=seed, **traced)) / flat_trace))
    error = np.std(ratios, ddof=1) / np.sqrt(len(ratios))
    assert abs(np.mean(ratios) - 1.0) < 3 * error + 0.01  # 1 %: the trace's binning


@pytest.mark.parametrize("rays", [24, 48, 96])
def test_the_target_mask_and_shadow_do_not_depend_on_the_laser_lattice(rays):
    # A user trial: a 0.3 m sphere at 5 m seen by 32 pixels (4.8 pixels across) had a
    # 16-pixel mask at 32, 40, 64 rays and 12 at 24 and 48 (the corners, more than half
    # covered, dropped): the mask was read from the laser lattice's cells. The mask, a
    # training label, and the view the target stops are read on the pixels' own grid:
    # the mask is the same whatever the rays, and the shadow a gate below the target
    # holds moves by less than 0.05 (transport: -0.84 ... -0.86 in clear water).
    base = Scene.model_validate(
        {
            "surface": {"spectrum": "flat"},
            "water": {"preset": "clear_ocean"},
            "receiver": {"pixels": 32, "gates": "mldc"},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0},
            "target": {"shape": "sphere", "radius": 0.3, "depth": 5.0, "reflectance": 0.2},
        }
    )

    def rendered(rays):
        scene = base.model_copy(update={"laser": base.laser.model_copy(update={"rays": rays})})
        return render_arrays(scene, seed=1)

    default, other = rendered(None), rendered(rays)
    assert default["target_mask"].sum() == 16
    assert np.array_equal(default["target_mask"], other["target_mask"])
    shadow = [r["target_effect_relative"][0, 4] for r in (default, other)]
    assert abs(shadow[1] - shadow[0]) < 0.05 and shadow[0] < -0.8, shadow
