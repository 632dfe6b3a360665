"""The torch operators of `render_batch` and the host's traffic they make (issue #39).

Counted with `benchmarks.torch_ops.count_ops` (a `TorchDispatchMode`) on the CPU, where the
operators and the transfers are those a GPU would launch and make.
"""

import numpy as np
import pytest

from workers.setup.gates import gate_gains

torch = pytest.importorskip("torch")

from benchmarks.gpu import scene  # noqa: E402
from benchmarks.torch_ops import READS, batch_ops, count_ops  # noqa: E402

SCENE = scene(32)
"""The six-gate benchmark scene (a 0.3 m sphere at 5 m, a wavy sea) at 32² pixels."""

FROM_HOST = 10
"""Tensors from host data a sample of `SCENE` makes: its sea's modes (two a cascade, drawn
on the host: `workers.sea.surface.Modes.surface`) and the target's maps for the sea's
height over it (`workers.fast.targetgating.TargetGating.light`), arrays, not scalars."""

LINEAR = 1.01
"""Allowance on 16 × the operators of a batch of one for a batch of 16: the samples take a
few branches apart (the target's maps, the rows light reaches), ±0.2 % of their operators
measured (9 150 a sample at batch 16 against 9 154 for the first alone)."""


@pytest.fixture(scope="module")
def counted():
    """`batch_ops` of `SCENE` at batches 1, 2 and 16, by batch."""
    return {batch: batch_ops(SCENE, batch) for batch in (1, 2, 16)}


@pytest.mark.parametrize("batch", [1, 2])
def test_a_sample_copies_no_python_scalar_to_the_device(counted, batch):
    counts, _, sites = counted[batch]
    assert counts["scalars"] == 0, +sites
    assert counts["from_host"] <= FROM_HOST * batch, +sites
    assert counts["ops"] > 1000 * batch  # the render was counted


@pytest.mark.parametrize("batch", [1, 2])
def test_the_gate_gains_and_the_sea_over_the_target_are_not_read_back(counted, batch):
    sites = counted[batch][2]
    reads = {site: count for (kind, site), count in sites.items() if count and kind in READS}
    # the gains are computed where the rays are: nothing goes to the host and back
    assert not any("gate" in site for site in reads), reads
    # the sea's height over the target: one value a sample (its gated maps are the host's)
    assert reads["workers.fast.stages:_target_frame"] == batch, reads


def test_a_batch_dispatches_no_more_than_its_samples_alone(counted):
    one, sixteen = counted[1][0]["ops"], counted[16][0]["ops"]
    assert sixteen <= 16 * one * LINEAR, (one, sixteen)


@pytest.mark.xfail(
    strict=True,
    reason="a batch renders its samples one after another: its operators grow with it "
    "until the render has a sample axis (issue #39, item 1)",
)
def test_a_batch_of_16_dispatches_the_operators_of_one(counted):
    one, sixteen = counted[1][0]["ops"], counted[16][0]["ops"]
    assert sixteen <= 1.05 * one, (one, sixteen)


K, N, SECANT = 0.2, 1.34, 1.2
SLABS = ((0.5, 2.0, 1.0), (3.0, 6.0, 4.0))
"""Two gates (top, bottom, plane's depth) [m]: the surface cuts the first, at the largest
excesses it closes before the light reaches the water."""


@pytest.mark.parametrize("k", [K, 0.0])
def test_gate_gains_on_the_device_are_the_hosts_and_read_nothing_back(k):
    # excess air paths from -1 to 12 m: slab rises δ = τ/(n sec) up to 7.5 m, past both gates
    excess = np.linspace(-1.0, 12.0, 2001, dtype=np.float32)
    terms = {"diffuse_attenuation": k, "refractive_index": N, "secant": SECANT, "slabs": SLABS}
    host = gate_gains(excess, **terms)
    rays = torch.from_numpy(excess)
    gate_gains(rays, **terms)  # the gates' constants moved, once
    with count_ops() as (counts, _, _):
        moved = gate_gains(rays, **terms)
    assert counts["from_host"] == counts["scalar_reads"] == counts["numpy"] == 0
    assert counts["tolist"] == 0 and counts["ops"] > 0
    # the slab's rise δ = τ/(n sec), taken in float32 as the gains take it (near a gate's
    # bottom, the cut slab's share is as thin as δ's rounding)
    rise = (excess * np.float32(1.0 / (N * SECANT))).astype(np.float64)
    for (top, bottom, depth), device, gain in zip(SLABS, moved, host, strict=True):
        assert isinstance(device, torch.Tensor) and device.dtype == torch.float32
        device = device.numpy()
        # float32 rounding of either (the exponentials of two libraries)
        np.testing.assert_allclose(device, gain, rtol=4 * np.finfo(np.float32).eps, atol=0)
        # the closed form, float64: sqrt of the cut slab's share of ∫ e^(-2K'z) dz
        upper, lower = np.maximum(top - rise, 0.0), np.maximum(bottom - rise, 0.0)
        attenuation = k * SECANT
        if attenuation:
            share = np.exp(-2 * attenuation * upper) - np.exp(-2 * attenuation * lower)
            share /= np.exp(-2 * attenuation * top) - np.exp(-2 * attenuation * bottom)
        else:
            share = (lower - upper) / (bottom - top)
        closed = np.where(rise > top, np.sqrt(share), np.exp(k / N * excess.astype(float)))
        closed *= np.exp(-k * depth * (SECANT - 1.0))
        np.testing.assert_allclose(device, closed, rtol=1e-6, atol=1e-7)
        assert np.any(rise > bottom) and device[rise > bottom].max() == 0.0  # closed: no light
