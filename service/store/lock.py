"""The writer's lock: one run (or ``stats``) writes a store at a time.

The lock is a file beside the store (`lock_file`: ``run.zarr.lock`` for ``run.zarr``),
created exclusively; the workers check that they see it (`check_workers_see`) before
anything is rendered. Both take the `service.store.location.Store` (`Store.lock`,
`Store.check_workers_see`). It is kept out of the store because zarr lists a store's
folder to find its members and warns of every file there that is none (``Object at
oceanlidar.lock is not recognized``), while a run held the lock or after one died holding
it; a lock that an older version left in the store (`LEGACY_LOCK_NAME`) is still honoured.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import socket
import time
import uuid

from service.errors import LockedError, UnusableOutputError
from service.inputs import shown

__all__ = ["LEGACY_LOCK_NAME", "LOCK_SUFFIX", "check_workers_see", "lock_file", "writer_lock"]

LOCK_SUFFIX = ".lock"
"""The writer's lock of a store is the file named as the store with this suffix, beside it."""

LEGACY_LOCK_NAME = "oceanlidar.lock"
"""The writer's lock where earlier versions kept it: a file in the store (zarr warned of it).
One left there is taken over if stale (`_is_stale`), else it refuses the writer."""

TAKEOVER_SUFFIX = ".takeover"
"""Suffix of the guard file held while a stale lock is removed (`_remove_stale`)."""

TAKEOVER_WAIT = 5.0
"""Longest wait for another run's takeover guard, s."""


def lock_file(path: str) -> str:
    """The writer's lock of the store at `path` (a path or an fsspec path): the file beside it.

    ``/data/run.zarr`` → ``/data/run.zarr.lock``; ``bucket/run.zarr`` → ``bucket/run.zarr.lock``.
    """
    return path.rstrip("/") + LOCK_SUFFIX


def check_workers_see(store, token: str) -> None:
    """Check, on a worker, that the store the runner locked is there and writable.

    Run this as a dask task before any sample is rendered: a worker that sees another file
    system (``memory://``, a disk of its own machine) does not find the lock's token.

    Parameters
    ----------
    store : service.store.location.Store
        The store.
    token : str
        The lock's token (`writer_lock`).

    Raises
    ------
    UnusableOutputError
        If the worker does not see the lock, or cannot write beside it.
    """
    fs, path = store.fs, store.path
    with store.errors():
        if _holder(fs, lock_file(path)).get("token") != token:
            raise UnusableOutputError(
                f"the workers do not see the store {shown(store.url)} that the runner created "
                "(another machine's disk, or a store in one process's memory?): write to "
                "storage every worker shares, such as an object-store URL"
            )
        probe = f"{path}/oceanlidar.probe-{uuid.uuid4().hex}"
        fs.pipe_file(probe, b"")
        fs.rm(probe)


def _holder(fs, lock: str) -> dict:
    try:
        holder = json.loads(fs.cat_file(lock))
    except (OSError, ValueError):
        return {}
    return holder if isinstance(holder, dict) else {}


def _is_stale(holder: dict, claim: str | None) -> bool:
    """A lock taken by a process that no longer runs, or by an earlier run of `claim`.

    A process that died on this machine is known dead. A lock whose ``claim`` is `claim`
    was taken by an earlier run of the same claimant: the batch service claims a job's
    store with the job's id (`service.jobs`), and a job is run again only once the service
    that ran it has died, on whatever machine (a container restarted as process 1, a pod
    with a new host name): a service owns its job table exclusively
    (`service.table.JobTable`), so no live service still runs the job.
    """
    if claim is not None and holder.get("claim") == claim:
        return True
    if holder.get("host") != socket.gethostname() or not isinstance(holder.get("pid"), int):
        return False
    try:
        os.kill(holder["pid"], 0)
    except ProcessLookupError:
        return True
    except OSError:  # alive, owned by another user
        return False
    return False


def _create_exclusive(fs, path: str, data: bytes) -> None:
    """Create the file `path` holding `data`, or raise FileExistsError if it is there.

    On a file system this is ``os.open`` with ``O_CREAT | O_EXCL`` (fsspec's
    ``mode="create"`` there checks, then writes: two writers can both get through). On
    object storage it is fsspec's conditional put (``If-None-Match``).
    """
    if "file" in fs.protocol:
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        with os.fdopen(descriptor, "wb") as handle:
            handle.write(data)
        return
    fs.pipe_file(path, data, mode="create")


def _remove_stale(fs, lock: str, holder: dict, record: dict) -> None:
    """Remove the lock file if it still holds the stale `holder`, one taker at a time.

    Two runs that both found the same dead holder must not both remove "the" lock: the
    second would delete the lock the first had just taken, and both would write. So the
    removal happens under a short-lived guard file (`TAKEOVER_SUFFIX`, created
    exclusively), and only if the lock still holds the very record found stale. After
    that both runs race for the exclusive create, which only one wins.

    Raises
    ------
    LockedError
        If the guard stays in place for `TAKEOVER_WAIT` s (a taker died within the
        microseconds it holds it): the message names the file to delete.
    """
    guard = lock + TAKEOVER_SUFFIX
    deadline = time.monotonic() + TAKEOVER_WAIT
    while True:
        try:
            _create_exclusive(fs, guard, json.dumps(record).encode())
            break
        except FileExistsError:
            if time.monotonic() > deadline:
                raise LockedError(
                    f"another run is taking over the stale lock {lock}; if none is, delete "
                    f"{guard} and try again"
                ) from None
            time.sleep(0.01)
    try:
        if _holder(fs, lock) == holder:
            fs.rm(lock)
    finally:
        fs.rm(guard)


@contextlib.contextmanager
def writer_lock(store, *, claim: str | None = None):
    """Hold the store's writer lock: one run (or ``stats``) writes a store at a time.

    The lock is the file beside the store (`lock_file`), created only if absent (an
    exclusive create: ``O_EXCL`` on a file system, a conditional ``If-None-Match`` put on
    object storage), holding the holder's host, process id and start time. It is removed
    on exit. A lock an older version left in the store (`LEGACY_LOCK_NAME`) is honoured
    as this one is, once this one is held: deleted if stale, else the writer is refused.

    A lock left by a process that died on this machine, or one holding the same `claim`
    (`_is_stale`), is taken over, by one run only when several find it at once
    (`_remove_stale`). Any other lock left by a machine that crashed cannot be told from
    a live run elsewhere: the message names the file to remove once no run is writing.

    Parameters
    ----------
    store : service.store.location.Store
        The store.
    claim : str or None
        Who the run writes for, kept in the lock: a lock of the same claim left by a run
        that was interrupted is taken over.

    Yields
    ------
    str
        The lock's token (`check_workers_see` looks for it).

    Raises
    ------
    LockedError
        If another run holds the lock.
    UnusableOutputError
        If the store's place cannot be written.
    """
    fs, path = store.fs, store.path
    lock = lock_file(path)
    token = uuid.uuid4().hex
    record = {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "since": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "token": token,
    }
    if claim is not None:
        record["claim"] = claim
    with store.errors():
        created = not fs.exists(path)
        if store.local:
            fs.makedirs(path, exist_ok=True)
    for attempt in range(2):
        try:
            with store.errors():
                _create_exclusive(fs, lock, json.dumps(record).encode())
            break
        except FileExistsError:
            holder = _holder(fs, lock)
            if attempt == 0 and _is_stale(holder, claim):
                with store.errors():  # a read-only file system refuses the takeover's guard
                    _remove_stale(fs, lock, holder, record)
                continue
            raise _locked(store, holder, lock) from None
    try:
        _clear_legacy(store, claim)
        yield token
    finally:
        if _holder(fs, lock).get("token") == token:
            fs.rm(lock)
        if created and store.local:
            with contextlib.suppress(OSError):  # holds a store now
                os.rmdir(path)


def _locked(store, holder: dict, lock: str) -> LockedError:
    """The refusal of a writer: who holds `lock` since when, and the file to delete."""
    return LockedError(
        f"{store.url} is locked by another run (host {holder.get('host', '?')}, process "
        f"{holder.get('pid', '?')}, since {holder.get('since', '?')}); wait for it, "
        f"or, if no run is writing there any more, delete {lock} and try again"
    )


def _clear_legacy(store, claim: str | None) -> None:
    """Honour a lock an older version left in the store (`LEGACY_LOCK_NAME`).

    Called holding the lock beside the store, so no writer of this version races for it:
    a stale one (`_is_stale`) is deleted, any other refuses the writer.

    Raises
    ------
    LockedError
        If the old lock's holder may still be writing.
    """
    fs, legacy = store.fs, f"{store.path}/{LEGACY_LOCK_NAME}"
    with store.errors():
        if not fs.exists(legacy):
            return
        holder = _holder(fs, legacy)
        if not _is_stale(holder, claim):
            raise _locked(store, holder, legacy)
        fs.rm(legacy)
