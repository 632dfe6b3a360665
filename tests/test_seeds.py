"""Random streams keyed by position (docs/model.md §0)."""

import pytest

from workers.settings.seeds import SampleSeed


def draw(rng):
    return rng.standard_normal(8).tobytes()


def test_surface_stream_ignores_the_parameter_point():
    a = SampleSeed(root=7, point=0, realisation=3)
    b = SampleSeed(root=7, point=5, realisation=3)
    assert draw(a.surface_rng()) == draw(b.surface_rng())
    assert draw(a.noise_rng()) != draw(b.noise_rng())


def test_streams_differ_by_realisation_and_root_and_from_each_other():
    base = SampleSeed(root=7, realisation=0)
    assert draw(base.surface_rng()) != draw(SampleSeed(root=7, realisation=1).surface_rng())
    assert draw(base.surface_rng()) != draw(SampleSeed(root=8, realisation=0).surface_rng())
    assert draw(base.surface_rng()) != draw(base.noise_rng())


@pytest.mark.parametrize("field", ["root", "point", "realisation"])
def test_negative_or_non_integer_seeds_are_refused(field):
    with pytest.raises(ValueError, match=field):
        SampleSeed(**{"root": 1, field: -1})
    with pytest.raises(ValueError, match=field):
        SampleSeed(**{"root": 1, field: 1.5})
