"""The two-level spread on either backend (issue #28): numpy arrays or torch tensors.

The filters are built once in numpy (`Spread.build`) and moved to a backend once
(`Spread.on`); a spread of torch tensors runs on torch (its FFTs, the torch column sums)
and returns tensors on the fields' device, equal to the numpy spread within 1e-6 of the
field's peak (float32 FFTs of two libraries), and the same bytes when run twice.
"""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from workers.backends.backend import get_backend
from workers.fast.spread import Levels, Spread
from workers.optics.water import WaterOptics
from workers.setup.geometry import PlaneGrid

torch = pytest.importorskip("torch")

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])

ROWS = {
    # (fine rows in, fine rows out) and the coarse rows as offsets from the fine block's
    "all": None,
    "wide": ((slice(4, 44), (0, 12)), (slice(2, 40), (-60, 72))),
    "narrow": ((slice(12, 20), (3, 5)), (slice(16, 24), (4, 6))),
}


@pytest.fixture(params=DEVICES)
def backend(request):
    """The torch backend on each device here."""
    return get_backend("torch", request.param)


@pytest.fixture
def calls(backend, monkeypatch):
    """The (first, start) rows of each of the torch backend's column sums."""
    kernels, calls = backend.kernels, []
    convolve = kernels.column_convolution

    def counted(kernel, rows, first, start, out):
        calls.append((first, start))
        convolve(kernel, rows, first, start, out)

    monkeypatch.setattr(kernels, "column_convolution", counted)
    return calls


@pytest.fixture
def spread():
    """A coastal spread of 9 m onto a 48 × 48 plane, the 95 % truncation, a gate's gain."""
    water = WaterOptics.from_preset("coastal")
    grid = PlaneGrid(
        depth=9.0,
        origin=(0.0, 0.0),
        axis_u=(1.0, 0.0),
        axis_v=(0.0, -1.0),
        spacing_u=0.05,
        spacing_v=0.06,
        shape=(48, 48),
    )
    levels = Levels.around(grid, factor=4, margin=20.0)
    return Spread.build(
        water=water, levels=levels, distance=9.0, truncation=0.95, gain=0.3, blur=(0.02, 0.03)
    )


def _sources(spread, rows_in, *, tail):
    """Random light on the fine `rows_in` (and, with `tail`, on the coarse margin), seeded."""
    levels = spread.levels
    rng = np.random.default_rng(28)
    fine = np.zeros(levels.fine.shape, np.float32)
    fine[rows_in[0]] = rng.random(levels.fine.shape, dtype=np.float32)[rows_in[0]]
    source = levels.downsample(fine, rows_in[0])
    if tail:
        # the beam's tail: light on the coarse margin too, so every coarse row is lit
        outside = rng.random(levels.coarse.shape, dtype=np.float32) * np.float32(0.2)
        outside[levels.block] = 0.0
        source += outside
        rows_in = (rows_in[0], slice(None))
    return fine, source, rows_in


def _rows(spread, name):
    """The `ROWS` case as (rows_in, rows_out) pairs of fine and coarse slices."""
    if ROWS[name] is None:
        return (slice(None), slice(None)), (slice(None), slice(None))
    start = spread.levels.block[0].start
    return tuple((fine, slice(start + a, start + b)) for fine, (a, b) in ROWS[name])


def _on_torch(backend, *arrays):
    """Host arrays as tensors on the backend's device."""
    return tuple(torch.from_numpy(a).to(backend.device) for a in arrays)


def test_the_filters_move_to_a_backend_once(backend, spread):
    moved = spread.on(backend)
    assert moved is spread.on(backend) and spread.on(get_backend()) is spread
    assert moved.levels is spread.levels.on(backend) and moved.backend == backend
    for name in ("near", "far", "whole", "columns"):
        tensor, array = getattr(moved, name), getattr(spread, name)
        assert isinstance(tensor, torch.Tensor) and tensor.device.type == backend.device
        assert_array_equal(tensor.cpu().numpy(), array)
    for (lower, weight), (host_lower, host_weight) in zip(
        moved.levels.lift, spread.levels.lift, strict=True
    ):
        assert isinstance(lower, torch.Tensor) and lower.device.type == backend.device
        assert_array_equal(lower.cpu().numpy(), host_lower)
        assert_array_equal(weight.cpu().numpy(), host_weight)


@pytest.mark.parametrize("tail", [False, True], ids=["plane", "tail"])
@pytest.mark.parametrize("far_out", [False, True], ids=["inside", "far_out"])
@pytest.mark.parametrize("rows", list(ROWS), ids=list(ROWS))
def test_torch_spreads_as_numpy_does(backend, calls, spread, rows, far_out, tail):
    rows_in, rows_out = _rows(spread, rows)
    fine, source, rows_in = _sources(spread, rows_in, tail=tail)
    keywords = dict(rows_in=rows_in, rows_out=rows_out, far_out=far_out)
    expected = spread.filtered(fine, source, **keywords)
    runs = [spread.filtered(*_on_torch(backend, fine, source), **keywords) for _ in range(2)]
    # the direct column sums ran on torch where few rows are lit and read (the narrow
    # rows, with or without the tail) and nothing goes outside; the column FFTs elsewhere
    assert len(calls) == (2 if rows == "narrow" and not far_out else 0)
    levels = spread.levels
    field = expected[0] + levels.upsample(expected[1], rows=rows_out[0])
    peak = np.abs(field).max()
    assert peak > 0
    for got, again, want in zip(*runs, expected, strict=True):
        if want is None:
            assert got is None and again is None
            continue
        assert isinstance(got, torch.Tensor) and got.device.type == backend.device
        assert got.dtype == torch.float32 and tuple(got.shape) == want.shape
        assert torch.equal(got, again), "two runs on torch differ"
        assert_allclose(got.cpu().numpy(), want, rtol=0, atol=1e-6 * peak)
    # brought to the fine grid on torch, as the render does
    whole = runs[0][0] + levels.upsample(runs[0][1], rows=rows_out[0])
    assert isinstance(whole, torch.Tensor)
    assert_allclose(whole.cpu().numpy(), field, rtol=0, atol=1e-6 * peak)


@pytest.mark.parametrize(
    ("lit", "read"),
    [((12, 20), (7, 7)), ((7, 7), (16, 24)), ((7, 7), (7, 7))],
    ids=["read-none", "lit-none", "neither"],
)
def test_a_spread_from_or_to_no_rows_is_zeros_on_torch(backend, spread, lit, read):
    # a target whose light lies on the coarse margin alone reads no fine rows: torch's
    # FFTs refuse an empty batch of rows where numpy's return an empty array
    start = spread.levels.block[0].start
    rows_in = (slice(*lit), slice(start + lit[0] // 4, start + -(-lit[1] // 4)))
    rows_out = (slice(*read), slice(start + read[0] // 4, start + -(-read[1] // 4)))
    fine, source, rows_in = _sources(spread, rows_in, tail=False)
    keywords = dict(rows_in=rows_in, rows_out=rows_out)
    want = spread.filtered(fine, source, **keywords)
    got = spread.filtered(*_on_torch(backend, fine, source), **keywords)
    for tensor, array in zip(got[:2], want[:2], strict=True):
        assert tuple(tensor.shape) == array.shape
        assert_allclose(tensor.cpu().numpy(), array, rtol=0, atol=1e-6 * max(fine.max(), 1.0))


def test_a_whole_spread_of_tensors_matches_numpy(backend, spread):
    fine, source, _ = _sources(spread, (slice(None), slice(None)), tail=True)
    outside = source - spread.levels.downsample(fine)
    want = spread(fine, outside)
    got = spread(*_on_torch(backend, fine, outside))
    peak = np.abs(want[0]).max()
    for tensor, array in zip(got, want, strict=True):
        assert isinstance(tensor, torch.Tensor) and tensor.device.type == backend.device
        assert_allclose(tensor.cpu().numpy(), array, rtol=0, atol=1e-6 * peak)


@pytest.mark.parametrize("rows", [slice(5, 23), slice(0, 48), slice(7, 7)])
def test_levels_resample_tensors_as_numpy(backend, spread, rows):
    levels = spread.levels
    rng = np.random.default_rng(5)
    fine = np.zeros(levels.fine.shape, np.float32)
    fine[rows] = rng.random(levels.fine.shape, dtype=np.float32)[rows]
    coarse = rng.random(levels.coarse.shape, dtype=np.float32)
    (down,) = _on_torch(backend, fine)
    down = levels.downsample(down, rows)
    up = levels.upsample(*_on_torch(backend, coarse), rows=rows)
    for tensor, array in (
        (down, levels.downsample(fine, rows)),
        (up, levels.upsample(coarse, rows)),
    ):
        assert isinstance(tensor, torch.Tensor) and tensor.dtype == torch.float32
        assert_allclose(tensor.cpu().numpy(), array, rtol=0, atol=1e-7)
