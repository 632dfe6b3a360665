"""The sweep's zarr store: template, region writes, completion records.

Layout (README, "The dataset"): dimensions ``sample, frame, gate, y, x``, one sample per chunk. The
template (metadata and the coordinates that do not depend on rendering) is written once with
``compute=False``; each task then writes whole chunks of its samples with region writes, and
only after that sets their ``completed`` flags, so an interrupted run never marks a sample
complete that is not written.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import re
import socket
import uuid
import warnings
import zlib
from importlib.metadata import PackageNotFoundError, version

import dask.array as da
import fsspec
import numpy as np
import xarray as xr
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from service.sweep import Plan, SweepError, field_units, shown
from workers.labels import rendered_variables
from workers.render import render, sample_labels
from workers.seeds import SampleSeed

__all__ = [
    "CODECS",
    "KIND",
    "LOCK_NAME",
    "RENDERED_VARIABLES",
    "DamagedStoreError",
    "check_uniform",
    "check_workers_see",
    "completed_samples",
    "create_store",
    "invalid_values",
    "lazy_array",
    "mark_incomplete",
    "move",
    "normalise",
    "occupied",
    "one_per_chunk",
    "open_group",
    "open_store",
    "read_samples",
    "removable_files",
    "remove_files",
    "root_attributes",
    "sample_checksum",
    "sample_dataset",
    "stats_url",
    "storage_errors",
    "store_exists",
    "verify",
    "write_samples",
    "writer_lock",
]

RENDERED_VARIABLES = ("image", "expected", "target_mask", "surface_elevation")
"""Per-sample variables that tasks write; the rest of a sample is written with the template."""

FLAT_CHUNK_KEYS = {"name": "default", "separator": "."}
"""Chunk files named c.4.0.0.0.0 in the array's folder: one file per chunk, no folders to
create (each folder costs as much as a small file on the file systems measured)."""
CONVENTIONS = "CF-1.10"
KIND = "oceanlidar_dataset"
"""Root attribute naming what a store holds: ``samples`` (a sweep) or ``statistics``."""
LOCK_NAME = "oceanlidar.lock"
"""The writer's lock, a file in the store (see `writer_lock`)."""
CODECS = (ZstdCodec(), Crc32cCodec())
"""Compression, then a CRC32C checksum of every chunk: a damaged chunk fails to decode
instead of reading as other numbers."""


@contextlib.contextmanager
def consolidated_v3():
    """Write consolidated metadata to a zarr v3 store without zarr's standing warning.

    zarr-python warns that consolidated metadata is not yet part of the v3 specification;
    we keep it because opening a store then costs one read (it matters on object storage),
    and zarr-python, which we pin, reads it. Consolidating lists the store, where zarr
    notices the writer's lock (`writer_lock`), which is not part of the hierarchy by design.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
        warnings.filterwarnings("ignore", message=f"Object at {LOCK_NAME} is not recognized")
        yield


def package_version() -> str:
    """The installed oceanlidar version."""
    try:
        return version("oceanlidar")
    except PackageNotFoundError:
        return "unknown"


def stats_url(url: str) -> str:
    """Where the statistics dataset of the store at `url` lives (beside it)."""
    stem = url.rstrip("/")
    if stem.endswith(".zarr"):
        stem = stem[: -len(".zarr")]
    return stem + ".stats.zarr"


def _fs(url: str, storage_options: dict | None):
    try:
        return fsspec.core.url_to_fs(url, **(storage_options or {}))
    except (TypeError, ValueError, ImportError) as error:
        raise SweepError(f"{url}: cannot open with these storage options ({error})") from None


def lazy_array(shape: tuple, fill, dtype) -> da.Array:
    """A dask array standing for data the template does not write (few, large chunks).

    The zarr chunking comes from `one_per_chunk`: a dask graph with one chunk per sample
    would grow with the sweep (10⁶ samples: gigabytes in the client).
    """
    return da.full(shape, fill, dtype=dtype, chunks=(min(shape[0], 65536), *shape[1:]))


def one_per_chunk(shape: tuple) -> dict:
    """Zarr encoding: one leading index (sample or point) per chunk, flat keys, checksums."""
    return {"chunks": (1, *shape), "chunk_key_encoding": FLAT_CHUNK_KEYS, "compressors": CODECS}


def store_exists(url: str, storage_options: dict | None = None) -> bool:
    """Whether anything is stored at `url`."""
    fs, path = _fs(url, storage_options)
    return fs.exists(path)


def _files(fs, path: str) -> list[str]:
    """Every file under `path`, relative to it (a file at `path` itself is named '.')."""
    if fs.isfile(path):
        return ["."]
    root = path.rstrip("/") + "/"
    return sorted(name[len(root) :] for name in fs.find(path) if name.startswith(root))


def occupied(url: str, storage_options: dict | None = None) -> bool:
    """Whether `url` holds anything besides a writer's lock."""
    fs, path = _fs(url, storage_options)
    return any(name != LOCK_NAME for name in _files(fs, path))


def root_attributes(url: str, storage_options: dict | None = None) -> dict | None:
    """The attributes of the zarr group at `url`; None if there is no readable group."""
    fs, path = _fs(url, storage_options)
    try:
        metadata = json.loads(fs.cat_file(f"{path}/zarr.json"))
    except (OSError, ValueError):
        return None
    if not isinstance(metadata, dict) or metadata.get("node_type") != "group":
        return None
    attributes = metadata.get("attributes")
    return attributes if isinstance(attributes, dict) else None


def _shown(names: list[str]) -> str:
    more = f" and {len(names) - 1} more" if len(names) > 1 else ""
    return repr(names[0][:200]) + more


def removable_files(url: str, storage_options: dict | None, *, kind: str) -> list[str]:
    """The files of the `kind` dataset at `url`, which may be deleted to replace it.

    Only what the store's own metadata lists may go: its group and array metadata, and
    chunk keys of the arrays that its consolidated metadata names. Anything else in the
    folder (a user's file, a store of another kind) refuses the whole deletion, before
    anything is deleted.

    Parameters
    ----------
    url : str
        The store.
    storage_options : dict or None
        fsspec options.
    kind : {'samples', 'statistics', 'detection'}
        What the store must hold (its `KIND` attribute).

    Returns
    -------
    list of str
        Paths relative to the store, the writer's lock excluded; empty if nothing is there.

    Raises
    ------
    SweepError
        If something is there that is not such a store, or holds files it does not list.
    """
    fs, path = _fs(url, storage_options)
    files = [name for name in _files(fs, path) if name != LOCK_NAME]
    if not files:
        return []
    attributes = root_attributes(url, storage_options) or {}
    if attributes.get(KIND) != kind:
        raise SweepError(
            f"{url} exists and is not an oceanlidar {kind} store; refusing to delete it"
        )
    metadata = json.loads(fs.cat_file(f"{path}/zarr.json"))
    arrays = (metadata.get("consolidated_metadata") or {}).get("metadata") or {}
    listed = re.compile(
        r"zarr\.json|(?:"
        + "|".join(re.escape(name) for name in arrays)
        + r")/(?:zarr\.json|c(?:[./]\d+)*)"
    )
    strangers = [name for name in files if not listed.fullmatch(name)]
    if strangers:
        raise SweepError(
            f"{url} holds {_shown(strangers)}, which the store's metadata does not list; "
            "refusing to delete it (move those files away first)"
        )
    return files


def remove_files(url: str, storage_options: dict | None, files: list[str]) -> None:
    """Delete `files` (from `removable_files`) of the store at `url`, and emptied folders."""
    fs, path = _fs(url, storage_options)
    if not files:
        return
    fs.rm([f"{path}/{name}" for name in files])
    if "file" in fs.protocol:
        folders = {os.path.dirname(f"{path}/{name}") for name in files}
        for folder in sorted(folders, key=len, reverse=True):
            with contextlib.suppress(OSError):  # not empty: the lock, or a folder above
                os.rmdir(folder)


def move(url: str, to: str, storage_options: dict | None = None) -> None:
    """Move the store at `url` to `to` (same file system; nothing may be at `to`).

    On a file system this is one rename. Object storage has no rename: objects are copied,
    the group's metadata last (until it lands, nothing reads as a store at `to`), then
    deleted at `url`.
    """
    fs, path = _fs(url, storage_options)
    target = _fs(to, storage_options)[1]
    if "file" in fs.protocol:
        os.rename(path, target)
        return
    names = sorted(_files(fs, path), key=lambda name: name == "zarr.json")
    fs.copy([f"{path}/{name}" for name in names], [f"{target}/{name}" for name in names])
    fs.rm([f"{path}/{name}" for name in names])


def normalise(url: str, storage_options: dict | None = None) -> str:
    """The output as every process reads it: a local path absolute with ``~`` expanded.

    ``file://`` URLs become paths. A path is resolved here, in the runner, because zarr on
    the workers neither expands ``~`` nor shares the runner's working directory.

    Raises
    ------
    SweepError
        For storage options given with a local path (they apply to URLs only).
    """
    protocol, path = fsspec.core.split_protocol(url)
    if protocol not in (None, "file", "local"):
        return url
    if storage_options:
        raise SweepError(
            f"--storage-options apply to URLs such as s3://bucket/run.zarr, not to the local "
            f"path {shown(url)}"
        )
    return os.path.abspath(os.path.expanduser(path))


def _storage_failures() -> tuple[type[BaseException], ...]:
    """`OSError`, and what S3 clients raise untranslated (an unreachable endpoint)."""
    try:
        from botocore.exceptions import BotoCoreError
    except ImportError:  # no S3 support installed: fsspec raises OSError alone
        return (OSError,)
    return (OSError, BotoCoreError)


@contextlib.contextmanager
def storage_errors(url: str):
    """Turn a failure to reach or write storage into a `SweepError` naming `url`.

    ``FileExistsError`` passes through: the writer's lock tells it from a failure.
    """
    try:
        yield
    except FileExistsError:
        raise
    except _storage_failures() as error:
        reason = getattr(error, "strerror", None) or str(error) or type(error).__name__
        raise SweepError(f"{shown(url)} cannot be written: {reason[:200]}") from None


def check_workers_see(url: str, storage_options: dict | None, token: str) -> None:
    """Check, on a worker, that the store the runner locked is there and writable.

    Run this as a dask task before any sample is rendered: a worker that sees another file
    system (``memory://``, a disk of its own machine) does not find the lock's token.

    Raises
    ------
    SweepError
        If the worker does not see the lock, or cannot write beside it.
    """
    fs, path = _fs(url, storage_options)
    with storage_errors(url):
        if _holder(fs, f"{path}/{LOCK_NAME}").get("token") != token:
            raise SweepError(
                f"the workers do not see the store {shown(url)} that the runner created "
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


def _is_stale(holder: dict) -> bool:
    """A lock taken on this machine by a process that no longer runs."""
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


@contextlib.contextmanager
def writer_lock(url: str, storage_options: dict | None = None):
    """Hold the store's writer lock: one run (or ``stats``) writes a store at a time.

    The lock is the file `LOCK_NAME` in the store, created only if absent (an exclusive
    create: ``O_EXCL`` on a file system, a conditional ``If-None-Match`` put on object
    storage), holding the holder's host, process id and start time. It is removed on exit.

    A lock left by a process that died on this machine is taken over. A lock left by a
    machine that crashed cannot be told from a live run elsewhere: the message names the
    file to remove once no run is writing.

    Yields
    ------
    str
        The lock's token (`check_workers_see` looks for it).

    Raises
    ------
    SweepError
        If another run holds the lock, or the store's place cannot be written.
    """
    fs, path = _fs(url, storage_options)
    lock = f"{path}/{LOCK_NAME}"
    token = uuid.uuid4().hex
    record = {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "since": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "token": token,
    }
    with storage_errors(url):
        created = not fs.exists(path)
        if "file" in fs.protocol:
            fs.makedirs(path, exist_ok=True)
    for attempt in range(2):
        try:
            with storage_errors(url):
                _create_exclusive(fs, lock, json.dumps(record).encode())
            break
        except FileExistsError:
            holder = _holder(fs, lock)
            if attempt == 0 and _is_stale(holder):
                fs.rm(lock)
                continue
            raise SweepError(
                f"{url} is locked by another run (host {holder.get('host', '?')}, process "
                f"{holder.get('pid', '?')}, since {holder.get('since', '?')}); wait for it, "
                f"or, if no run is writing there any more, delete {lock} and try again"
            ) from None
    try:
        yield token
    finally:
        if _holder(fs, lock).get("token") == token:
            fs.rm(lock)
        if created and "file" in fs.protocol:
            with contextlib.suppress(OSError):  # holds a store now
                os.rmdir(path)


def check_uniform(plan: Plan) -> None:
    """One store holds one array shape: the shape-defining parameters must not vary."""
    first = plan.scenes[0]
    fields = {
        "receiver.pixels": lambda s: s.receiver.pixels,
        "receiver.gates": lambda s: s.receiver.gate_depths,
        "sequence.frames": lambda s: s.sequence.frames,
        "save_surface": lambda s: s.save_surface,
        "surface.grid_size": lambda s: s.surface.grid_size if s.save_surface else None,
        "surface.spacing": lambda s: s.surface_spacing() if s.save_surface else None,
    }
    for path, get in fields.items():
        if any(get(scene) != get(first) for scene in plan.scenes[1:]):
            raise SweepError(
                f"sweep.parameters.{path}: cannot vary within one sweep (it sets the shape of "
                "the stored arrays); run one sweep per value"
            )


def sample_dataset(plan: Plan, sample: int) -> xr.Dataset:
    """Render sample `sample` of the plan, with its per-sample coordinates."""
    point, realisation = divmod(sample, plan.realisations)
    return render(
        plan.scenes[point],
        seed=SampleSeed(root=plan.sweep.seed, point=point, realisation=realisation),
    )


def _coordinate_array(values: list) -> np.ndarray:
    """Numbers as numbers; anything else (names, lists) as strings (zarr's `string`)."""
    if all(isinstance(v, bool | int | float) for v in values):
        return np.asarray(values)
    return np.asarray([v if isinstance(v, str) else json.dumps(v) for v in values], dtype=object)


def create_store(plan: Plan, url: str, *, storage_options: dict | None = None) -> None:
    """Write the template of the store: metadata, coordinates, empty data arrays.

    Parameters
    ----------
    plan : Plan
        The validated sweep.
    url : str
        A path or fsspec URL; nothing but the writer's lock may be there yet.
    storage_options : dict, optional
        fsspec options (credentials, endpoint).
    """
    check_uniform(plan)
    first = plan.scenes[0]
    # names, dimensions, dtypes and attributes from the renderer's table; nothing rendered
    table = rendered_variables(first)
    sizes = {
        "frame": first.sequence.frames,
        "gate": len(first.receiver.gate_depths),
        "y": first.receiver.pixels,
        "x": first.receiver.pixels,
        "sy": first.surface.grid_size,
        "sx": first.surface.grid_size,
    }
    n = plan.samples
    realisations = plan.realisations
    data_vars = {}
    encoding = {}
    for name in RENDERED_VARIABLES:
        if name not in table:
            continue
        dims, dtype, attrs = table[name]
        shape = tuple(sizes[dim] for dim in dims)
        fill = np.nan if dtype.kind == "f" else 0
        data_vars[name] = (("sample", *dims), lazy_array((n, *shape), fill, dtype), dict(attrs))
        encoding[name] = one_per_chunk(shape)
    data_vars["completed"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint8),
        {"long_name": "sample rendered and written", "units": "1"},
    )
    encoding["completed"] = one_per_chunk(())
    data_vars["checksum"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint32),
        {"long_name": "CRC-32 of the sample's rendered arrays", "units": "1"},
    )
    encoding["checksum"] = one_per_chunk(())
    # labels and the platform track follow from each point's scene: written once, here
    track = ["time", "platform_x", "platform_y", "platform_z"]
    labels = xr.concat(
        [sample_labels(scene).reset_coords(track) for scene in plan.scenes],
        dim="sample",
        data_vars="all",
    )
    for name in ("target_present", "target_visibility", *track):
        variable = labels[name]
        data_vars[name] = (
            variable.dims,
            np.repeat(variable.values, realisations, axis=0),
            dict(variable.attrs),
        )
    coords = {
        "gate_top": labels["gate_top"],
        "gate_bottom": labels["gate_bottom"],
        "point": (
            "sample",
            np.repeat(np.arange(len(plan.points)), realisations),
            {"long_name": "parameter point index", "units": "1"},
        ),
        "realisation": (
            "sample",
            np.tile(np.arange(realisations), len(plan.points)),
            {"long_name": "Monte Carlo realisation index", "units": "1"},
        ),
    }
    axis = np.arange(first.surface.grid_size) * first.surface_spacing()
    for name in ("sx", "sy"):
        if name in table:
            coords[name] = (name, axis, dict(table[name][2]))
    for path in plan.swept:
        values = _coordinate_array([point[path] for point in plan.points])
        coords[path] = (
            "sample",
            np.repeat(values, realisations),
            {"long_name": f"swept scene parameter {path}", "units": field_units(path)},
        )
    ds = xr.Dataset(data_vars, coords=coords)
    for name in ds.variables:
        encoding.setdefault(name, {"compressors": CODECS})
    ds.attrs.update(
        title=f"oceanlidar sweep {plan.sweep.name}",
        Conventions=CONVENTIONS,
        source=f"oceanlidar {package_version()}",
        oceanlidar_version=package_version(),
        sweep=plan.text,
        sweep_sha256=plan.digest,
        seed=plan.sweep.seed,
        **{KIND: "samples"},
        realisations=realisations,
        points=len(plan.points),
    )
    with consolidated_v3():
        ds.to_zarr(
            url,
            mode="a",  # the folder holds the writer's lock
            compute=False,
            consolidated=True,
            zarr_format=3,
            encoding=encoding,
            storage_options=storage_options,
        )


def open_store(
    url: str, *, storage_options: dict | None = None, samples_per_chunk: int | None = None
) -> xr.Dataset:
    """Open a store lazily (dask arrays; one sample per dask chunk unless told otherwise)."""
    if samples_per_chunk is None:
        return xr.open_zarr(url, consolidated=True, storage_options=storage_options)
    with warnings.catch_warnings():
        # labels are stored in one chunk per array: splitting them for reading is intended
        warnings.filterwarnings("ignore", message="The specified chunks separate")
        return xr.open_zarr(
            url,
            consolidated=True,
            storage_options=storage_options,
            chunks={"sample": samples_per_chunk},
        )


def _chunk_samples(fs, folder: str) -> set[int]:
    """Sample indices of the chunks stored in an array's folder (flat keys ``c.S...``)."""
    return {
        int(name.split(".")[1])
        for name in _files(fs, folder)
        if name.startswith("c.") and name.split(".")[1].isdigit()
    }


def completed_samples(url: str, *, storage_options: dict | None = None) -> np.ndarray:
    """Boolean array: which samples are written.

    A sample's completion flag is a chunk of its own, and a flag of 0 is no chunk at all
    (zarr stores no chunk that holds only the fill value), so the flags are read from one
    listing of the ``completed`` array, not from one read per sample.
    """
    fs, path = _fs(url, storage_options)
    attributes = root_attributes(url, storage_options) or {}
    done = np.zeros(int(attributes["points"]) * int(attributes["realisations"]), dtype=bool)
    done[sorted(_chunk_samples(fs, f"{path}/completed"))] = True
    return done


def sample_checksum(arrays: list[np.ndarray]) -> int:
    """CRC-32 of a sample's rendered arrays, in `RENDERED_VARIABLES` order."""
    crc = 0
    for values in arrays:
        crc = zlib.crc32(np.ascontiguousarray(values).tobytes(), crc)
    return crc


def verify(url: str, storage_options: dict | None = None) -> list[tuple[int, str]]:
    """The samples marked complete whose chunks are missing, damaged or not theirs.

    Every chunk of every completed sample is read back (the CRC32C codec finds a damaged
    chunk) and the sample's arrays are compared with the checksum its task recorded
    (which finds a chunk deleted, or swapped with another sample's).

    Returns
    -------
    list of tuple
        ``(sample, reason)``, by sample index.
    """
    fs, path = _fs(url, storage_options)
    group = zarr.open_group(
        store=url, mode="r", zarr_format=3, use_consolidated=True, storage_options=storage_options
    )
    names = [name for name in RENDERED_VARIABLES if name in group]
    stored = {name: _chunk_samples(fs, f"{path}/{name}") for name in [*names, "checksum"]}
    problems = []
    for sample in np.flatnonzero(completed_samples(url, storage_options=storage_options)):
        missing = [name for name, samples in stored.items() if sample not in samples]
        if missing:
            problems.append((int(sample), f"no {' or '.join(missing)} chunk"))
            continue
        try:
            crc = sample_checksum([group[name][sample] for name in names])
            recorded = int(group["checksum"][sample])
        except Exception as error:
            problems.append((int(sample), f"a chunk cannot be read ({type(error).__name__})"))
            continue
        if crc != recorded:
            problems.append((int(sample), "its chunks do not match its checksum"))
    return problems


def mark_incomplete(url: str, samples: list[int], storage_options: dict | None = None) -> None:
    """Clear the completion flags of `samples`, so that a resumed run renders them again."""
    completed = open_group(url, storage_options)["completed"]
    for sample in samples:
        completed[sample] = 0


def open_group(url: str, storage_options: dict | None = None):
    """A store's zarr group, for whole-chunk writes into arrays the template created."""
    return zarr.open_group(
        store=url,
        mode="r+",
        zarr_format=3,
        use_consolidated=False,
        storage_options=storage_options,
    )


NON_NEGATIVE = ("image", "expected")
"""Rendered variables that are counts or intensities: never below zero."""


def invalid_values(sample: xr.Dataset) -> str | None:
    """Why a rendered sample may not be stored, or None if every value is valid.

    Floating-point variables must be finite, counts and intensities non-negative and
    the target mask 0 or 1: a sample that breaks any of these is never written nor marked
    complete.
    """
    for name in RENDERED_VARIABLES:
        if name not in sample:
            continue
        values = sample[name].values
        if values.dtype.kind == "f" and not np.isfinite(values).all():
            count = int(np.count_nonzero(~np.isfinite(values)))
            return f"{name} holds {count} non-finite value(s) (NaN or inf)"
        if name in NON_NEGATIVE and (values < 0).any():
            return f"{name} holds {int(np.count_nonzero(values < 0))} negative value(s)"
        if name == "target_mask" and (values > 1).any():
            return "target_mask holds values other than 0 and 1"
    return None


class DamagedStoreError(RuntimeError):
    """A chunk of a store cannot be read back: the message names the sample."""


def read_samples(array, samples: list[int]) -> np.ndarray:
    """The chunks of `samples` from a one-sample-per-chunk array.

    Raises
    ------
    DamagedStoreError
        Naming the first sample whose chunk fails to decode (a checksum that does not
        match, truncated or foreign bytes).
    """
    try:
        return array.get_orthogonal_selection((samples,))
    except Exception:
        for sample in samples:
            try:
                array[sample]
            except Exception as error:
                raise DamagedStoreError(
                    f"sample {sample}: its {array.basename} chunk cannot be read "
                    f"({type(error).__name__}: {str(error)[:120]}); run the sweep again with "
                    "--resume --verify to recompute it"
                ) from None
        raise


def write_samples(group, start: int, samples: list[xr.Dataset]) -> None:
    """Write consecutive rendered samples' whole chunks, then mark them complete.

    Writes go straight to the zarr arrays the template created (one chunk per sample per
    variable), one call per variable for the whole batch: xarray's region writes re-read
    the store's metadata on every call, which costs more than rendering a small sample.
    """
    region = slice(start, start + len(samples))
    names = [name for name in RENDERED_VARIABLES if name in samples[0]]
    stacked = {
        name: np.stack([sample[name].values for sample in samples]).astype(group[name].dtype)
        for name in names
    }
    for name in names:
        group[name][region] = stacked[name]
    group["checksum"][region] = np.array(
        [sample_checksum([stacked[name][i] for name in names]) for i in range(len(samples))],
        dtype=np.uint32,
    )
    group["completed"][region] = np.ones(len(samples), dtype=np.uint8)
