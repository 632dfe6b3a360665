"""Scene validation: defaults, ranges and the errors users see."""

import pytest
from pydantic import ValidationError

from workers.scene import MLDC_GATES, Scene


def test_defaults_are_the_papers_example_3_geometry():
    s = Scene()
    assert s.surface.spectrum == "elfouhaily"
    assert (s.surface.grid_size, s.surface.spacing) == (256, 0.016)
    assert (s.platform.altitude, s.receiver.field_of_view_deg) == (34.0, 6.7)
    assert s.receiver.gate_depths == MLDC_GATES


def test_mldc_gates_in_metres():
    # Table 1 of the paper, in feet; 1 ft = 0.3048 m exactly.
    feet = [(12, 32), (16, 36), (20, 40), (25, 40), (35, 45), (40, 50)]
    assert MLDC_GATES == tuple((a * 0.3048, b * 0.3048) for a, b in feet)


@pytest.mark.parametrize(
    ("data", "where"),
    [
        ({"target": {"colour": "red"}}, "target.colour"),
        ({"target": {"depth": "deep"}}, "target.depth"),
        ({"target": {"reflectance": 1.5}}, "target.reflectance"),
        ({"platform": {"nadir_deg": 75}}, "platform.nadir_deg"),
        ({"surface": {"spectrum": "tessendorf"}}, "surface.spectrum"),
        ({"surface": {"grid_size": 255}}, "surface"),
        ({"receiver": {"gates": [[10, 5]]}}, "receiver"),
        ({"target": {"depth": 0.2, "radius": 0.3}}, "target"),
        ({"water": {"preset": None, "absorption": 0.1}}, "water"),
        ({"radiometry": {"white_plane_photons": -1}}, "radiometry.white_plane_photons"),
    ],
    ids=[
        "unknown-key",
        "wrong-type",
        "reflectance-range",
        "nadir-range",
        "unknown-spectrum",
        "odd-grid",
        "inverted-gate",
        "sphere-breaks-surface",
        "incomplete-water",
        "negative-photons",
    ],
)
def test_bad_scenes_name_the_field(data, where):
    with pytest.raises(ValidationError) as info:
        Scene.model_validate(data)
    located = [".".join(str(p) for p in e["loc"]) for e in info.value.errors()]
    assert any(loc.startswith(where) for loc in located), located


def test_explicit_gates_and_water():
    s = Scene.model_validate(
        {
            "receiver": {"gates": [[1.0, 3.0], [2.0, 6.0]]},
            "water": {"preset": None, "absorption": 0.1, "scattering": 0.0, "backscatter": 0.0},
        }
    )
    assert s.receiver.gate_depths == ((1.0, 3.0), (2.0, 6.0))


def test_scene_is_frozen():
    s = Scene()
    with pytest.raises(ValidationError):
        s.target.depth = 3.0


def test_backscatter_cannot_exceed_scattering():
    with pytest.raises(ValidationError, match="backscatter"):
        Scene.model_validate({"water": {"preset": "clear_ocean", "backscatter": 0.5}})


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"target": {"x": 1.0}}, "both x and y"),
        (
            {
                "laser": {"field_of_view_deg": 60},
                "receiver": {"field_of_view_deg": 1, "pixels": 512},
            },
            "rays per side",
        ),
        (
            {
                "laser": {"field_of_view_deg": 0.2, "rays": 4096},
                "receiver": {"field_of_view_deg": 40},
            },
            "would span",
        ),
    ],
    ids=["half-set-position", "too-many-rays", "too-fine-lattice"],
)
def test_scenes_that_would_mislead_or_exhaust_memory_are_refused(data, message):
    with pytest.raises(ValidationError, match=message):
        Scene.model_validate(data)
