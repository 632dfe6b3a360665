"""Admission of a sweep: everything checked before anything is queued, written or deleted.

One path for both front ends: ``oceanlidar run`` and ``validate`` (`service.cli`) admit the
sweep file with `admit`, and `service.run.execute` checks the output with `check_output`;
the job service (``POST /v1/jobs``, `service.jobs.Runner.submit`) checks the submitted
text's quick part at once with `admit_header` (its output confined under the data root,
`confine_output`) and the whole of it in the background with `admit_job`, which calls
`admit` and `check_output`. What differs between them is a `Rules`: the limits, and the remedy
their messages name (the command line's flags, the service's modes). Every refusal is an
`service.errors.InputError` of its kind.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import fsspec
import numpy as np

from service import package_version
from service.devices import NUMPY, check_same
from service.errors import BadFileError, BadOptionError, OutputTakenError, UnusableOutputError
from service.inputs import DEFAULT_MAX_MEMORY, MAX_FILE_BYTES, shown
from service.stats import check_owner
from service.store import integrity
from service.store.location import KIND, Store, old_gate_numbering
from service.store.template import check_uniform
from service.sweep import MEMORY_REMEDY, NO_LIMITS, Plan, parse_sweep, read_header
from workers.backends.backend import Backend

__all__ = [
    "CLI",
    "MODES",
    "SERVICE",
    "Rules",
    "admit",
    "admit_header",
    "admit_job",
    "check_output",
    "confine_output",
    "enclosing_store",
    "parents",
    "resumable",
]

MODES = ("new", "resume", "overwrite")
"""What a run does with an existing output: refuse it, complete it, replace it."""


@dataclass(frozen=True)
class Rules:
    """How a front end admits sweeps: its limits, and the remedies its messages name.

    Attributes
    ----------
    limits : bool
        Whether the size and memory limits hold (``--no-limits`` lifts them).
    max_memory : float
        The most memory [bytes] one sample may need (`service.sweep.memory_estimate`).
    too_big : str
        What to do about a sweep over the size limits.
    too_heavy : str
        What to do about a sample over `max_memory`.
    exists : str
        What to do about an output that exists, in a new run.
    """

    limits: bool = True
    max_memory: float = DEFAULT_MAX_MEMORY
    too_big: str = NO_LIMITS
    too_heavy: str = MEMORY_REMEDY
    exists: str = "pass --resume to complete it or --overwrite"


CLI = Rules()
"""The command line's rules (its flags change the limits: `Rules(limits=..., ...)`)."""
SERVICE = Rules(
    too_big="split it into smaller sweeps (the service's limit)",
    too_heavy="make each sample smaller (the service's limit)",
    exists="submit with mode resume (oceanlidar submit --resume) to complete it or "
    "overwrite (--overwrite) to replace it",
)
"""The job service's rules: always its limits."""


def admit(
    text: str, *, folder, rules: Rules = CLI, resume: Callable[[str], Store] | None = None
) -> Plan:
    """The plan of the sweep `text`: validated, within `rules`' limits, one store's layout.

    `folder` is where the sweep's relative paths start (`service.sweep.parse_sweep`).
    `resume` (a resume's), called with the sweep's output, gives the store the run would
    complete: if that store holds this sweep written by this version (`resumable`), its
    points were checked when it was made, and only the scenes of the samples the run
    addresses are built (`service.sweep.Plan.stored_image`); the limits are checked all
    the same.

    Raises
    ------
    InputError
        A `BadSweepError`, `BadFileError` (a measurement file) or `TooBigError`.
    """
    plan = parse_sweep(
        text,
        folder=folder,
        max_memory=rules.max_memory if rules.limits else None,
        memory_remedy=rules.too_heavy,
        resumed=None
        if resume is None
        else lambda sweep, digest: resumable(resume(sweep.output), digest),
    )
    if rules.limits:
        plan.check_limits(remedy=rules.too_big)
    if plan.stored_image is None:  # else checked when its store was made
        check_uniform(plan)
    return plan


def resumable(store: Store, digest: str) -> np.dtype | None:
    """The image type of `store` if it holds the sweep `digest` written by this version.

    None if it does not (or cannot be read): then the plan is checked whole, and
    `check_output` says what is wrong with the store. `check_output` checks the store
    again, holding its writer's lock.
    """
    try:
        previous = store.attributes() or {}
        if (
            previous.get(KIND) != "samples"
            or previous.get("sweep_sha256") != digest
            or previous.get("oceanlidar_version") != package_version()
        ):
            return None
        image = store.group().get("image")
    except (OSError, ValueError):
        return None
    return None if image is None else image.dtype


def check_output(
    plan: Plan,
    store: Store,
    *,
    resume: bool,
    overwrite: bool,
    name: str | None = None,
    rules: Rules = CLI,
    backend: Backend = NUMPY,
) -> tuple:
    """Check what is at the output before anything is written or deleted.

    `name` is how messages name the output `store` (default: its URL). A resumed store
    must have been rendered on `backend` (`service.devices.check_same`).

    Returns
    -------
    tuple of (bool, list, list)
        Whether an existing store is resumed, and the files of the old store and of its
        statistics that ``--overwrite`` deletes (`service.store.location.Store.removable`).

    Raises
    ------
    UnusableOutputError
        If the output or the statistics path holds something this run may not replace
        (the statistics of another store among them: `service.stats.check_owner`), or
        the output is neither a folder nor a regular file (``/dev/null``); an
        `OutputTakenError` if the output is occupied and neither resumed nor overwritten;
        an `UnusableOutputError` too for a resume on another backend or device.
    """
    name = name or store.url
    if (outer := enclosing_store(store)) is not None:
        raise UnusableOutputError(
            f"{name} lies inside the store {shown(outer)}; choose an output outside it"
        )
    if store.special():
        raise UnusableOutputError(
            f"{name} exists and is neither a folder nor a regular file (a device, a pipe, a "
            "socket?); choose another output"
        )
    check_owner(store)
    stats_files = store.stats.removable("statistics")
    if not store.occupied():
        return False, [], []
    if not resume and not overwrite:
        raise OutputTakenError(f"{name} already exists; {rules.exists}")
    if overwrite:
        return False, store.removable("samples"), stats_files
    previous = store.attributes() or {}
    if previous.get(KIND) != "samples":
        raise UnusableOutputError(
            f"{name} is not an oceanlidar samples store; cannot resume into it"
        )
    if previous.get("sweep_sha256") != plan.digest:
        raise UnusableOutputError(
            f"{name} holds a different sweep (its hash differs); refusing to resume into it"
        )
    written_by = previous.get("oceanlidar_version")
    if written_by != package_version():
        raise UnusableOutputError(
            f"{name} was written by oceanlidar {written_by}, this is "
            f"{package_version()}: samples would differ; resume with that version "
            "or start again with --overwrite"
        )
    if not store.finished():
        raise UnusableOutputError(
            f"{name}'s template was not finished (a run stopped while writing it); "
            "start again with --overwrite"
        )
    check_same(previous, backend, name=name)
    gates = store.group().get("gate")
    if gates is not None and (problem := old_gate_numbering(gates[:], name)):
        raise UnusableOutputError(problem)
    if stale := integrity.stale_layout(store, plan):
        raise UnusableOutputError(
            f"{name} was written with another layout of its samples ({', '.join(stale)} "
            "missing or shaped otherwise): start again with --overwrite"
        )
    return True, [], []


def confine_output(output: str, data_root: str) -> str:
    """The store URL of a sweep's `output` under `data_root`.

    Raises
    ------
    UnusableOutputError
        If `output` is a URL (chained ``::`` ones included) or an absolute path, climbs
        out of `data_root`, as written or through links, or lies under (or is) a symbolic
        link of a local `data_root` (wherever it leads: a link planted later could lead
        out; the service checks again as the job starts, `service.jobs.Runner`).
    """
    if any(ord(character) < 32 for character in output):
        raise UnusableOutputError(
            f"output: control characters are not allowed, got {shown(output)}"
        )
    protocol, _ = fsspec.core.split_protocol(output)
    normal = os.path.normpath(output)
    if (
        protocol is not None
        or "://" in output
        or "::" in output
        or os.path.isabs(output)
        or normal == os.curdir
        or normal.split(os.sep)[0] == os.pardir
    ):
        raise UnusableOutputError(
            f"output: must be a path relative to the service's data root, inside it, "
            f"got {shown(output)}"
        )
    url = f"{data_root.rstrip('/')}/{normal}"
    if fsspec.core.split_protocol(data_root)[0] in (None, "file", "local"):
        root = os.path.realpath(data_root)
        if os.path.commonpath([root, os.path.realpath(url)]) != root:
            raise UnusableOutputError(
                f"output: {shown(output)} leads out of the service's data root"
            )
        parts = normal.split(os.sep)
        for depth in range(1, len(parts) + 1):
            if os.path.islink(os.path.join(data_root, *parts[:depth])):
                raise UnusableOutputError(
                    f"output: {shown(output)} lies under the symbolic link "
                    f"{shown(os.path.join(*parts[:depth]))} of the data root; outputs may not"
                )
    return url


def parents(url: str) -> list[str]:
    """The folders `url` lies in, innermost first (``a/b/c`` → ``a/b``, ``a``)."""
    parts = url.rstrip("/").split("/")
    return ["/".join(parts[:depth]) for depth in range(len(parts) - 1, 0, -1)]


def enclosing_store(store: Store, *, within: str | None = None) -> str | None:
    """The innermost store that `store` would lie inside, if any.

    Every folder above it is looked at (one metadata read each), up to the file system's
    root or the bucket (neither looked at), or below `within` (the service's data root,
    not itself looked at). Below `within` any zarr group or array counts; elsewhere an
    oceanlidar dataset (its `KIND` attribute: samples, statistics, detection), so that a
    folder above that happens to be some other zarr group refuses nothing.

    Returns
    -------
    str or None
        The enclosing store's URL; None if `store` lies inside none.
    """
    for folder in parents(store.url):
        if not folder or (within is not None and not folder.startswith(f"{within.rstrip('/')}/")):
            break  # the file system's root, or the data root
        if "://" in folder and "/" not in folder.split("://", 1)[1]:
            break  # the bucket
        above = store.other(folder)
        if above.kind() is not None if within is None else above.attributes() is not None:
            return folder
    return None


def admit_header(text: str, mode: str, *, data_root: Store) -> tuple:
    """The quick checks of a submitted sweep, those the service answers at once.

    `mode` (one of `MODES`), the text's size, the sweep's header (`service.sweep.read_header`:
    YAML, schema, default scene, under the `SERVICE` rules) and its output confined under
    `data_root`: none grows with the sweep's points. `admit_job` does the rest.

    Returns
    -------
    tuple of (Sweep, str)
        The parsed sweep file and the store URL its output names.

    Raises
    ------
    InputError
        With the field path and the reason.
    """
    if mode not in MODES:
        raise BadOptionError(f"mode: must be one of {', '.join(MODES)}, got {shown(mode)}")
    if len(text.encode()) > MAX_FILE_BYTES:
        raise BadFileError(f"the sweep is larger than {MAX_FILE_BYTES:,} bytes")
    sweep = read_header(
        text,
        folder=data_root.url,
        max_memory=SERVICE.max_memory,
        memory_remedy=SERVICE.too_heavy,
    )
    return sweep, confine_output(sweep.output, data_root.url)


def admit_job(text: str, mode: str, *, data_root: Store, backend: Backend = NUMPY) -> tuple:
    """Check a submitted sweep as ``oceanlidar run`` would; its plan and store URL.

    The sweep passes `admit_header`, then is admitted whole under the service's `SERVICE`
    rules (every point), its output checked never to lie inside another store (under
    `data_root`, a folder or prefix with the service's storage options) and for `mode`
    (a resumed store rendered on the service's `backend`).

    Raises
    ------
    InputError
        With the field path and the reason; nothing is queued or written.
    """
    _, url = admit_header(text, mode, data_root=data_root)
    resume = (lambda _: data_root.other(url)) if mode == "resume" else None
    plan = admit(text, folder=data_root.url, rules=SERVICE, resume=resume)
    root = data_root.url.rstrip("/")
    if (outer := enclosing_store(data_root.other(url), within=root)) is not None:
        raise UnusableOutputError(
            f"output: {shown(plan.sweep.output)} lies inside the store "
            f"{shown(outer[len(root) + 1 :])}"
        )
    store = data_root.other(url)
    with store.errors():
        check_output(
            plan,
            store,
            resume=mode == "resume",
            overwrite=mode == "overwrite",
            name=f"output: {shown(plan.sweep.output)}",
            rules=SERVICE,
            backend=backend,
        )
    return plan, url
