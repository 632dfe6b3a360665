"""Scene validation: defaults, ranges and the errors users see."""

import math

import pytest
from pydantic import BaseModel, ValidationError

from workers.render import render
from workers.settings.instrument import MLDC_GATES
from workers.settings.scene import Scene, footprint_span
from workers.setup.seasetup import scene_sea


def test_defaults_are_the_papers_example_3_geometry():
    s = Scene()
    assert s.surface.spectrum == "elfouhaily"
    assert (s.surface.grid_size, s.surface.spacing) == (256, None)
    assert s.surface_spacing() == pytest.approx(2 * 34 * math.tan(math.radians(6.7 / 2)) / 256)
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


# --- the footprint against the periodic sea patch (issue #9) ---------------------------

H, FOV = 34.0, math.radians(6.7)
T = math.tan(FOV / 2)
ALONG_30 = H * (math.tan(math.radians(30) + FOV / 2) - math.tan(math.radians(30) - FOV / 2))
"""Near to far edge of the footprint at 30° from the vertical: h tan(θ ± α/2) [m]."""


@pytest.mark.parametrize(
    ("nadir_deg", "azimuth_deg", "expected"),
    [
        (0.0, 0.0, 2 * H * T),
        (0.0, 90.0, 2 * H * T),
        # a square footprint turned by 45°: its diagonal runs along x
        (0.0, 45.0, 2 * H * T * math.sqrt(2)),
        # looking north at 30°: from the near edge to the far one, h tan(θ ± α/2)
        (
            30.0,
            0.0,
            H * (math.tan(math.radians(30) + FOV / 2) - math.tan(math.radians(30) - FOV / 2)),
        ),
        (
            30.0,
            -90.0,
            H * (math.tan(math.radians(30) + FOV / 2) - math.tan(math.radians(30) - FOV / 2)),
        ),
        # the field reaches the horizon
        (60.0, 0.0, math.inf),
    ],
    ids=["nadir", "nadir-east", "nadir-45", "oblique-north", "oblique-west", "horizon"],
)
def test_footprint_span_closed_forms(nadir_deg, azimuth_deg, expected):
    field = math.radians(64.0) if expected == math.inf else FOV
    span = footprint_span(
        altitude=H,
        nadir=math.radians(nadir_deg),
        azimuth=math.radians(azimuth_deg),
        field_of_view=field,
    )
    assert span == pytest.approx(expected, rel=1e-12)


FOOTPRINT_FIELDS = (
    "platform.altitude",
    "receiver.field_of_view_deg",
    "surface.grid_size",
    "surface.spacing",
    "surface.allow_repeat",
)


SINGLE = {"coarse_patches": [], "spacing": 0.016}


@pytest.mark.parametrize(
    "data",
    [
        # 2 H tan(α/2) = 4.21 m at 36 m, over the default 256 x 0.016 m = 4.10 m patch
        {"platform": {"altitude": 36.0}, "surface": SINGLE},
        {"surface": {**SINGLE, "spacing": 0.015}},
        {"platform": {"nadir_deg": 20.0}, "surface": SINGLE},
        # from 34 m the platform climbs 2 m during the sequence
        {
            "sequence": {"frames": 11, "interval": 0.2, "velocity": [0.0, 0.0, 1.0]},
            "surface": SINGLE,
        },
        # 300 m: a 35 m footprint over explicit cascades of 4.1 and 32.8 m
        {"platform": {"altitude": 300.0}, "surface": {"coarse_patches": [32.8], "spacing": 0.016}},
    ],
    ids=["higher", "smaller-patch", "oblique", "climbing", "cascades-too-small"],
)
def test_a_footprint_wider_than_the_sea_patch_is_refused_unless_allowed(data):
    # Issue #9: a sea of period P shows the same waves twice in one image when the
    # footprint is wider than P; with cascades P is the coarsest patch.
    with pytest.raises(ValidationError) as info:
        Scene.model_validate(data)
    message = str(info.value)
    assert "repeat inside the image" in message
    for field in FOOTPRINT_FIELDS:
        assert field in message
    surface = {**data.get("surface", {}), "allow_repeat": True}
    assert Scene.model_validate({**data, "surface": surface}).surface.allow_repeat
    # a flat sea has nothing to repeat
    flat = {**data, "surface": {**data.get("surface", {}), "spectrum": "flat"}}
    Scene.model_validate(flat)


def test_the_default_footprint_fits_the_default_patch():
    scene = Scene()
    span = footprint_span(altitude=34.0, nadir=0.0, azimuth=0.0, field_of_view=FOV)
    assert span <= scene.surface.grid_size * scene.surface_spacing()


@pytest.mark.parametrize("altitude", [36.0, 300.0, 500.0])
def test_the_default_cascades_cover_the_footprint(altitude):
    # Issue #14: by default the coarsest cascade covers the footprint at any altitude
    scene = Scene.model_validate({"platform": {"altitude": altitude}})
    span = footprint_span(altitude=altitude, nadir=0.0, azimuth=0.0, field_of_view=FOV)
    assert scene_sea(scene).patches[-1] >= span
    assert scene_sea(scene).patches[0] == pytest.approx(span)  # the finest covers it too


@pytest.mark.parametrize(
    ("patches", "message"),
    [([3.0], "larger than patch 0"), ([4.1, 100.0], "at most grid_size/16"), ([-1.0], "0")],
    ids=["smaller", "too-far", "negative"],
)
def test_bad_coarse_patches_are_refused_with_the_field(patches, message):
    with pytest.raises(ValidationError) as info:
        Scene.model_validate({"surface": {"coarse_patches": patches}})
    assert "coarse_patches" in str(info.value) and message in str(info.value)


def test_cli_validate_refuses_a_repeating_sea_with_a_message(tmp_path, cli):
    sweep = tmp_path / "wide.yaml"
    sweep.write_text(
        "name: wide\nseed: 1\noutput: wide.zarr\n"
        "scene:\n  platform: {altitude: 60.0}\n  receiver: {pixels: 16}\n"
        "  surface: {coarse_patches: [], spacing: 0.016}\n"
    )
    result = cli("validate", sweep, cwd=tmp_path)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "surface.allow_repeat" in result.stderr and "platform.altitude" in result.stderr
    allowed = tmp_path / "allowed.yaml"
    allowed.write_text(
        sweep.read_text().replace("coarse_patches: []", "coarse_patches: [], allow_repeat: true")
    )
    assert cli("validate", allowed, cwd=tmp_path).returncode == 0


def scene_leaves(model=Scene, prefix=""):
    """(dotted path, pydantic field) of every value of the scene, sections walked into."""
    for name, field in model.model_fields.items():
        annotation = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            yield from scene_leaves(annotation, f"{prefix}{name}.")
        else:
            yield f"{prefix}{name}", field


def test_every_scene_field_declares_its_unit_as_data():
    leaves = dict(scene_leaves())
    assert len(leaves) > 40 and "surface.conditioning.noise" in leaves
    for path, field in leaves.items():
        extra = field.json_schema_extra
        assert isinstance(extra, dict) and extra.get("units"), f"{path} declares no unit"


def test_scenes_are_hashable_and_equal_by_value():
    data = {
        "receiver": {"gates": [[2.0, 6.0], [5.0, 9.0]]},
        "surface": {"conditioning": {"points": [[1.0, 2.0, 0.1], [2.0, 1.0, 0.0, 0.5]]}},
    }
    first = Scene.model_validate(data)
    again = Scene.model_validate({**data, "water": {"preset": "coastal"}})
    assert first == again and hash(first) == hash(again)
    assert {first: "cached"}[again] == "cached"
    assert first != Scene.model_validate({**data, "receiver": {"gates": [[2.0, 7.0]]}})


def test_a_render_never_round_trips_its_scene_through_json(monkeypatch):
    scene = Scene.model_validate(
        {
            "surface": {"grid_size": 32, "spacing": 0.1, "allow_repeat": True},
            "receiver": {"pixels": 16, "gates": [[2.0, 6.0]]},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0},
        }
    )

    def refused(*args, **kwargs):
        raise AssertionError("the scene went through JSON")

    monkeypatch.setattr(Scene, "model_dump_json", refused)
    monkeypatch.setattr(Scene, "model_validate_json", refused)
    ds = render(scene, seed=1)
    assert ds.expected.shape == (1, 1, 16, 16)


@pytest.mark.parametrize("fraction", [0.001, 0.5, 1.0], ids=["below", "half", "all"])
def test_a_backscatter_fraction_the_fit_cannot_meet_is_refused_whatever_it_is(fraction):
    # issue #37 item 15: b_b = b (no forward scattering) was accepted and rendered while
    # b_b/b = 0.5 was refused; the Fournier-Forand fit needs 0.002 <= b_b/b <= 0.095
    # (`workers.optics.phases.fournier_forand.FF_FRACTIONS`) whatever b_f, so both are
    # refused, naming the field
    water = {"preset": None, "absorption": 0.1, "scattering": 0.4, "backscatter": 0.4 * fraction}
    with pytest.raises(ValidationError, match=r"water\.backscatter: b_b/b = .* water\.phase"):
        Scene.model_validate({"water": water})
    # the paper's phase function is not fitted to b_b/b: any b_b <= b goes
    paper = Scene.model_validate({"water": {**water, "phase_function": "paper"}})
    assert paper.water.coefficients["backscatter"] == 0.4 * fraction
    # nor does a water that does not scatter need one
    still = {**water, "scattering": 0.0, "backscatter": 0.0}
    assert Scene.model_validate({"water": still}).water.coefficients["scattering"] == 0.0
