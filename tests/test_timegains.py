"""Time-resolved gate gains (issue #40 item 2): where they apply, how a gate weights its slabs,
and that they are a fixed quadrature (same bytes, every run)."""

import numpy as np
import pytest

from workers.calibration import timegains
from workers.calibration.timegains import gate_time_gains
from workers.render import render_arrays
from workers.settings.scene import Scene
from workers.setup import builder


def scene(water, gates, method="small_angle", **water_fields):
    return Scene.model_validate(
        {
            "water": {"preset": water, **water_fields},
            "receiver": {"pixels": 16, "field_of_view_deg": 6.7, "gates": gates},
            "platform": {"altitude": 34.0},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
            "target": {"shape": "none"},
            "surface": {"spectrum": "flat"},
            "transport": {"method": method},
        }
    )


@pytest.mark.parametrize(
    ("water", "fields", "gates", "method", "applies"),
    [
        ("clear_ocean", {}, "mldc", "small_angle", False),
        ("coastal", {}, "mldc", "small_angle", False),  # b_b z = 0.0028 x 15.2 = 0.043
        ("turbid_harbour", {}, "mldc", "small_angle", True),  # 0.035 x 15.2 = 0.53
        ("turbid_harbour", {}, "mldc", "monte_carlo", False),
        ("turbid_harbour", {}, [[1.0, 2.0]], "small_angle", False),  # 0.035 x 2 = 0.069
        # the paper's Example 4 water, gate 4-9 m: 0.0154 x 9 = 0.139
        (
            None,
            {"absorption": 0.1, "scattering": 0.4, "backscatter": 0.0154},
            [[4, 9]],
            "small_angle",
            True,
        ),
    ],
)
def test_time_resolved_where_backscatter_optical_depth_reaches_a_tenth(
    water, fields, gates, method, applies
):
    assert builder.time_resolved(scene(water, gates, method, **fields)) is applies


def test_paper_takes_transport_gains_in_any_water_that_backscatters():
    # `paper` (PhaseFunction.transport_gains): its wide-angle tail, not the light's time,
    # sets Wells' deficit, 0.72-0.87 of transport in coastal water (b_b z = 0.043)
    assert builder.time_resolved(scene("coastal", "mldc", phase_function="paper"))
    no_return = scene("coastal", "mldc", phase_function="paper", backscatter=0.0)
    assert not builder.time_resolved(no_return)  # Examples 1-2: nothing to gain


def test_time_resolved_needs_a_phase_function_transport_can_sample():
    # Wells' own is defined at small angles only: no transport of that water to gain by
    turbid = scene("turbid_harbour", "mldc", phase_function="wells")
    assert not builder.time_resolved(turbid)


def test_the_gains_are_the_waters_whatever_the_monte_carlo_would_sample():
    # transport.phase_function is the Monte Carlo's choice alone: the fast renderer's
    # gains are transport's of its own water, so the images do not depend on it
    water = scene("turbid_harbour", [[1.0, 2.0], [2.0, 3.0]], phase_function="paper")
    other = water.model_copy(
        update={"transport": water.transport.model_copy(update={"phase_function": "paper"})}
    )
    assert builder.time_resolved(water)
    assert builder.slab_setups(water) == builder.slab_setups(other)


def test_gate_gain_weights_slabs_by_their_single_scattering_return():
    # gate 2.5-4 m over slabs 2-3 m (gain 1.2) and 3-4 m (gain 1.5): weights
    # (e^(-2K 2.5) - e^(-2K 3)) and (e^(-2K 3) - e^(-2K 4)) (closed form of ∫ e^(-2Kz) dz)
    k = 0.4
    gains = np.array([1.0, 1.0, 1.2, 1.5, 9.0])
    w1 = np.exp(-2 * k * 2.5) - np.exp(-2 * k * 3.0)
    w2 = np.exp(-2 * k * 3.0) - np.exp(-2 * k * 4.0)
    (gain,) = gate_time_gains(gains=gains, gates=[(2.5, 4.0)], diffuse_attenuation=k)
    assert gain == pytest.approx((1.2 * w1 + 1.5 * w2) / (w1 + w2), rel=1e-12)
    # a uniform gain is that gain, whatever the gate
    flat = gate_time_gains(
        gains=np.full(5, 1.3), gates=[(0.2, 4.9), (3, 3.5)], diffuse_attenuation=k
    )
    assert flat == pytest.approx((1.3, 1.3), rel=1e-12)


def test_time_resolved_render_is_the_same_bytes_each_time():
    # shallow gates keep the Monte Carlo tabulation short (its photons stop at the last gate)
    turbid = scene("turbid_harbour", [[1.0, 2.0], [2.0, 3.0]])
    assert builder.time_resolved(turbid)
    first = render_arrays(turbid, seed=5)["expected"]
    builder.scene_setup.cache_clear()
    builder._slab_setups.cache_clear()
    timegains.slab_gains.cache_clear()
    timegains.calibrated.cache_clear()
    again = render_arrays(turbid, seed=5)["expected"]
    assert first.tobytes() == again.tobytes()
