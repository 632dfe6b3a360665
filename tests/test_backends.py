"""The array backends (`workers.backends.backend`): what runs here, the errors, host ↔ device."""

import importlib.util

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from workers.backends.backend import get_backend

torch = pytest.importorskip("torch")

NO_CUDA = not torch.cuda.is_available()


@pytest.mark.parametrize(
    ("name", "device", "message"),
    [
        ("jax", "cpu", "backend: 'jax' is not one of numpy, torch"),
        ("numpy", "cuda", "device: the numpy backend runs on the cpu, not 'cuda'"),
        ("torch", "gpu", "device: 'gpu' is neither 'cpu' nor 'cuda'"),
        ("torch", "cuda:x", "device: 'cuda:x' is neither 'cpu' nor 'cuda'"),
        ("torch", "cuda:-1", "device: 'cuda:-1' is neither 'cpu' nor 'cuda'"),
        ("torch", None, "device: None is neither 'cpu' nor 'cuda'"),
    ],
    ids=["unknown-backend", "numpy-on-cuda", "unknown-device", "cuda-index", "negative", "none"],
)
def test_a_backend_that_cannot_be_named_is_refused_naming_the_field(name, device, message):
    with pytest.raises(ValueError, match="^" + message.replace("(", r"\(")):
        get_backend(name, device)


@pytest.mark.skipif(not NO_CUDA, reason="this machine has a CUDA device")
@pytest.mark.parametrize("device", ["cuda", "cuda:0", "cuda:3"])
def test_cuda_without_a_cuda_device_is_refused(device):
    with pytest.raises(ValueError, match=f"^device: '{device}' asked, but this machine has"):
        get_backend("torch", device)


def test_torch_missing_names_the_extra_that_installs_it(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "torch" else real(name, *a)
    )
    get_backend.cache_clear()
    try:
        with pytest.raises(
            ValueError, match=r"^backend: torch is not installed.*oceanlidar\[gpu\]"
        ):
            get_backend("torch", "cpu")
    finally:
        get_backend.cache_clear()


@pytest.mark.parametrize("values", [np.float32(2.5), np.arange(6, dtype=np.float32)])
def test_a_host_array_moves_with_its_shape_and_dtype_and_comes_back(values):
    backend = get_backend("torch", "cpu")
    moved = backend.asarray(values)
    assert tuple(moved.shape) == np.shape(values) and moved.dtype == torch.float32
    back = backend.to_numpy(moved)
    assert back.dtype == np.float32
    assert_array_equal(back, values)


def test_a_moved_array_is_a_copy_on_the_cpu_as_on_a_device():
    backend = get_backend("torch", "cpu")
    host = np.zeros(4, dtype=np.float32)
    moved = backend.asarray(host)
    moved += 1.0
    assert_array_equal(host, 0.0)  # the cached host geometry is never written through


def test_a_read_only_host_array_moves_without_a_warning(recwarn):
    host = np.arange(3, dtype=np.float32)
    host.flags.writeable = False  # as a cached geometry's arrays may be
    moved = get_backend("torch", "cpu").asarray(host)
    moved += 1.0
    assert_array_equal(host, [0.0, 1.0, 2.0])
    assert not [w for w in recwarn if "not writable" in str(w.message)]


def test_the_numpy_backend_keeps_host_arrays_and_has_no_generator():
    backend = get_backend()
    values = np.arange(3, dtype=np.float32)
    assert backend.asarray(values) is values
    assert backend.generator(1) is None
    assert backend.fft.__name__ == "scipy.fft"
    assert backend.kernels.__name__ == "workers.backends.kernels"


def test_a_torch_generator_is_seeded_on_its_device():
    backend = get_backend("torch", "cpu")
    first = torch.rand(5, generator=backend.generator(11))
    again = torch.rand(5, generator=backend.generator(11))
    other = torch.rand(5, generator=backend.generator(12))
    assert torch.equal(first, again) and not torch.equal(first, other)


def test_get_backend_is_cached_and_backends_are_dictionary_keys():
    assert get_backend("torch", "cpu") is get_backend("torch", "cpu")
    assert {get_backend(): 1}[get_backend("numpy", "cpu")] == 1
