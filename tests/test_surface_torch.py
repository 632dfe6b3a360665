"""The sea on the PyTorch backend (CPU) against numpy: the same sea, to float32 rounding."""

import importlib.util
import sys
import types

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from workers.backend import get_backend  # noqa: E402
from workers.scene import Scene  # noqa: E402
from workers.seeds import SampleSeed  # noqa: E402
from workers.sensor import scene_setup  # noqa: E402
from workers.surface import Cascade  # noqa: E402

TORCH = get_backend("torch")

SCENES = {
    "three cascades": {},
    "conditioned": {
        "surface": {
            "conditioning": {"points": [[1.0, 2.0, 0.3], [5.0, 3.0, -0.2, 0.5]], "noise": 0.01}
        }
    },
    "max elevation": {"surface": {"max_elevation": 0.7, "grid_size": 64}},
    "odd grid": {"surface": {"spectrum": "phillips", "grid_size": 96, "wind_speed": 9.0}},
}
TIMES = (0.0, 0.25, 1.0)


# -- a stand-in for workers.kernels_torch until it lands (the numba kernels' semantics) --


def _unsigned_shift(word, bits):
    """Logical right shift of int64 words read as uint64."""
    return (word >> bits) & ((1 << (64 - bits)) - 1)


def _signed(value):
    return int(value) - (1 << 64) if int(value) >= 1 << 63 else int(value)


def _mix(z):
    z = z ^ _unsigned_shift(z, 30)
    z = z * _signed(0xBF58476D1CE4E5B9)
    z = z ^ _unsigned_shift(z, 27)
    z = z * _signed(0x94D049BB133111EB)
    return z ^ _unsigned_shift(z, 31)


def _bilinear_sum(grids, sizes, inverses, x, y, out):
    for g, (grid, n, inverse) in enumerate(zip(grids, sizes, inverses, strict=True)):
        tx, ty = x.float() * float(inverse), y.float() * float(inverse)
        column, row = torch.floor(tx), torch.floor(ty)
        tx, ty = tx - column, ty - row
        low = torch.remainder(row.long(), n) * (n + 1) + torch.remainder(column.long(), n)
        high = low + n + 1
        for k in range(out.shape[0]):
            field = grid[k]
            lower = (field[low + 1] - field[low]) * tx + field[low]
            upper = (field[high + 1] - field[high]) * tx + field[high]
            value = (upper - lower) * ty + lower
            out[k] = value if g == 0 else out[k] + value


def _cell_uniforms(x, y, inverse, key, frame, first, second):
    seed = _mix(torch.tensor(key ^ _signed((frame * 0x632BE59BD9B4E019) % (1 << 64))))
    column = torch.floor(x.float() * float(inverse)).long()
    row = torch.floor(y.float() * float(inverse)).long()
    word = _mix((column * _signed(0x9E3779B97F4A7C15)) ^ _mix(row + seed))
    first[:] = (_unsigned_shift(word, 40).float() + 0.5) * 2.0**-24
    second[:] = ((word & 0xFFFFFF).float() + 0.5) * 2.0**-24


@pytest.fixture(autouse=True)
def torch_kernels(monkeypatch):
    """The torch kernels: workers.kernels_torch where it exists, else this stand-in."""
    if importlib.util.find_spec("workers.kernels_torch") is None:
        standin = types.ModuleType("workers.kernels_torch")
        standin.bilinear_sum, standin.cell_uniforms = _bilinear_sum, _cell_uniforms
        monkeypatch.setitem(sys.modules, "workers.kernels_torch", standin)


# -- the tests --


def surfaces(name, root=5):
    setup = scene_setup(Scene.model_validate(SCENES[name]))
    seed = SampleSeed(root=root)
    return setup.surface(seed, TIMES), setup.surface(seed, TIMES, backend=TORCH)


def points(count=4000):
    """Random points over the finest patch, its neighbours and far off (wraps)."""
    x, y = np.random.default_rng(1).uniform(-60.0, 90.0, (2, count))
    return x, y


@pytest.mark.parametrize("name", list(SCENES), ids=list(SCENES))
def test_torch_sea_equals_numpy_sea_at_random_points(name):
    host, device = surfaces(name)
    x, y = points()
    tx, ty = torch.from_numpy(x), torch.from_numpy(y)
    for frame in range(len(TIMES)):
        eta = device.elevation_at(tx, ty, frame)
        slopes = device.slopes_at(tx, ty, frame)
        assert all(isinstance(v, torch.Tensor) for v in (eta, *slopes))
        assert all(v.dtype == torch.float32 and v.shape == (x.size,) for v in (eta, *slopes))
        expected = (host.elevation_at(x, y, frame), *host.slopes_at(x, y, frame))
        for got, want in zip((eta, *slopes), expected, strict=True):
            scale = np.abs(want).max()
            np.testing.assert_allclose(got.numpy(), want, rtol=0, atol=1e-6 * scale)
        sampled = device.sample(tx, ty, frame)
        for got, want in zip(sampled, (eta, *slopes), strict=True):
            assert torch.equal(got, want)


def test_the_subgrid_slopes_are_the_same_cells_on_torch():
    host, device = surfaces("three cascades")
    x, y = points()
    got = device.subgrid.at(torch.from_numpy(x), torch.from_numpy(y), 2)
    want = host.subgrid.at(x, y, 2)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g.numpy(), w, rtol=0, atol=1e-6 * np.abs(w).max())


@pytest.mark.parametrize("name", ["three cascades", "max elevation"])
def test_stored_elevations_come_back_as_numpy_and_match(name):
    host, device = surfaces(name)
    for attribute in ("elevation", "centred_elevation"):
        got, want = getattr(device, attribute), getattr(host, attribute)
        assert isinstance(got, np.ndarray) and got.dtype == np.float32
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * np.abs(want).max())
    if name == "max elevation":
        assert np.abs(device.centred_elevation).max() == pytest.approx(0.7, rel=1e-6)


def test_the_conditioned_torch_sea_honours_the_data():
    _, device = surfaces("conditioned")
    for x, y, elevation, frame in ((1.0, 2.0, 0.3, 0), (5.0, 3.0, -0.2, 1)):
        eta = device.elevation_at(torch.tensor([x]), torch.tensor([y]), frame)
        assert float(eta[0]) == pytest.approx(elevation, abs=0.05)  # noise 0.01 m


def test_torch_surface_twice_gives_the_same_bytes():
    first, second = surfaces("three cascades")[1], surfaces("three cascades")[1]
    x, y = (torch.from_numpy(v) for v in points())
    for frame in (0, 2):
        for a, b in zip(first.sample(x, y, frame), second.sample(x, y, frame), strict=True):
            assert a.numpy().tobytes() == b.numpy().tobytes()
    assert first.centred_elevation.tobytes() == second.centred_elevation.tobytes()


def test_a_torch_cascade_from_host_arrays_keeps_them_on_the_device():
    fields = np.random.default_rng(0).normal(size=(3, 1, 8, 8))
    cascade = Cascade(*fields, spacing=0.5, grid_size=8, backend=TORCH)
    assert isinstance(cascade.elevation, torch.Tensor) and cascade.elevation.dtype == torch.float32
    nodes = torch.arange(8, dtype=torch.float64) * 0.5
    eta = cascade.elevation_at(nodes, torch.zeros(8, dtype=torch.float64))
    np.testing.assert_array_equal(eta.numpy(), fields[0, 0, 0].astype(np.float32))
    with pytest.raises(ValueError, match="slope_y must have shape"):
        Cascade(*fields[:2], fields[2, :, :4], spacing=0.5, grid_size=8, backend=TORCH)
