"""The sea on the PyTorch backend (CPU, and CUDA where there is one) against numpy: the same
sea, to float32 rounding."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from workers.backends.backend import get_backend  # noqa: E402
from workers.sea.surface import Cascade  # noqa: E402
from workers.settings.scene import Scene  # noqa: E402
from workers.settings.seeds import SampleSeed  # noqa: E402
from workers.setup.builder import scene_setup  # noqa: E402

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
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device here")


@pytest.fixture(params=["cpu", pytest.param("cuda", marks=CUDA)])
def device(request):
    """The torch backend on each device there is."""
    return get_backend("torch", request.param)


def host(values):
    return values.cpu().numpy()


def surfaces(name, backend, root=5):
    setup = scene_setup(Scene.model_validate(SCENES[name]))
    seed = SampleSeed(root=root)
    return setup.surface(seed, TIMES), setup.surface(seed, TIMES, backend=backend)


def points(backend, count=4000):
    """Random points over the finest patch, its neighbours and far off (wraps): host, device."""
    x, y = np.random.default_rng(1).uniform(-60.0, 90.0, (2, count))
    return (x, y), (backend.asarray(x), backend.asarray(y))


@pytest.mark.parametrize("name", list(SCENES), ids=list(SCENES))
def test_torch_sea_equals_numpy_sea_at_random_points(name, device):
    numpy_sea, torch_sea = surfaces(name, device)
    (x, y), (tx, ty) = points(device)
    for frame in range(len(TIMES)):
        eta = torch_sea.elevation_at(tx, ty, frame)
        slopes = torch_sea.slopes_at(tx, ty, frame)
        for value in (eta, *slopes):
            assert isinstance(value, torch.Tensor) and value.device == tx.device
            assert value.dtype == torch.float32 and value.shape == (x.size,)
        expected = (numpy_sea.elevation_at(x, y, frame), *numpy_sea.slopes_at(x, y, frame))
        for got, want in zip((eta, *slopes), expected, strict=True):
            scale = np.abs(want).max()
            np.testing.assert_allclose(host(got), want, rtol=0, atol=1e-6 * scale)
        sampled = torch_sea.sample(tx, ty, frame)
        for got, want in zip(sampled, (eta, *slopes), strict=True):
            assert torch.equal(got, want)


def test_the_subgrid_slopes_are_the_same_cells_on_torch(device):
    numpy_sea, torch_sea = surfaces("three cascades", device)
    (x, y), (tx, ty) = points(device)
    got = torch_sea.subgrid.at(tx, ty, 2)
    want = numpy_sea.subgrid.at(x, y, 2)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(host(g), w, rtol=0, atol=1e-6 * np.abs(w).max())


@pytest.mark.parametrize("name", ["three cascades", "max elevation"])
def test_stored_elevations_come_back_as_numpy_and_match(name, device):
    numpy_sea, torch_sea = surfaces(name, device)
    for attribute in ("elevation", "centred_elevation"):
        got, want = getattr(torch_sea, attribute), getattr(numpy_sea, attribute)
        assert isinstance(got, np.ndarray) and got.dtype == np.float32
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * np.abs(want).max())
    if name == "max elevation":
        assert np.abs(torch_sea.centred_elevation).max() == pytest.approx(0.7, rel=1e-6)


def test_the_conditioned_torch_sea_honours_the_data(device):
    _, torch_sea = surfaces("conditioned", device)
    for x, y, elevation, frame in ((1.0, 2.0, 0.3, 0), (5.0, 3.0, -0.2, 1)):
        eta = torch_sea.elevation_at(device.asarray([x]), device.asarray([y]), frame)
        assert float(eta[0]) == pytest.approx(elevation, abs=0.05)  # noise 0.01 m


def test_torch_surface_twice_gives_the_same_bytes(device):
    first, second = surfaces("three cascades", device)[1], surfaces("three cascades", device)[1]
    _, (x, y) = points(device)
    for frame in (0, 2):
        for a, b in zip(first.sample(x, y, frame), second.sample(x, y, frame), strict=True):
            assert host(a).tobytes() == host(b).tobytes()
    assert first.centred_elevation.tobytes() == second.centred_elevation.tobytes()


def test_a_torch_cascade_from_host_arrays_keeps_them_on_the_device(device):
    fields = np.random.default_rng(0).normal(size=(3, 1, 8, 8))
    cascade = Cascade(*fields, spacing=0.5, grid_size=8, backend=device)
    assert isinstance(cascade.elevation, torch.Tensor) and cascade.elevation.dtype == torch.float32
    nodes = device.asarray(np.arange(8) * 0.5)
    eta = cascade.elevation_at(nodes, device.asarray(np.zeros(8)))
    np.testing.assert_array_equal(host(eta), fields[0, 0, 0].astype(np.float32))
    with pytest.raises(ValueError, match="slope_y must have shape"):
        Cascade(*fields[:2], fields[2, :, :4], spacing=0.5, grid_size=8, backend=device)
