"""The array backends a sample is rendered on: numpy (with numba kernels) or PyTorch.

The physics is written once, against the array API standard (`array_api_compat`'s
namespaces); the few operations the standard lacks (scatter-add, bilinear gather, the
column convolution, Poisson draws) are small kernels per backend: `workers.backends.kernels`
(numba) for numpy, `workers.backends.kernels_torch` for PyTorch, with the same names, arguments
and out-parameters. PyTorch runs on the CPU (the tests) and on CUDA devices.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import re
from dataclasses import dataclass

import numpy as np

__all__ = ["BACKENDS", "Backend", "get_backend"]

BACKENDS = ("numpy", "torch")
"""The backends' names."""

INSTALL_HINT = "pip install 'oceanlidar[train]' for the CPU, 'oceanlidar[gpu]' for CUDA devices"
"""What installs PyTorch for the torch backend."""


@dataclass(frozen=True)
class Backend:
    """An array backend and its device: where a sample's arrays live and what computes them.

    Build it with `get_backend`, which checks that it can run here.

    Parameters
    ----------
    name : str
        ``numpy`` or ``torch``.
    device : str
        ``cpu``, or for torch ``cuda`` / ``cuda:N``.
    """

    name: str
    device: str

    @property
    def xp(self):
        """The backend's array API namespace (`array_api_compat`'s wrapper)."""
        return importlib.import_module(f"array_api_compat.{self.name}")

    @property
    def fft(self):
        """The FFTs: `scipy.fft` for numpy (the renderer's bytes), the namespace's for torch."""
        if self.name == "numpy":
            return importlib.import_module("scipy.fft")
        return self.xp.fft

    @property
    def kernels(self):
        """The module of compiled kernels: `kernels` or `kernels_torch` (this package)."""
        module = (
            "workers.backends.kernels"
            if self.name == "numpy"
            else "workers.backends.kernels_torch"
        )
        return importlib.import_module(module)

    def asarray(self, values, dtype=None):
        """A host array (or scalar) as an array of this backend on its device.

        Parameters
        ----------
        values : array_like
            The values (a numpy array is not copied on the numpy backend; on torch the
            tensor is always a copy, so that writing to it never changes the host array).
        dtype : numpy.dtype or None, optional
            The numpy dtype to convert to first (None: keep it).

        Returns
        -------
        array
            numpy.ndarray or torch.Tensor on `device`, of the same shape (a scalar: 0-d;
            a read-only array moves as any other).
        """
        values = np.asarray(values, dtype=dtype)
        if self.name == "numpy":
            return values
        torch = importlib.import_module("torch")
        return torch.tensor(values, device=self.device)

    def to_numpy(self, values) -> np.ndarray:
        """An array of this backend on the host, as numpy."""
        if self.name == "numpy":
            return np.asarray(values)
        return values.detach().cpu().numpy()

    def generator(self, seed: int):
        """A random generator on the device seeded with `seed` (None on numpy).

        Parameters
        ----------
        seed : int
            A non-negative integer below 2⁶³.
        """
        if self.name == "numpy":
            return None
        torch = importlib.import_module("torch")
        return torch.Generator(device=self.device).manual_seed(int(seed))


@functools.lru_cache(maxsize=8)
def get_backend(name: str = "numpy", device: str = "cpu") -> Backend:
    """The backend `name` on `device`, checked to run here.

    Parameters
    ----------
    name : str, optional
        ``numpy`` or ``torch``.
    device : str, optional
        ``cpu``; for torch also ``cuda`` or ``cuda:N``.

    Returns
    -------
    Backend

    Raises
    ------
    ValueError
        Naming ``backend`` or ``device`` and why: an unknown backend or device, PyTorch
        not installed, no CUDA device, numpy on a device other than the CPU.
    """
    if name not in BACKENDS:
        raise ValueError(f"backend: {name!r} is not one of {', '.join(BACKENDS)}")
    if not isinstance(device, str) or not re.fullmatch(r"cpu|cuda(:[0-9]+)?", device):
        raise ValueError(f"device: {device!r} is neither 'cpu' nor 'cuda' (or 'cuda:N')")
    if name == "numpy":
        if device != "cpu":
            raise ValueError(f"device: the numpy backend runs on the cpu, not {device!r}")
        return Backend(name=name, device=device)
    if importlib.util.find_spec("torch") is None:
        raise ValueError(f"backend: torch is not installed here ({INSTALL_HINT})")
    if device != "cpu":
        torch = importlib.import_module("torch")
        if not torch.cuda.is_available():
            raise ValueError(f"device: {device!r} asked, but this machine has no CUDA device")
        index = int(device.partition(":")[2] or 0)  # the pattern above: digits
        if index >= torch.cuda.device_count():
            raise ValueError(
                f"device: {device!r} asked, but this machine has "
                f"{torch.cuda.device_count()} CUDA device(s)"
            )
    return Backend(name=name, device=device)


def moved(values, backend: Backend):
    """Host arrays (nested in tuples; None kept) as arrays of `backend`; numbers as floats."""
    if values is None:
        return None
    if isinstance(values, tuple):
        return tuple(moved(v, backend) for v in values)
    if np.ndim(values) == 0:  # a ray origin shared by every ray: a float32 value
        return float(values)
    return backend.asarray(values)
