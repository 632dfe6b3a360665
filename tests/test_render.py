"""End-to-end rendering of one sample: closed forms, invariants, labels, determinism."""

import numpy as np
import pytest
from conftest import ring_around
from numpy.testing import assert_allclose, assert_array_equal

from workers.dataset.labels import RING_FRACTION, signal_means
from workers.optics.fresnel import fresnel_reflectance
from workers.render import render, render_arrays, render_images, render_pair
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup

N_WATER = 1.34
T0 = 1.0 - fresnel_reflectance(1.0, n1=1.0, n2=N_WATER)


def scene(**sections):
    """A small scene (fast) with the given sections merged over test defaults."""
    base = {
        "surface": {"grid_size": 64, "spacing": 0.064},
        "receiver": {"pixels": 32},
        "radiometry": {"mode": "normalised", "white_plane_photons": 0},
    }
    for key, value in sections.items():
        base[key] = {**base.get(key, {}), **value} if isinstance(value, dict) else value
    return Scene.model_validate(base)


def clear_water(absorption=0.1, scattering=0.0, backscatter=0.0, phase_function="fournier_forand"):
    return {
        "preset": None,
        "absorption": absorption,
        "scattering": scattering,
        "backscatter": backscatter,
        "phase_function": phase_function,
    }


SLIGHTLY_TURBID = {
    "absorption": 0.15,
    "scattering": 0.01,
    "backscatter": 0.01,
    "phase_function": "paper",
}
"""Water for the single-scattering backscatter checks (scene and oracle alike): b_b = b,
no forward scattering, so the paper's phase function (the Fournier-Forand fit has no
member that scatters only backwards) and no small-angle spread."""


def water_column(gate, **sections):
    """A flat sea over SLIGHTLY_TURBID water, no target, one gate, a parallel laser."""
    return scene(
        surface={"spectrum": "flat"},
        water=clear_water(**SLIGHTLY_TURBID),
        laser={"beam": "parallel"},
        target={"shape": "none"},
        receiver={"gates": [list(gate)]},
        **sections,
    )


def centre(image):
    """Mean of the four central pixels of (..., y, x)."""
    n = image.shape[-1] // 2
    return image[..., n - 1 : n + 1, n - 1 : n + 1].mean(axis=(-2, -1))


FLAT_DISK = {
    "surface": {"spectrum": "flat"},
    "water": clear_water(),
    "laser": {"beam": "parallel"},
    "receiver": {"gates": [[0.5, 12.0]]},
}


@pytest.mark.parametrize(
    ("depth", "reflectance"),
    [(2.0, 0.2), (5.0, 0.2), (5.0, 0.6), (9.0, 1.0)],
    ids=["d2-r0.2", "d5-r0.2", "d5-r0.6", "d9-r1"],
)
def test_flat_sea_disk_equals_the_closed_form(depth, reflectance):
    # Flat sea, no scattering, nadir, a disk wider than the field: each pixel sees
    # t0 (down) · e^-Kd · ρ · e^-Kd · t0 (up), in units of a ρ = 1 plane just under the
    # surface (which itself returns t0²). K = a when b = 0.
    s = scene(
        **FLAT_DISK,
        target={"shape": "disk", "radius": 5.0, "depth": depth, "reflectance": reflectance},
    )
    value = centre(render(s, seed=1).expected.values[0, 0])
    expected = reflectance * np.exp(-2 * 0.1 * depth)
    assert_allclose(value, expected, rtol=0.01)
    # the same in the form: the ratio of two samples is the ratio of t0²ρe^-2Kd
    ref = scene(
        **FLAT_DISK, target={"shape": "disk", "radius": 5.0, "depth": 2.0, "reflectance": 0.2}
    )
    ratio = value / centre(render(ref, seed=1).expected.values[0, 0])
    closed = (T0**2 * reflectance * np.exp(-0.2 * depth)) / (T0**2 * 0.2 * np.exp(-0.2 * 2.0))
    assert_allclose(ratio, closed, rtol=0.01)


def test_divergent_beam_spreads_as_the_apparent_range_squared():
    # A divergent beam from altitude H reaches depth d with its cross-section widened by
    # (H + d/n)/H (paraxial refraction), so the irradiance falls by its square.
    H, d = 34.0, 6.0
    s = scene(
        **{**FLAT_DISK, "laser": {"beam": "divergent"}},
        platform={"altitude": H},
        target={"shape": "disk", "radius": 5.0, "depth": d, "reflectance": 0.5},
    )
    value = centre(render(s, seed=1).expected.values[0, 0])
    expected = 0.5 * np.exp(-2 * 0.1 * d) * (H / (H + d / N_WATER)) ** 2
    assert_allclose(value, expected, rtol=0.01)


@pytest.mark.parametrize("gate", [(2.0, 4.0), (3.0, 9.0), (6.0, 15.0)], ids=["2-4", "3-9", "6-15"])
def test_flat_sea_water_backscatter_is_the_single_scattering_lidar_integral(gate):
    # No target, flat sea, no forward scattering: the gated return is
    # π β(π) ∫ e^(-2Kz) dz over the gate (units of the ρ = 1 plane under the surface).
    from workers.optics.water import WaterOptics

    s = water_column(gate)
    optics = WaterOptics(**SLIGHTLY_TURBID)
    K, (top, bottom) = optics.diffuse_attenuation, gate
    integral = (np.exp(-2 * K * top) - np.exp(-2 * K * bottom)) / (2 * K)
    value = centre(render(s, seed=1).expected.values[0, 0])
    assert_allclose(value, np.pi * optics.backscatter_pi * integral, rtol=0.01)


ROUGH = {
    # the 4.1 m patch repeats inside oblique and climbing views; these tests accept it
    "surface": {"spectrum": "elfouhaily", "wind_speed": 5.0, "allow_repeat": True},
    "water": {"preset": "clear_ocean"},
}


def target_scene(shape="sphere", depth=5.0, gates=((4.0, 7.0), (8.0, 12.0), (1.0, 2.5)), **extra):
    return scene(
        **ROUGH,
        target={"shape": shape, "depth": depth, "radius": 0.6, "reflectance": 0.5},
        receiver={"gates": [list(g) for g in gates]},
        **extra,
    )


def test_target_visibility_labels():
    ds = render(target_scene(), seed=3)
    # gate 4–7 m holds the sphere (4.4–5.6 m), 8–12 m lies below it, 1–2.5 m above it
    assert ds.target_visibility.values.tolist() == [[1, 2, 3]]
    assert ds.target_effect.values[0, 2] == 0  # the water above the sphere is the twin's
    assert int(ds.target_present) == 1
    none = render(target_scene(shape="none"), seed=3)
    assert none.target_visibility.values.tolist() == [[0, 0, 0]]
    assert np.isnan(none.target_effect.values).all()
    assert int(none.target_present) == 0
    assert none.target_mask.values.sum() == 0


def rule(relative, threshold):
    """docs/model.md §8's labels of a gate with a non-empty mask, from its relative effect."""
    return np.select([relative >= threshold, relative <= -threshold], [1, 2], 3)


@pytest.mark.parametrize(
    "surface", [{"spectrum": "flat"}, ROUGH["surface"]], ids=["flat", "rough"]
)
def test_target_effect_is_the_change_from_the_target_free_twin(surface):
    # Issue #24, item 6: the effect and the labels against an independent computation, the
    # twin rendered as a scene of its own and the means over the mask taken here; two
    # frames of a climbing platform, so that each frame has its own mask.
    s = target_scene(sequence={"frames": 2, "velocity": [0.0, 0.5, 2.0]})
    s = s.model_copy(update={"surface": s.surface.model_copy(update=surface)})
    ds = render(s, seed=4)
    twin = render(s.without_target(), seed=4)
    for frame in range(2):
        mask = ds.target_mask.values[frame].astype(bool)
        shown, bare = (
            d.expected.values[frame][:, mask].astype(np.float64).mean(axis=1) for d in (ds, twin)
        )
        assert_allclose(ds.target_effect.values[frame], shown - bare, rtol=1e-5, atol=1e-9)
        relative = ds.target_effect_relative.values[frame]
        assert_allclose(relative, (shown - bare) / bare, rtol=1e-5, atol=1e-9)
        assert ds.target_visibility.values[frame].tolist() == rule(relative, 0.05).tolist()
    # another threshold relabels the same effects
    strict = s.model_copy(
        update={"target": s.target.model_copy(update={"visibility_threshold": 1.0})}
    )
    again = render(strict, seed=4)
    assert_array_equal(again.target_effect_relative, ds.target_effect_relative)
    assert_array_equal(again.target_visibility, rule(ds.target_effect_relative.values, 1.0))


@pytest.mark.parametrize(
    ("depth", "gate", "reflectance"),
    [(5.0, (2.0, 9.0), 0.05), (3.0, (1.0, 4.0), 0.3)],
    ids=["d5-r0.05", "d3-r0.3"],
)
def test_target_effect_of_a_wide_disk_is_the_closed_form(depth, gate, reflectance):
    # Flat sea, nadir, a disk wider than the field lit by a parallel beam six times wider
    # than the image, water that hardly forward-scatters. Per pixel, in units of the white
    # plane: the sample shows ρ e^(-2Kd) and the water above the disk, π β(π) ∫ e^(-2Kz) dz
    # from the gate's top to d; its twin the whole slab. The target's effect is ρ e^(-2Kd)
    # less the water it hides, from d to the gate's bottom. The beam's profile, common to
    # both, cancels from the relative effect; the absolute one is the mask's mean.
    from workers.optics.water import WaterOptics

    s = scene(
        surface={"spectrum": "flat"},
        water=clear_water(**SLIGHTLY_TURBID),
        laser={"beam": "parallel", "field_of_view_deg": 40.0},
        receiver={"gates": [list(gate)]},
        target={"shape": "disk", "radius": 5.0, "depth": depth, "reflectance": reflectance},
    )
    ds = render(s, seed=1)
    optics = WaterOptics(**SLIGHTLY_TURBID)
    K, (top, bottom) = optics.diffuse_attenuation, gate

    def water(a, b):
        return np.pi * optics.backscatter_pi * (np.exp(-2 * K * a) - np.exp(-2 * K * b)) / (2 * K)

    effect = reflectance * np.exp(-2 * K * depth) - water(depth, bottom)
    assert ds.target_mask.values.all()
    assert_allclose(ds.target_effect_relative.values[0, 0], effect / water(top, bottom), rtol=0.01)
    assert_allclose(ds.target_effect.values[0, 0], effect, rtol=0.03)


@pytest.mark.parametrize("nadir", [0.0, 20.0], ids=["nadir", "nadir20"])
def test_a_black_disk_hides_each_gate_its_own_slab_behind_it(nadir):
    # Issue #38 item 5 (c): the shadow's timing, gate by gate. A black disk (ρ = 0) at
    # 6 m under a flat sea, wider than the field, in water that does not forward-scatter:
    # each pixel keeps 1 - h of its gate's water, h the share of the gate's single-
    # scattering integral ∫ e^(-2K sec ϑc z) dz lying below the disk along the pixel's
    # line (docs/model.md §5, §6). The gate opens and closes at the optical paths
    # P = H / cos θ + n d / cos ϑc of the central ray's bounds d; a pixel whose line leaves
    # at γ from the vertical (ϑ in the water) gates the depths (P - H / cos γ) cos ϑ / n.
    # Five gates: above the disk (h = 0), through it three ways, below it (h = 1): a
    # gate's shadow timed by a neighbouring gate misses by 0.2 or more.
    from workers.optics.water import WaterOptics

    gates = [(1.0, 4.0), (4.0, 8.0), (5.5, 7.0), (7.0, 10.0), (5.0, 12.0)]
    H, depth, pixels = 34.0, 6.0, 16
    s = scene(
        surface={"spectrum": "flat"},
        water=clear_water(**SLIGHTLY_TURBID),
        laser={"beam": "parallel", "field_of_view_deg": 40.0},
        platform={"altitude": H, "nadir_deg": nadir},
        receiver={"gates": [list(g) for g in gates], "pixels": pixels},
        target={"shape": "disk", "radius": 5.0, "depth": depth, "reflectance": 0.0},
    )
    kept = (
        render(s, seed=1).expected.values[0]
        / render(s.without_target(), seed=1).expected.values[0]
    )
    n, theta = s.water.refractive_index, np.radians(nadir)
    # each pixel's line: the optical axis plus its offsets on the image plane (unit focal
    # length) across and up the image (row 0 the far edge), the pinhole of §2
    half = np.tan(0.5 * np.radians(s.receiver.field_of_view_deg))
    offsets = (2 * np.arange(pixels) + 1 - pixels) / pixels * half
    u, w = offsets[None, :], -offsets[:, None]
    cos_air = (np.cos(theta) - w * np.sin(theta)) / np.sqrt(1 + u**2 + w**2)
    cos_water = np.sqrt(1 - (1 - cos_air**2) / n**2)
    cos_central = np.sqrt(1 - (np.sin(theta) / n) ** 2)
    K = WaterOptics(**SLIGHTLY_TURBID).diffuse_attenuation / cos_central
    for gate, (top, bottom) in enumerate(gates):
        t, b = (
            np.maximum(H / np.cos(theta) + n * d / cos_central - H / cos_air, 0) * cos_water / n
            for d in (top, bottom)
        )
        behind = np.clip(depth, t, b)
        h = (np.exp(-2 * K * behind) - np.exp(-2 * K * b)) / (
            np.exp(-2 * K * t) - np.exp(-2 * K * b)
        )
        # the deficit maps are sampled on the planes' grids and read bilinearly: 3.3e-4 at
        # most over the image's middle half, 3.2e-3 where the gate's top crosses the disk
        # at the near corner (h's kink) at 20°
        middle = slice(pixels // 4, 3 * pixels // 4)
        assert_allclose(kept[gate][middle, middle], 1 - h[middle, middle], atol=5e-4)
        assert_allclose(kept[gate], 1 - h, atol=5e-3)


def test_the_images_alone_are_those_of_the_sample():
    # `detect` renders a store's images again without the twin: the same bytes
    s = target_scene(radiometry={"white_plane_photons": 50.0})
    arrays = render_arrays(s, seed=SampleSeed(root=2, point=1, realisation=3))
    expected, image = render_images(s, seed=SampleSeed(root=2, point=1, realisation=3))
    assert expected.tobytes() == arrays["expected"].tobytes()
    assert_array_equal(image, arrays["image"])


@pytest.mark.parametrize("frames", [1, 2], ids=["one-frame", "climbing-two-frames"])
def test_a_twin_rendered_in_the_same_pass_is_the_target_free_point_rendered_apart(frames):
    # `detect` renders a positive sample with its twin in one pass for the negative
    # point's images (`render_pair`): they must be that point's own, to the byte
    s = target_scene(
        radiometry={"white_plane_photons": 50.0},
        sequence={"frames": frames, "velocity": [0.0, 0.5, 2.0]},
    )
    seed, twin_seed = (SampleSeed(root=2, point=p, realisation=3) for p in (4, 5))
    pair = render_pair(s, seed=seed, twin_seed=twin_seed)
    own = (*render_images(s, seed=seed), *render_images(s.without_target(), seed=twin_seed))
    assert [a.tobytes() for a in pair] == [b.tobytes() for b in own]
    assert render_pair(s.without_target(), seed=seed, twin_seed=twin_seed) is None
    with pytest.raises(ValueError, match="same root seed and realisation"):
        render_pair(s, seed=seed, twin_seed=SampleSeed(root=2, point=5, realisation=4))


def test_a_target_in_the_gate_that_changes_it_by_little_is_unseen():
    # Issue #24, item 6: a sphere at 9.5–10.5 m in turbid harbour water, its top inside the
    # gate 3.66–9.75 m, was labelled in_gate (its return exceeds the 0.25 m of water it
    # hides) though it changes the gate's image by 2e-4: the rest of the gate's water is
    # there with or without it. The gate 9.4–10.0 m holds its top: +4 % with the
    # small-angle return alone, -7 % with the time-resolved gains (issue #40 item 2: the
    # water there returns 1.41 times more, and the sphere hides more than its top sends);
    # the gate 9–12 m lies mostly in its shadow (-23 %).
    s = scene(
        surface={"spectrum": "flat"},
        water={"preset": "turbid_harbour"},
        target={"shape": "sphere", "depth": 10.0, "radius": 0.5, "reflectance": 0.2},
        receiver={"gates": [[3.66, 9.75], [9.4, 10.0], [9.0, 12.0]]},
    )
    ds = render(s, seed=1)
    relative = ds.target_effect_relative.values[0]
    assert abs(relative[0]) < 1e-3 and -0.09 < relative[1] < -0.05 and relative[2] < -0.1
    assert ds.target_visibility.values.tolist() == [[3, 2, 2]]
    loose = s.model_copy(
        update={"target": s.target.model_copy(update={"visibility_threshold": 0.1})}
    )
    assert render(loose, seed=1).target_visibility.values.tolist() == [[3, 3, 2]]


def test_target_in_gate_brightens_below_gate_is_invisible_above_gate_shadows():
    with_target = render(target_scene(), seed=3)
    without = render(target_scene(shape="none"), seed=3)
    mask = with_target.target_mask.values[0].astype(bool)
    assert mask.sum() > 20
    a, b = with_target.expected.values[0], without.expected.values[0]
    # in the gate: brighter inside the silhouette
    assert a[0][mask].mean() > 2 * b[0][mask].mean()
    # gate below the target: its shadow (clear water: little filling)
    assert a[1][mask].mean() < 0.5 * b[1][mask].mean()
    # gate above the target: untouched, to rounding
    assert_allclose(a[2], b[2], rtol=1e-5, atol=1e-12)


def test_same_seed_same_bytes_and_surface_depends_on_the_seed_only():
    s = target_scene(
        save_surface=True, radiometry={"mode": "normalised", "white_plane_photons": 20}
    )
    a = render(s, seed=SampleSeed(root=5, point=0, realisation=2))
    b = render(s, seed=SampleSeed(root=5, point=0, realisation=2))
    for name in a.data_vars:
        assert a[name].values.tobytes() == b[name].values.tobytes(), name
    other_point = render(
        target_scene(
            shape="none",
            save_surface=True,
            radiometry={"mode": "normalised", "white_plane_photons": 20},
        ),
        seed=SampleSeed(root=5, point=7, realisation=2),
    )
    assert a.surface_elevation.values.tobytes() == other_point.surface_elevation.values.tobytes()
    assert a.image.values.tobytes() != other_point.image.values.tobytes()
    other_realisation = render(s, seed=SampleSeed(root=5, point=0, realisation=3))
    assert not np.array_equal(
        a.surface_elevation.values, other_realisation.surface_elevation.values
    )


def test_image_is_poisson_around_expected():
    s = target_scene(radiometry={"mode": "normalised", "white_plane_photons": 500})
    ds = render(s, seed=11)
    lam = ds.expected.values.astype(np.float64)
    counts = ds.image.values.astype(np.float64)
    assert np.all(counts == np.round(counts))
    # Σ(n - λ) over N pixels has variance Σλ; allow 5 standard deviations.
    assert abs((counts - lam).sum()) < 5 * np.sqrt(lam.sum())
    # Σ((n - λ)² - λ) has variance Σ(2λ² + λ) for Poisson counts.
    residual = ((counts - lam) ** 2 - lam).sum()
    assert abs(residual) < 5 * np.sqrt((2 * lam**2 + lam).sum())


def test_white_plane_photons_zero_means_image_equals_expected():
    ds = render(target_scene(), seed=1)
    assert ds.image.values.tobytes() == ds.expected.values.tobytes()
    assert ds.image.attrs["units"] == "1"


def test_dataset_layout_and_metadata():
    ds = render(target_scene(save_surface=True, sequence={"frames": 2}), seed=1)
    assert ds.image.dims == ("frame", "gate", "y", "x")
    assert ds.image.shape == (2, 3, 32, 32)
    assert ds.expected.dtype == np.float32 and ds.target_mask.dtype == np.uint8
    assert ds.target_mask.dims == ("frame", "y", "x")
    assert ds.target_visibility.dims == ("frame", "gate")
    assert ds.surface_elevation.dims == ("frame", "sy", "sx")
    assert_allclose(ds.sx.values[1] - ds.sx.values[0], 0.064)
    assert_allclose(ds.gate_top.values, [4.0, 8.0, 1.0])
    for name, variable in {**ds.data_vars, **ds.coords}.items():
        assert "units" in variable.attrs and "long_name" in variable.attrs, name
    assert np.isfinite(ds.expected.values).all()


def test_default_scene_uses_the_mldc_gates():
    ds = render(scene(), seed=1)
    assert_allclose(ds.gate_top.values, np.array([12, 16, 20, 25, 35, 40]) * 0.3048)
    assert_allclose(ds.gate_bottom.values, np.array([32, 36, 40, 40, 45, 50]) * 0.3048)


def test_sequence_frames_evolve_and_the_platform_moves():
    s = target_scene(
        sequence={"frames": 3, "interval": 0.2, "velocity": [1.0, 0.0, 5.0]}, save_surface=True
    )
    ds = render(s, seed=4)
    assert_allclose(ds.platform_z.values, [34.0, 35.0, 36.0])
    assert_allclose(ds.platform_x.values, [0.0, 0.2, 0.4])
    assert_allclose(ds.time.values, [0.0, 0.2, 0.4])
    eta = ds.surface_elevation.values
    assert not np.array_equal(eta[0], eta[1])
    img = ds.expected.values
    assert not np.array_equal(img[0], img[1]) and not np.array_equal(img[1], img[2])


def test_a_rising_platform_sees_the_divergent_beam_weaken():
    # Example 1 of the paper: the helicopter climbs; the beam's power is fixed, so the
    # irradiance on the water falls with range (the pinhole keeps radiance per pixel).
    flat = dict(FLAT_DISK, laser={"beam": "divergent"})
    s = scene(
        **flat,
        target={"shape": "disk", "radius": 30.0, "depth": 3.0, "reflectance": 1.0},
        sequence={"frames": 2, "interval": 1.0, "velocity": [0.0, 0.0, 34.0]},
    )
    values = centre(render(s, seed=1).expected.values[:, 0])
    H, d = 34.0, 3.0
    ratio = ((H + d / N_WATER) / (2 * H + d / N_WATER)) ** 2
    assert_allclose(values[1] / values[0], ratio, rtol=0.01)


@pytest.mark.parametrize("nadir", [20.0, 45.0, 60.0], ids=lambda a: f"nadir{a:g}")
def test_oblique_views_render_the_target_near_the_image_centre(nadir):
    s = target_scene(platform={"nadir_deg": nadir, "azimuth_deg": 30.0})
    ds = render(s, seed=2)
    mask = ds.target_mask.values[0]
    assert np.isfinite(ds.expected.values).all()
    rows, cols = np.nonzero(mask)
    assert rows.size > 5
    assert abs(rows.mean() - 15.5) < 6 and abs(cols.mean() - 15.5) < 6


def test_paper_shading_returns_about_three_times_lambert():
    paper_scene = scene(
        **ROUGH,
        target={
            "shape": "sphere",
            "depth": 5.0,
            "radius": 0.6,
            "reflectance": 0.5,
            "shading": "paper",
        },
        receiver={"gates": [[4.0, 7.0]]},
    )
    lambert_scene = paper_scene.model_copy(
        update={"target": paper_scene.target.model_copy(update={"shading": "lambert"})}
    )
    # outside the silhouette the two agree; inside, paper weights integrate to 2πr²
    # (limb-brightened), lambert to (2/3)πr²: three times the return, blurred a little.
    # Summed over four seas: which parts of the sphere a rough sea lights varies (the
    # ratio of one realisation ranges over 1.7-3.0 with the multi-scale sea).
    inside = [0.0, 0.0]
    for seed in range(1, 5):
        paper, lambert = render(paper_scene, seed=seed), render(lambert_scene, seed=seed)
        mask = paper.target_mask.values[0].astype(bool)
        assert np.array_equal(mask, lambert.target_mask.values[0])
        a, b = paper.expected.values[0, 0], lambert.expected.values[0, 0]
        inside[0] += a[mask].sum()
        inside[1] += b[mask].sum()
        assert a[~mask].sum() > b[~mask].sum() * 0.99
    assert 2.0 < inside[0] / inside[1] < 4.0


@pytest.mark.parametrize("K", [0.0, 0.05, 0.8], ids=["K0", "K0.05", "K0.8"])
def test_hidden_fraction_is_the_share_of_the_slab_integral_behind_the_target(K):
    from workers.setup.gates import hidden_fraction

    top, bottom = 3.0, 9.0
    depths = np.array([1.0, 3.0, 5.0, 9.0, 12.0])
    got = hidden_fraction(depths, np.ones(5), top=top, bottom=bottom, diffuse_attenuation=K)
    z = np.linspace(top, bottom, 200001)
    weight = np.exp(-2 * K * z)
    expected = [weight[z >= d].sum() / weight.sum() for d in depths]
    assert_allclose(got, expected, atol=1e-4)


@pytest.mark.parametrize("nadir", [0.0, 30.0, 45.0, 60.0], ids=lambda a: f"nadir{a:g}")
def test_oblique_water_backscatter_is_the_single_scattering_integral(nadir):
    # Along a line of sight at angle ϑ in the water, with the laser along the same line:
    # horizontal irradiance J cosθ t e^(-Kl), normal irradiance that over cosϑ, return
    # β(π) dl with dl = dz/cosϑ, so the pixel sees (units of the white plane, J = 1)
    # π β t² (cosθ/cosϑ) [e^(-2K top/cosϑ) - e^(-2K bottom/cosϑ)] / (2K) / t0².
    from workers.optics.water import WaterOptics

    gate = (2.0, 6.0)
    s = water_column(gate, platform={"nadir_deg": nadir})
    optics = WaterOptics(**SLIGHTLY_TURBID)
    K = optics.diffuse_attenuation
    theta = np.radians(nadir)
    cos_w = np.cos(np.arcsin(np.sin(theta) / N_WATER))
    t = 1.0 - fresnel_reflectance(np.cos(theta), n1=1.0, n2=N_WATER)
    slab = (np.exp(-2 * K * gate[0] / cos_w) - np.exp(-2 * K * gate[1] / cos_w)) / (2 * K)
    expected = np.pi * optics.backscatter_pi * t**2 * np.cos(theta) / cos_w * slab / T0**2
    value = centre(render(s, seed=1).expected.values[0, 0])
    assert_allclose(value, expected, rtol=0.01)


def test_visibility_follows_the_visible_surface_of_the_sphere():
    # A sphere at 10.0-11.0 m seen from above shows its cap 10.0-10.5 m: a gate from
    # 10.67 m only sees its shadow, though the sphere's bottom reaches into it.
    s = target_scene(depth=10.5, gates=((10.67, 13.72), (9.0, 10.2), (11.2, 12.0)))
    s = s.model_copy(update={"target": s.target.model_copy(update={"radius": 0.5})})
    assert render(s, seed=1).target_visibility.values.tolist() == [[2, 1, 2]]


def test_a_sphere_is_attenuated_from_its_surface_not_its_centre():
    # Flat sea, nadir, no scattering, K = 0.2 /m: the centre pixel of a white Lambertian
    # sphere of radius 2 m at 6 m sees its top (4 m, normal incidence): the same as a white
    # disk at 4 m. Attenuating at the centre depth makes it e^(-2K·2) = 0.45 times darker.
    flat = {**FLAT_DISK, "water": clear_water(absorption=0.2)}
    sphere = scene(
        **flat, target={"shape": "sphere", "radius": 2.0, "depth": 6.0, "reflectance": 1.0}
    )
    disk = scene(**flat, target={"shape": "disk", "radius": 5.0, "depth": 4.0, "reflectance": 1.0})
    a = centre(render(sphere, seed=1).expected.values[0, 0])
    b = centre(render(disk, seed=1).expected.values[0, 0])
    assert_allclose(a, b, rtol=0.01)


def test_a_gate_opens_on_slant_range_at_oblique_views():
    # 30° nadir, flat sea, no water return: a wide disk at 5 m, a gate whose bottom is
    # 5.3 m along the central ray. Lines of sight towards the far edge (top rows) travel
    # longer in the air, so in the same time they reach less deep: where the gate's bottom
    # passes above 5 m the disk drops out of the gate. Closed form of the gate bottom for
    # the pixel ray at incidence θ (n = 1.34, H = 34 m):
    #   d(θ) = [H/cos θ_c + n·5.3/cos ϑ_c - H/cos θ] cos ϑ / n,  sin ϑ = sin θ / n.
    s = scene(
        surface={"spectrum": "flat"},
        water=clear_water(absorption=0.05),
        laser={"beam": "divergent", "field_of_view_deg": 30.0},
        target={"shape": "disk", "radius": 40.0, "depth": 5.0, "reflectance": 0.5},
        receiver={"gates": [[3.0, 5.3]]},
        platform={"nadir_deg": 30.0},
    )
    image = render(s, seed=1).expected.values[0, 0]
    n, H, pixels = N_WATER, 34.0, 32
    theta_c = np.radians(30.0)
    tangents = (np.arange(pixels) + 0.5 - pixels / 2) * (2 * np.tan(np.radians(3.35)) / pixels)
    theta = theta_c - np.arctan(tangents)  # row 0 is the far edge: the largest incidence
    cos_w = np.sqrt(1 - (np.sin(theta) / n) ** 2)
    cos_c = np.sqrt(1 - (np.sin(theta_c) / n) ** 2)
    bottom = (H / np.cos(theta_c) + n * 5.3 / cos_c - H / np.cos(theta)) * cos_w / n
    # by hand for the edge rows (θ = 33.25°, 26.75°): the far edge reaches 1.04 m less
    # deep than the centre, the near edge 0.91 m deeper
    assert_allclose(bottom[[0, -1]], [4.26, 6.21], atol=0.01)
    visible = image[:, pixels // 2] > 0.5 * image[:, pixels // 2].max()
    expected = bottom >= 5.0
    assert expected.any() and not expected.all()
    assert np.count_nonzero(visible != expected) <= 1


def test_a_target_on_a_gate_bottom_renders():
    # float32 rounding of a depth onto a gate's bottom made the hidden-fraction slab
    # inverted ("need top <= bottom"): the quickstart with target.depth 10.0 crashed.
    s = scene(
        **ROUGH,
        target={"shape": "sphere", "depth": 10.0, "radius": 0.3, "reflectance": 0.2},
        platform={"altitude": 34.0},
    )
    ds = render(s, seed=0)
    assert np.isfinite(ds.expected.values).all()


@pytest.mark.parametrize("pixels", [32, 33], ids=["on-a-pixel-corner", "on-a-pixel-centre"])
def test_a_small_target_far_below_is_seen_and_marked(pixels):
    # At 500 m a pixel spans 0.9 m: the default mine (0.3 m) is a third of one. Its mask is
    # never empty, it brightens the pixels it covers, and it is labelled in the gate.
    s = scene(
        surface={"spectrum": "flat"},
        water={"preset": "clear_ocean"},
        target={"shape": "sphere", "depth": 3.0, "radius": 0.3, "reflectance": 0.5},
        platform={"altitude": 500.0},
        receiver={"pixels": pixels, "gates": [[1.0, 5.0]]},
    )
    ds = render(s, seed=0)
    without = render(
        s.model_copy(update={"target": s.target.model_copy(update={"shape": "none"})}), seed=0
    )
    mask = ds.target_mask.values[0].astype(bool)
    assert 1 <= mask.sum() <= 4
    net = ds.expected.values[0, 0][mask].sum() - without.expected.values[0, 0][mask].sum()
    assert net > 0
    assert ds.target_visibility.values.tolist() == [[1]]


def test_a_limb_reaching_into_a_gate_is_a_shadow_not_in_gate():
    # Sphere 2.5–3.5 m seen at 45° nadir (31.8° in the water): its visible cap reaches
    # down to 3.26 m at the limb, so a gate from 3.2 m holds a sliver of limb; the pixels
    # show the sphere hiding the gate's water (net darker), so the label is shadow.
    s = scene(
        surface={"spectrum": "flat"},
        water={"preset": "coastal"},
        target={"shape": "sphere", "depth": 3.0, "radius": 0.5, "reflectance": 0.2},
        receiver={"gates": [[3.2, 6.0]], "pixels": 64},
        platform={"nadir_deg": 45.0},
    )
    ds = render(s, seed=0)
    without = render(
        s.model_copy(update={"target": s.target.model_copy(update={"shape": "none"})}), seed=0
    )
    mask = ds.target_mask.values[0].astype(bool)
    assert ds.expected.values[0, 0][mask].sum() < without.expected.values[0, 0][mask].sum()
    assert ds.target_visibility.values.tolist() == [[2]]


def gated_water(gates, *, nadir, laser=None):
    """Flat sea, water that absorbs and backscatters but does not forward-scatter.

    By default a wide parallel laser: nearly the same irradiance on every plane.
    """
    return scene(
        surface={"spectrum": "flat", "allow_repeat": True},
        water=clear_water(
            absorption=0.2, scattering=0.01, backscatter=0.01, phase_function="paper"
        ),
        target={"shape": "none"},
        receiver={"gates": [list(g) for g in gates]},
        platform={"nadir_deg": nadir},
        laser=laser or {"beam": "parallel", "field_of_view_deg": 60.0},
    )


def test_a_gate_opening_above_the_surface_holds_only_the_water():
    # 45° nadir, a gate 0.5–3 m along the central ray: towards the far edge the air path is
    # longer and the gate opens before light reaches the sea, so only the water from the
    # surface to the gate's closing counts (the slab is cut at the surface). Closed form per
    # row (monostatic, flat sea, no forward scattering), against a deep gate for the rest:
    #   S(row) ∝ e^(-2K (P_a - L)₊/n) - e^(-2K (P_b - L)₊/n), L the row's air path.
    # The default, monostatic beam (its range spreading, the same for both gates to 1-2 %,
    # is left in the tolerance; holding the full slab instead is 1.8 times too bright). At
    # 45° the laser lattice lands at a pitch 0.87-1.18 of the plane's cells, and its
    # bilinear splat rings by up to 3-5 % on a few rows of each gate's image (as it did
    # when the lines of sight were the rays); read between the rays, the two gates' rows
    # no longer ring alike, so the tolerance is 5 %.
    n, H, pixels = N_WATER, 34.0, 32
    image = render(
        gated_water([(0.5, 3.0), (10.0, 12.5)], nadir=45.0, laser={"beam": "divergent"}), seed=1
    ).expected
    ratio = (image.values[0, 0] / image.values[0, 1])[:, 14:18].mean(axis=1)
    theta_c = np.radians(45.0)
    sec_c = 1 / np.sqrt(1 - (np.sin(theta_c) / n) ** 2)
    tangents = (np.arange(pixels) + 0.5 - pixels / 2) * (2 * np.tan(np.radians(3.35)) / pixels)
    air = H / np.cos(theta_c - np.arctan(tangents))
    K = 0.2 + 0.01

    def slab(top, bottom):
        path = H / np.cos(theta_c) + n * np.array([top, bottom]) * sec_c
        w = np.maximum(path[:, None] - air[None, :], 0.0) / n
        return np.exp(-2 * K * w[0]) - np.exp(-2 * K * w[1])

    expected = slab(0.5, 3.0) / slab(10.0, 12.5)
    assert (air - H / np.cos(theta_c) > n * 0.5 * sec_c).sum() >= 4  # the far rows are cut
    assert_allclose(ratio / ratio[16], expected / expected[16], rtol=0.05)


@pytest.mark.parametrize("height", [-0.3, 0.3], ids=["trough", "crest"])
def test_a_crest_gates_less_water(height, monkeypatch):
    # A sea raised by η shortens the air path by η: within the same gate times the light
    # goes η/n less far into the water each way, so the gate's return changes by e^(-2Kη/n).
    from workers.sea.surface import Cascade, Surface

    def surface(setup, seed, times, *, backend):
        n, zero = 16, np.zeros((len(times), 16, 16), np.float32)
        raised = zero + np.float32(height)
        plane = Cascade(elevation=raised, slope_x=zero, slope_y=zero, spacing=1.0, grid_size=n)
        return Surface(cascades=(plane,))

    flat = gated_water([(3.0, 6.0)], nadir=0.0)
    raised = flat.model_copy(
        update={"surface": flat.surface.model_copy(update={"spectrum": "phillips"})}
    )
    base = centre(render(flat, seed=1).expected.values[0, 0])
    monkeypatch.setattr("workers.setup.compiled.Setup.surface", surface)
    value = centre(render(raised, seed=1).expected.values[0, 0])
    K = 0.2 + 0.01
    assert_allclose(value / base, np.exp(-2 * K * height / N_WATER), rtol=0.003)


def test_saved_surface_is_the_summed_sea_over_the_footprint():
    # The stored grid is where the image looks (the footprint, centred on the boresight's
    # sea point at the origin), and holds the sum of all cascades, which the renderer
    # refracts at: not the finest cascade's periodic patch [0, NΔ₀)².
    s = scene(
        surface={**ROUGH["surface"], "grid_size": 32, "spacing": None, "allow_repeat": False},
        target={"shape": "sphere", "depth": 5.0, "radius": 0.6, "reflectance": 0.5},
        save_surface=True,
        sequence={"frames": 2, "interval": 0.5},
    )
    seed = SampleSeed(root=3)
    surface = scene_setup(s).surface(seed, [0.0, 0.5])
    assert len(surface.cascades) > 1  # a multi-scale sea, not periodic on the finest patch
    ds = render(s, seed=seed)
    half = 0.5 * s.footprint()  # at nadir the footprint is [-L/2, L/2]²
    for name in ("sx", "sy"):
        axis = ds[name].values
        assert_allclose([axis[0], axis[-1]], [-half, half], rtol=1e-12)
        assert_allclose(np.diff(axis), s.surface_spacing(), rtol=1e-12)
    for frame in range(2):
        truth = surface.elevation_at(ds.sx.values[None, :], ds.sy.values[:, None], frame)
        assert_array_equal(ds.surface_elevation.values[frame], truth)
    assert ds.surface_elevation.std() > 0.01  # a real sea, m


@pytest.mark.parametrize("where", ["centre", "corner", "none"])
def test_signal_means_are_the_means_over_the_mask_and_its_ring(where):
    # The means are taken on the box around the mask; brute force over the whole image:
    # the ring is every pixel within the ring's width (Chebyshev) of the mask, outside it.
    rng = np.random.default_rng(2)
    values = rng.random((2, 3, 40, 40)).astype(np.float32)
    mask = np.zeros((2, 40, 40), bool)
    if where == "centre":
        mask[0, 15:20, 18:25], mask[1, 22:24, 10:12] = True, True
    elif where == "corner":
        mask[:, 0:3, 36:40] = True
    inside, ring = signal_means(values, mask)
    width = max(2, round(RING_FRACTION * 40))
    for s in range(2):
        for region, got in ((mask[s], inside[s]), (ring_around(mask[s], width), ring[s])):
            if not region.any():
                assert np.all(np.isnan(got))
                continue
            expected = values[s][:, region].astype(np.float64).mean(axis=1)
            assert_allclose(got, expected, rtol=1e-12)
