"""Where a run renders: the array backend and device a store's samples come from.

``--backend numpy|torch`` and ``--device cpu|cuda[:N]`` (``run``, ``validate``, ``serve``)
name a `workers.backends.backend.Backend`: numpy on the CPU by default, and a CUDA device implies
torch. The backend is checked by `workers.backends.backend.get_backend` where the samples render:
here for the embedded cluster and ``validate``, on a worker of ``--scheduler``'s cluster
before anything is written (`check_on_worker`). Samples rendered on another backend or
device are other bytes (torch's random streams and FFTs are not numpy's, nor CUDA's the
CPU's), so a store records where it was rendered (`recorded`) and a resume refuses to mix
(`check_same`).
"""

from __future__ import annotations

from service.errors import BadOptionError, BadSweepError, UnusableOutputError
from workers.backends.backend import Backend, get_backend

__all__ = [
    "BACKEND_ATTR",
    "DEVICE_ATTR",
    "NUMPY",
    "check_on_worker",
    "check_same",
    "choose",
    "named",
    "recorded",
    "stored",
]

BACKEND_ATTR = "render_backend"
"""Root attribute of a samples store: the array backend its samples were rendered on."""
DEVICE_ATTR = "render_device"
"""Root attribute of a samples store: the kind of device they were rendered on."""
NUMPY = Backend(name="numpy", device="cpu")
"""The default backend, and that of the stores written before they recorded one."""


def named(backend: str | None, device: str | None) -> tuple[str, str]:
    """The backend and device that ``--backend`` and ``--device`` name, defaults filled in.

    A device of None is ``cpu``; a backend of None is torch on a CUDA device, else numpy.
    """
    device = "cpu" if device is None else device
    return backend or ("numpy" if device == "cpu" else "torch"), device


def choose(backend: str | None, device: str | None, *, here: bool = True) -> Backend:
    """The backend that ``--backend`` and ``--device`` name, checked if it renders `here`.

    Parameters
    ----------
    backend : str or None
        ``numpy`` or ``torch``; None: torch on a CUDA device, else numpy.
    device : str or None
        ``cpu``, ``cuda`` or ``cuda:N``; None: ``cpu``.
    here : bool, optional
        Whether this process's machine renders (``validate``, the embedded cluster): then
        `workers.backends.backend.get_backend` checks that it can. False for a ``--scheduler``'s
        workers, checked there (`check_on_worker`).

    Returns
    -------
    Backend

    Raises
    ------
    BadOptionError
        Naming ``--backend`` or ``--device`` and why (torch not installed, no CUDA device,
        numpy on a GPU, an unknown name; a GPU's index for a scheduler's workers).
    """
    name, device = named(backend, device)
    if not here:
        if ":" in device:
            raise BadOptionError(
                f"--device {device}: a scheduler's GPU workers each render on the GPU they "
                "were given; pass --device cuda"
            )
        return Backend(name=name, device=device)
    try:
        return get_backend(name, device)
    except ValueError as error:
        raise BadOptionError(f"--{error}") from None


def check_renderers(plan, backend: Backend, points=None) -> None:
    """Refuse a sweep with Monte Carlo points on a backend other than numpy, before any work.

    Parameters
    ----------
    plan : service.sweep.Plan
        The sweep (every point's scene is read: built, on a trusted resume).
    backend : Backend
        Where it would render.
    points : iterable of int, optional
        The points that render (``preview``'s one); default every point.

    Raises
    ------
    BadOptionError
        Naming ``--backend`` and the first such point.
    """
    if backend.name == "numpy":
        return
    for point in range(len(plan.scenes)) if points is None else points:
        if plan.scenes[point].transport.method == "monte_carlo":
            raise BadOptionError(
                f"--backend {backend.name}: point {point} renders by Monte Carlo "
                "(transport.method: monte_carlo), which runs on the numpy backend only"
            )


def check_on_worker(backend: Backend) -> None:
    """Check on a dask worker that it renders on `backend` (`get_backend`).

    Raises
    ------
    ValueError
        As `get_backend` does (the client turns it into a `BadOptionError`).
    """
    get_backend(backend.name, backend.device)


def recorded(backend: Backend) -> dict[str, str]:
    """The root attributes that record `backend` in a store: its name and device kind.

    The device is recorded without its index (``cuda``, not ``cuda:1``): every GPU of a
    cluster renders the same bytes.
    """
    return {BACKEND_ATTR: backend.name, DEVICE_ATTR: backend.device.partition(":")[0]}


def stored(attributes: dict) -> dict[str, str]:
    """The backend and device a store's root `attributes` record (numpy, cpu if none)."""
    return {key: attributes.get(key, value) for key, value in recorded(NUMPY).items()}


def written_by(attributes: dict, name: str) -> Backend:
    """The backend and device that rendered a store's samples, checked to run here.

    What ``detect`` renders a store's samples again on, for their expected images (another
    backend draws other noise).

    Parameters
    ----------
    attributes : dict
        The store's root attributes.
    name : str
        The store, for the message.

    Raises
    ------
    BadSweepError
        Naming the store's backend and device and why they cannot run here.
    """
    written = stored(attributes)
    try:
        return get_backend(written[BACKEND_ATTR], written[DEVICE_ATTR])
    except ValueError as error:
        raise BadSweepError(
            f"{name}: its samples were rendered with --backend {written[BACKEND_ATTR]} "
            f"--device {written[DEVICE_ATTR]}, and detect renders them again there for their "
            f"expected images, but cannot here ({error})"
        ) from None


def check_same(attributes: dict, backend: Backend, *, name: str) -> None:
    """Refuse to resume the store `name` (root `attributes`) on another backend or device.

    Raises
    ------
    UnusableOutputError
        Naming both, and the remedy: resume with the store's flags, or ``--overwrite``.
    """
    were, now = stored(attributes), recorded(backend)
    if were != now:
        raise UnusableOutputError(
            f"{name} was rendered with --backend {were[BACKEND_ATTR]} --device "
            f"{were[DEVICE_ATTR]}, this run renders with --backend {now[BACKEND_ATTR]} "
            f"--device {now[DEVICE_ATTR]}: its samples would differ; resume with "
            f"--backend {were[BACKEND_ATTR]} --device {were[DEVICE_ATTR]} or start again "
            "with --overwrite"
        )
