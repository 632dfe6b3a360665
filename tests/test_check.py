"""``oceanlidar check``: the fidelity report of a sweep, and the comparison it shares.

The command renders a few points of a small sweep by both renderers (a flat sea, clear
water, 32 px, 10⁵ photons: about a second a point once compiled) and holds the fast
renderer to transport (`workers.fidelity.compare`); the comparison's verdicts are tested
on images made by hand, where the answer is known exactly.
"""

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.check import spanning_points
from service.cli import main
from service.sweep import parse_sweep
from workers import fidelity
from workers.fidelity import BARS, Light, compare, gate_kinds
from workers.settings.scene import Scene

SWEEP = """\
name: check-test
seed: 5
realisations: 3
output: {output}
scene:
  surface: {{spectrum: flat}}
  water: {{preset: clear_ocean}}
  target: {{shape: sphere, radius: 0.3, depth: 5.0, reflectance: 0.2}}
  receiver: {{pixels: 32, field_of_view_deg: 6.7, gates: mldc}}
  radiometry: {{mode: normalised, white_plane_photons: 0.0}}
  transport: {{photons: 100000, method: {method}}}
sweep:
  method: grid
  parameters:
    target.reflectance: {{values: [0.2, 0.3, 0.4]}}
"""


def sweep_file(folder: Path, method: str = "small_angle") -> Path:
    path = folder / "sweep.yaml"
    path.write_text(SWEEP.format(output=folder / "out.zarr", method=method))
    return path


@pytest.fixture(scope="module")
def checked(tmp_path_factory):
    """The command's exit code, output and plot on the sweep's two extreme points."""
    folder = tmp_path_factory.mktemp("check")
    plot = folder / "check.png"
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["check", str(sweep_file(folder)), "--points", "2", "--plot", str(plot)])
    return code, out.getvalue(), err.getvalue(), plot, folder


def test_check_holds_the_fast_renderer_on_a_flat_sea_and_exits_0(checked):
    # clear water, flat sea, nadir: the calibrated case (tests/test_transport_reference.py
    # holds it at 1.6e7 photons): every gate within its bars
    code, out, err, _, _ = checked
    assert code == 0, out + err
    assert "2 of 2 points hold" in out
    assert "FAIL" not in out
    assert "checking 2 of 3 points (0, 2)" in err


def test_check_prints_each_gate_of_each_point(checked):
    _, out, _, _, _ = checked
    lines = out.splitlines()
    for point, value in ((0, "0.2"), (2, "0.4")):
        header = next(i for i, line in enumerate(lines) if line.startswith(f"point {point} "))
        assert f"target.reflectance={value}" in lines[header]
        rows = lines[header + 2 : header + 8]
        kinds = [row.split()[1] for row in rows]
        # sphere 4.7-5.3 m: gate 1 (3.7-9.8 m) holds it, gate 2 (from 4.88 m) cuts it,
        # gates 3-6 lie below it
        assert kinds == ["inside", "edge", "shadow", "shadow", "shadow", "shadow"], rows
        ratio = float(rows[0].split()[2])  # the background, fast/transport
        assert abs(ratio - 1) < 0.05


def test_check_draws_the_comparison(checked):
    *_, plot, _ = checked
    with Image.open(plot) as image:
        width, height = image.size
    assert width > 800 and height > 400  # two points: two pairs of image rows


def test_check_writes_nothing_into_the_output(checked):
    *_, folder = checked
    assert not (folder / "out.zarr").exists()


def test_check_fails_a_planted_discrepancy(tmp_path, capsys, monkeypatch):
    # a fast renderer whose target's light is doubled: the target's contrast inside
    # gate 1 is twice transport's, outside the bars: exit 1, marked
    rendered = fidelity.render_pair

    def doubled(scene, **kwargs):
        image, noisy, twin, twin_noisy = rendered(scene, **kwargs)
        return twin + 2 * (image - twin), noisy, twin, twin_noisy

    monkeypatch.setattr(fidelity, "render_pair", doubled)
    code = main(["check", str(sweep_file(tmp_path)), "--points", "1"])
    out = capsys.readouterr().out
    assert code == 1, out
    gate1 = next(line for line in out.splitlines() if line.strip().startswith("1 inside"))
    assert "FAIL (bar 5 %" in gate1
    assert "0 of 1 points hold; outside the bars: point(s) 0" in out


def test_check_is_seeded(tmp_path):
    # the same sweep (same seed) gives the same comparison, bit for bit
    plan = parse_sweep(sweep_file(tmp_path).read_text(), folder=tmp_path)
    sample = plan.sample(0)
    first = fidelity.transport_light(sample.scene, seed=sample.seed)
    again = fidelity.transport_light(sample.scene, seed=sample.seed)
    for name in ("image", "twin", "stderr", "twin_stderr", "mask"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--points", "0"], "--points 0: check at least 1 point"),
        (["--photons", "10"], "--photons 10: photons per frame run 1000 to 1000000000"),
        (["--plot", "/nonexistent-folder/x.png"], "--plot '/nonexistent-folder/x.png': no folder"),
        (["--plot", "PLACE/x.unknown"], "cannot write a .unknown picture"),
    ],
    ids=["points", "photons", "plot-folder", "plot-type"],
)
def test_check_refuses_bad_flags(tmp_path, capsys, flags, message):
    flags = [flag.replace("PLACE", str(tmp_path)) for flag in flags]
    assert main(["check", str(sweep_file(tmp_path)), *flags]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err


def test_check_refuses_a_monte_carlo_sweep(tmp_path, capsys):
    assert main(["check", str(sweep_file(tmp_path, method="monte_carlo"))]) == 2
    err = capsys.readouterr().err
    assert "transport.method: point 0 renders by monte_carlo already" in err
    assert "Traceback" not in err


def test_check_refuses_a_bad_sweep_naming_the_field(tmp_path, capsys):
    path = sweep_file(tmp_path)
    path.write_text(path.read_text().replace("radius: 0.3", "radius: -1"))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "target.radius" in err and "Traceback" not in err


def test_spanning_points_are_a_grids_corners_farthest_first(tmp_path):
    text = sweep_file(tmp_path).read_text()
    text = text.replace(
        "    target.reflectance: {values: [0.2, 0.3, 0.4]}",
        "    target.reflectance: {values: [0.2, 0.3, 0.4]}\n"
        "    water.preset: {values: [clear_ocean, coastal, turbid_harbour]}",
    )
    plan = parse_sweep(text, folder=tmp_path)
    # points (reflectance, preset) in grid order: 0 = (0.2, clear) ... 8 = (0.4, turbid);
    # the opposite corner first, then the two others (ties: the lower index)
    assert spanning_points(plan, 4) == [0, 8, 2, 6]
    assert spanning_points(plan, 1) == [0]
    assert len(spanning_points(plan, 100)) == 9


# the comparison on images made by hand: a uniform twin of 100 counts (error 1 a pixel)
# and a target that adds `contrast` over a 4x4 mask


def hand_light(contrast, *, gates=4, error=1.0):
    twin = np.full((gates, 32, 32), 100.0)
    mask = np.zeros((32, 32), dtype=bool)
    mask[14:18, 14:18] = True
    image = twin.copy()
    image[:, mask] *= 1.0 + np.asarray(contrast, dtype=np.float64)[:, None]
    stderr = np.full_like(twin, error)
    return Light(image, twin, stderr, stderr, mask, 0.0)


KINDS = ("inside", "edge", "shadow", "above")


def test_compare_holds_an_exact_copy():
    reference = hand_light([1.0, 0.5, -0.6, 0.0])
    checks = compare(reference, Light(reference.image, reference.twin), kinds=KINDS)
    assert [c.kind for c in checks] == list(KINDS)
    assert all(c.holds for c in checks)
    assert [c.contrast.value for c in checks] == pytest.approx([1, 1, 0, 0])
    assert checks[0].background.value == 1.0
    # background error: 1 count a pixel over 1024 pixels of 100 counts
    assert checks[0].background.error == pytest.approx(1 / 32 / 100)


@pytest.mark.parametrize(
    ("gate", "fast", "holds"),
    [
        (0, [1.04, 0.5, -0.6, 0.0], True),  # inside: 4 % off, bar 5 %
        (0, [1.2, 0.5, -0.6, 0.0], False),  # inside: 20 % off
        (1, [1.0, 0.54, -0.6, 0.0], True),  # edge: 8 % off, bar 10 %
        (1, [1.0, 0.6, -0.6, 0.0], False),  # edge: 20 % off
        (2, [1.0, 0.5, -0.56, 0.0], True),  # shadow: 0.04 off, bar 0.05
        (2, [1.0, 0.5, -0.4, 0.0], False),  # shadow: 0.2 off
        (3, [1.0, 0.5, -0.6, 0.2], False),  # above: 0.2 of contrast where none belongs
    ],
)
def test_compare_holds_each_kind_to_its_bar(gate, fast, holds):
    reference = hand_light([1.0, 0.5, -0.6, 0.0], error=0.01)  # errors far below the bars
    other = hand_light(fast, error=0.01)
    checks = compare(reference, Light(other.image, other.twin), kinds=KINDS)
    assert checks[gate].contrast.holds is holds
    assert all(c.holds for g, c in enumerate(checks) if g != gate)


def test_compare_allows_the_references_error():
    # a 20 % excess inside a gate holds when the reference's error explains it: the
    # contrast's error bound over 16 pixels of error e: (e/4 + e/4 · 2)/100 for t/b = 2
    error = 40.0
    bound = (error / 4 + error / 4 * 2) / 100  # 0.3 of a contrast of 1
    reference = hand_light([1.0, 0.5, -0.6, 0.0], error=error)
    fast = hand_light([1.2, 0.5, -0.6, 0.0])
    check = compare(reference, Light(fast.image, fast.twin), kinds=KINDS)[0]
    assert check.reference_error == pytest.approx(bound)
    assert check.contrast.error == pytest.approx(1.2 * bound)
    assert 0.2 > BARS["inside"] and check.contrast.holds is True


def test_compare_leaves_an_unresolved_contrast_unjudged():
    reference = hand_light(
        [0.01, 0.5, -0.6, 0.0], error=1.0
    )  # 0.01, its error 0.005: under 3 errors
    fast = hand_light([0.5, 0.5, -0.6, 0.0])
    check = compare(reference, Light(fast.image, fast.twin), kinds=KINDS)[0]
    assert check.contrast.holds is None and check.holds


def test_compare_fails_a_background_off_by_a_tenth():
    reference = hand_light([1.0, 0.5, -0.6, 0.0], error=0.01)
    fast = Light(reference.image * 1.1, reference.twin * 1.1)
    checks = compare(reference, fast, kinds=KINDS)
    assert all(c.background.holds is False for c in checks)
    assert all(c.contrast.holds for c in checks)


def test_gate_kinds_widen_the_target_by_the_seas_reach():
    scene = Scene.model_validate(
        {
            "surface": {"spectrum": "flat"},
            "target": {"shape": "sphere", "radius": 0.3, "depth": 5.0},
            "receiver": {
                "pixels": 16,
                "gates": [[1, 4.6], [1, 4.8], [4.5, 5.5], [5.0, 6], [5.4, 6]],
            },
        }
    )
    assert gate_kinds(scene, sea_std=0.0) == ("above", "edge", "inside", "edge", "shadow")
    # a sea of 0.1 m std: the extent 4.5-5.5 m, each gate's edge within it cuts
    assert gate_kinds(scene, sea_std=0.1) == ("edge", "edge", "inside", "edge", "edge")
    disk = scene.model_copy(update={"target": scene.target.model_copy(update={"shape": "disk"})})
    # a disk at a gate's top lies in its shadow
    assert gate_kinds(disk, sea_std=0.0) == ("above", "above", "inside", "shadow", "shadow")
    assert gate_kinds(scene.without_target(), sea_std=0.0) == ("none",) * 5


def test_lights_are_the_renderers_own(tmp_path):
    # what check compares is what a run stores: the Monte Carlo's and the fast renderer's
    # expected images of the sample, and the Monte Carlo's error and mask, bit for bit
    from workers.render import render_arrays

    plan = parse_sweep(sweep_file(tmp_path).read_text(), folder=tmp_path)
    sample = plan.sample(4)  # point 1, realisation 1: its own sea and photons
    scene = sample.scene
    transported = scene.model_copy(
        update={"transport": scene.transport.model_copy(update={"method": "monte_carlo"})}
    )
    stored = render_arrays(transported, seed=sample.seed)
    light = fidelity.transport_light(scene, seed=sample.seed)
    np.testing.assert_array_equal(light.image, stored["expected"][0])
    np.testing.assert_array_equal(light.stderr, stored["expected_stderr"][0])
    np.testing.assert_array_equal(light.mask, stored["target_mask"][0].astype(bool))
    twin = render_arrays(transported.without_target(), seed=sample.seed)
    np.testing.assert_array_equal(light.twin, twin["expected"][0])
    fast = fidelity.fast_light(scene, seed=sample.seed)
    np.testing.assert_array_equal(
        fast.image, render_arrays(scene, seed=sample.seed)["expected"][0]
    )
    free = render_arrays(scene.without_target(), seed=sample.seed)["expected"][0]
    np.testing.assert_array_equal(fast.twin, free)
