"""Tests of workers.setup.seasetup: the sea's objects built below the configuration classes."""

import numpy as np
import pytest

from workers.sea import spectra
from workers.sea.conditioning import kriging
from workers.sea.described import wave_spectrum
from workers.settings.scene import Scene
from workers.settings.sea import SurfaceSpec
from workers.settings.section import SceneError
from workers.setup.builder import scene_setup
from workers.setup.seasetup import scene_sea, surface_kriging, surface_sea

WIND = {"wind_speed": 7.0, "wind_direction": np.radians(30.0)}


@pytest.mark.parametrize(
    ("section", "factory"),
    [
        (SurfaceSpec, "sea"),
        (SurfaceSpec, "wave_spectrum"),
        (SurfaceSpec, "kriging"),
        (Scene, "sea"),
    ],
    ids=["SurfaceSpec.sea", "SurfaceSpec.wave_spectrum", "SurfaceSpec.kriging", "Scene.sea"],
)
def test_the_configuration_classes_build_nothing(section, factory):
    # issue #28 item 1: the factories moved to one setup layer below the settings
    assert not hasattr(section, factory)


@pytest.mark.parametrize(
    ("settings", "expected"),
    [
        ({"spectrum": "flat"}, None),
        (
            {"spectrum": "elfouhaily", "inverse_wave_age": 1.2},
            spectra.Elfouhaily(**WIND, inverse_wave_age=1.2),
        ),
        ({"spectrum": "phillips"}, spectra.Phillips(**WIND)),
        ({"spectrum": "pierson_moskowitz"}, spectra.PiersonMoskowitz(**WIND)),
        ({"spectrum": "jonswap", "fetch": 2.0e4}, spectra.Jonswap(**WIND, fetch=2.0e4)),
    ],
    ids=["flat", "elfouhaily", "phillips", "pierson_moskowitz", "jonswap"],
)
def test_wave_spectrum_is_the_named_spectrum_with_the_sections_settings(settings, expected):
    surface = SurfaceSpec(**settings, wind_speed=7.0, wind_direction_deg=30.0)
    assert wave_spectrum(surface) == expected


def test_surface_sea_lays_the_cascades_out_and_names_bad_patches():
    surface = SurfaceSpec(grid_size=64, spacing=0.05, coarse_patches=[12.8])
    sea = surface_sea(surface, span=3.0)
    assert sea.patches == (3.2, 12.8) and sea.grid_size == 64
    assert sea.spectrum == wave_spectrum(surface)
    assert surface_sea(SurfaceSpec(spectrum="flat"), span=3.0) is None
    default = SurfaceSpec(grid_size=64, coarse_patches=[2.0])  # spacing from the footprint
    with pytest.raises(ValueError, match=r"surface\.coarse_patches: .*patch 0 is grid_size"):
        surface_sea(default, span=3.2)


def test_the_scenes_setup_holds_the_sea_of_the_setup_layer():
    scene = Scene.model_validate({"platform": {"altitude": 300.0}})
    assert scene_setup(scene).sea == scene_sea(scene)
    assert scene_sea(scene) == surface_sea(scene.surface, span=scene.footprint())


def test_surface_kriging_is_built_once_and_names_the_field():
    points = [[1.0, 2.0, 0.3], [2.0, 1.0, -0.1]]
    surface = {"grid_size": 32, "spacing": 0.1, "conditioning": {"points": points}}
    scene = Scene.model_validate({"surface": surface})
    sea = scene_sea(scene)
    assert surface_kriging(Scene().surface, scene_sea(Scene())) is None
    kriging.cache_clear()
    first = surface_kriging(scene.surface, sea)
    assert surface_kriging(scene.surface, sea) is first
    assert kriging.cache_info().misses == 1
    near = {**surface, "conditioning": {"points": [[1.0, 3.0, 0.1], [1.000001, 3.0, 0.1]]}}
    near = Scene.model_validate({"surface": near})
    with pytest.raises(SceneError, match=r"surface\.conditioning\.points: "):
        surface_kriging(near.surface, scene_sea(near))
