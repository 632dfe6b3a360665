"""configs/wind-trend.yaml: Tulldahl & Steinvall's case as the model allows (issue #29.4).

Their figures (Applied Optics; a waveform model validated on Hawk Eye data): a 1 m³ object
at 9 m, Pd above 90 % at 1 m/s wind and below 80 % at 6 m/s in the same water. The config
must stand for that case, pair every target with its target-free twin on the same seas
(what `detect` needs), and hold enough realisations to tell 90 % from 80 %.
"""

import math

import numpy as np
import pytest
from conftest import ROOT

from service.cli import main
from workers.detectors.detection import MIN_FALSE_ALARMS, held_out

PATH = ROOT / "configs" / "wind-trend.yaml"

PFA = 1e-2
"""The stricter false-alarm rate `detect` reports Pd at (the one the README table uses)."""


@pytest.fixture(scope="module")
def plan():
    from service.sweep import load_sweep

    return load_sweep(PATH)


def test_the_target_is_one_cubic_metre_at_nine_metres_inside_a_gate(plan):
    spheres = [scene for scene in plan.scenes if scene.target.shape != "none"]
    assert spheres, "no point has a target"
    for scene in spheres:
        target = scene.target
        assert target.shape == "sphere"
        assert 4.0 / 3.0 * math.pi * target.radius**3 == pytest.approx(1.0, rel=1e-3)
        assert target.depth == 9.0
        top, bottom = target.depth - target.radius, target.depth + target.radius
        # A gate holds the whole sphere (its light on time), another its top.
        assert any(a <= top and bottom <= b for a, b in scene.receiver.gates)
        assert any(a < top < b < bottom for a, b in scene.receiver.gates)


def test_wind_spans_their_two_speeds_and_every_target_has_its_twin(plan):
    winds = sorted({scene.surface.wind_speed for scene in plan.scenes})
    assert winds[0] == 1.0 and winds[-1] == 10.0 and 6.0 in winds
    scenes = set(plan.scenes)
    for scene in plan.scenes:
        if scene.target.shape != "none":
            # detect pairs it with the target-free point of the same scene, same seas.
            assert scene.without_target() in scenes
    # Same water, same geometry, same photons at every wind: only the sea changes.
    rest = [scene.model_dump(exclude={"surface", "target"}) for scene in plan.scenes]
    assert all(other == rest[0] for other in rest)
    surfaces = [scene.surface.model_dump(exclude={"wind_speed"}) for scene in plan.scenes]
    assert all(other == surfaces[0] for other in surfaces)


def test_enough_realisations_to_tell_ninety_from_eighty_percent(plan):
    realisations = plan.realisations
    # Pd at Pfa = 1e-2 is reported only with MIN_FALSE_ALARMS / Pfa negatives, for the
    # trained detector among its held-out realisations too.
    assert held_out(realisations).sum() >= MIN_FALSE_ALARMS / PFA
    # Binomial 95 % half-width of a Pd near 0.85 below half the 0.1 gap.
    assert 1.96 * np.sqrt(0.85 * 0.15 / realisations) < 0.05


def test_the_config_validates_on_the_command_line(capsys):
    assert main(["validate", str(PATH)]) == 0
    assert "wind-trend" in capsys.readouterr().out
