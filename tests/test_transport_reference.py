"""The fast renderer held to photon transport: the stored Monte Carlo reference images.

`tests/data/transport_reference.npz` holds Monte Carlo images (`workers.montecarlo.renderer`) of
the scenes of `benchmarks.transport_reference` (32 px, 34 m, ML(DC) gates, a 0.3 m sphere
at 5 m in clear, coastal and turbid water; the paper's Example 4; coastal water under a
5 m/s sea), each with its standard error and its no-target twin. Rewrite them with
``python -m benchmarks.transport_reference`` after a change of the transport physics.

Where the fast (small-angle) renderer is not yet true to transport, the check is marked
``xfail(strict=True)``: the gap is measured, not hidden, and a fix turns the mark into a
failure until it is removed (turbid water's backgrounds were, until issue #40 item 2).
"""

import json
from pathlib import Path

import numpy as np
import pytest

from workers.render import render_arrays
from workers.settings.scene import Scene

REFERENCE = Path(__file__).parent / "data" / "transport_reference.npz"


@pytest.fixture(scope="module")
def reference():
    with np.load(REFERENCE) as data:
        return dict(data)


def stored(reference, name):
    """(expected, stderr, mask, scene) of reference `name`, one frame."""
    scene = Scene.model_validate(json.loads(str(reference[f"{name}/scene"])))
    return (
        reference[f"{name}/expected"],
        reference[f"{name}/stderr"],
        reference[f"{name}/mask"].astype(bool),
        scene,
    )


def small_angle(scene):
    """The same scene by the fast renderer: its noise-free images, one frame."""
    fast = scene.model_copy(
        update={"transport": scene.transport.model_copy(update={"method": "small_angle"})}
    )
    return render_arrays(fast, seed=2026)["expected"][0]


def gate_means(image, stderr):
    """Each gate's image mean and its standard error."""
    return image.mean(axis=(1, 2)), np.sqrt((stderr**2).sum(axis=(1, 2))) / image[0].size


def contrast(reference, name):
    """Per gate, (target − twin)/twin over the target's mask, and a bound on its error."""
    image, error, mask, _ = stored(reference, name)
    twin, twin_error, _, _ = stored(reference, f"{name}-none")
    t, b = image[:, mask].mean(axis=1), twin[:, mask].mean(axis=1)
    dt = np.sqrt((error[:, mask] ** 2).sum(axis=1)) / mask.sum()
    db = np.sqrt((twin_error[:, mask] ** 2).sum(axis=1)) / mask.sum()
    return t / b - 1, (dt + db * t / b) / b


def fast_contrast(reference, name):
    _, _, mask, scene = stored(reference, name)
    _, _, _, twin = stored(reference, f"{name}-none")
    image, other = small_angle(scene), small_angle(twin)
    return image[:, mask].mean(axis=1) / other[:, mask].mean(axis=1) - 1


def rerun_scores(reference, name):
    """Reference `name` rendered again by transport (10⁶ other photons): each gate's mean
    over the stored one, and their difference in standard errors."""
    image, error, _, scene = stored(reference, name)
    again = scene.model_copy(
        update={"transport": scene.transport.model_copy(update={"photons": 1_000_000})}
    )
    out = render_arrays(again, seed=7)
    mean, se = gate_means(image, error)
    new, new_se = gate_means(out["expected"][0], out["expected_stderr"][0])
    return new / mean, (new - mean) / np.hypot(se, new_se)


def test_monte_carlo_reproduces_its_reference(reference):
    # the Monte Carlo renderer today gives the stored images (other photons, same law)
    _, z = rerun_scores(reference, "clear-none")
    assert np.all(np.abs(z) < 4), z


def test_fast_renderer_holds_to_transport_in_clear_water(reference):
    # Issue #23 item 4: every gate's water background within 5 % in clear water at nadir
    image, error, _, scene = stored(reference, "clear-none")
    mean, se = gate_means(image, error)
    assert np.all(se < 0.01 * mean)
    fast = small_angle(scene).mean(axis=(1, 2))
    assert np.all(np.abs(fast / mean - 1) < 0.05 + 3 * se / mean), fast / mean


def test_monte_carlo_shadow_agrees_with_the_independent_transport_of_issue_23(reference):
    # Issue #23: an independent photon Monte Carlo gives the paper's Example 4 (its water,
    # sphere at 3 m, gate 4-9 m) a shadow contrast of -0.75 +- 0.02. Its mask is not
    # stated: here the whole mask reads -0.71 and its interior (one pixel in) -0.79, so
    # both are held to it within its error, three of ours and 0.03 for the mask's rim.
    value, error = contrast(reference, "example4")
    assert abs(value[0] - -0.75) < 0.02 + 3 * error[0] + 0.03, (value, error)
    image, _, mask, _ = stored(reference, "example4")
    twin = stored(reference, "example4-none")[0]
    inner = mask & np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1)
    inner &= np.roll(mask, -1, 1)
    interior = image[0][inner].mean() / twin[0][inner].mean() - 1
    assert abs(interior - -0.75) < 0.02 + 0.03, interior


def test_fast_renderer_holds_to_transport_on_the_sphere_in_clear_water(reference):
    # the sphere inside gate 1 (3.7-9.8 m) in clear water: both renderers give the same
    # contrast over its mask (two independent computations of the target's light)
    value, error = contrast(reference, "clear")
    fast = fast_contrast(reference, "clear")
    assert error[0] < 0.02 * value[0]
    assert abs(fast[0] / value[0] - 1) < 0.05 + 3 * error[0] / value[0], (fast[0], value[0])


@pytest.mark.parametrize("water", ["clear", "coastal", "coastal-waves"])
def test_fast_renderer_gate_backgrounds_within_issue_24_targets(reference, water):
    # Issue #24 item 2: every ML(DC) gate's water background within 5 % of transport in
    # coastal water, over a flat sea and a 5 m/s one (with the paper's phase function in
    # the fast renderer: 0.51-0.83; the Monte Carlo's Fournier-Forand, fitted to the same
    # b_b/b, is now both renderers')
    image, error, _, scene = stored(reference, f"{water}-none")
    mean, se = gate_means(image, error)
    fast = small_angle(scene).mean(axis=(1, 2))
    assert np.all(np.abs(fast / mean - 1) < 0.05 + 3 * se / mean), fast / mean


def test_fast_renderer_turbid_backgrounds_within_issue_24_target(reference):
    # Issue #40 item 2: in turbid harbour water the small-angle spread alone gave 0.80,
    # 0.78, 0.71 of transport in gates 1-3 (b z = 7-20: the light it counts as lost to
    # backscatter returns, late); with the time-resolved gains (`workers.calibration.timegains`)
    # 0.97, 1.03, 0.99, 0.92 in gates 1-4
    image, error, _, scene = stored(reference, "turbid-none")
    mean, se = gate_means(image, error)
    fast = small_angle(scene).mean(axis=(1, 2))
    ratio = (fast / mean)[:4]  # gates 5-6: < 1e-5 of a white plane, 9-16 % errors
    assert np.all(np.abs(ratio - 1) < 0.10 + 3 * (se / mean)[:4]), ratio


def test_fast_renderer_example4_background_within_issue_40_target(reference):
    # Issue #40 item 2: the paper's Example 4 water (a = 0.1, b = 0.4 /m, Fournier-Forand),
    # gate 4-9 m: background within 5 % of transport's (the small-angle spread alone:
    # 0.944 +- 0.003; with the time-resolved gains 0.990)
    image, error, _, scene = stored(reference, "example4-none")
    mean, se = gate_means(image, error)
    fast = small_angle(scene).mean(axis=(1, 2))
    assert abs(fast[0] / mean[0] - 1) < 0.05 + 3 * se[0] / mean[0], fast / mean


@pytest.mark.parametrize(("name", "gate"), [("example4", 0), ("coastal", 2), ("coastal", 4)])
def test_fast_renderer_shadows_within_issue_24_targets(reference, name, gate):
    # Issue #24 item 3: shadow contrast within the reference's error + 0.05 (Example 4,
    # its water, sphere at 3 m: -0.71 by transport, -0.36 by the old fast renderer;
    # coastal gate 5, 10.7-13.7 m: -0.77 against -0.38; gate 3: -0.75 against -0.58)
    value, error = contrast(reference, name)
    fast = fast_contrast(reference, name)
    assert abs(fast[gate] - value[gate]) < error[gate] + 0.05, (fast[gate], value[gate])


def test_fast_renderer_gate_edge_within_issue_24_target(reference):
    # Issue #24 item 4: clear water, gate 2 from 4.88 m cuts the sphere (4.7-5.3 m): its
    # contrast within 10 % of transport's (the old fast renderer, each cell in a gate or
    # not by its centre's depth: 1.7 times). Coastal's reference holds this contrast
    # only to +-0.5 (its forward-scattered target light is the estimator's hardest case).
    value, error = contrast(reference, "clear")
    fast = fast_contrast(reference, "clear")
    assert abs(fast[1] / value[1] - 1) < 0.10 + 3 * error[1] / abs(value[1]), (fast, value)
