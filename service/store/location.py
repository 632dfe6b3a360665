"""A store where it lives: `Store`, a zarr store at a URL and the fsspec options to reach it.

Every dataset the service writes or reads (samples, statistics, detection) is a `Store`:
its file system and path, its zarr group (`Store.group`, the one way the service opens
one) and its dataset (`Store.dataset`), its siblings (statistics and detection beside it),
its writer's lock (`Store.lock`, `service.store.lock`) and the samples' completion flags.
`Store.errors` turns a failure to reach or write storage into an
`service.errors.UnusableOutputError` naming the URL. Deletion is refused unless every file
is one the store's own metadata lists (`Store.removable`).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field

import fsspec
import numpy as np
import xarray as xr
import zarr

from service.errors import BadFileError, BadOptionError, DamagedStoreError, UnusableOutputError
from service.inputs import shown
from service.store.lock import LEGACY_LOCK_NAME, check_workers_see, writer_lock

__all__ = ["KIND", "Store", "chunk_file", "consolidated_v3", "old_gate_numbering"]

KIND = "oceanlidar_dataset"
"""Root attribute naming what a store holds: ``samples`` (a sweep), ``statistics`` or
``detection``."""


def old_gate_numbering(gates: np.ndarray, url: str) -> str | None:
    """Why a dataset whose ``gate`` coordinate is `gates` cannot be read or resumed, or None.

    Until issue #27 the ``gate`` coordinate held positions from 0 where every picture and
    the README count gates from 1 (the ML(DC) cameras 1–6); a store written then would mix
    the two numberings with the statistics or detection datasets written now. It is
    refused, never renumbered behind the user's back: the message gives the remedy (README,
    "The dataset").
    """
    if gates.size == 0 or int(gates[0]) != 0:
        return None
    return (
        f"{url} numbers its gates from 0, as oceanlidar did before issue #27; gates are now "
        "numbered from 1 (the ML(DC) cameras 1–6): renumber it in place (add 1 to its "
        "'gate' array and to those of its statistics and detection datasets: README, 'The "
        "dataset') or write the sweep again with --overwrite"
    )


def chunk_file(array, sample: int) -> str:
    """The file of a zarr `array` (samples along its first axis) that holds `sample`.

    Its shard's file, or its chunk's in an array without shards; a local store's as a path.
    """
    size = int((array.shards or array.chunks)[0])
    key = array.metadata.encode_chunk_key((sample // size,) + (0,) * (array.ndim - 1))
    return f"{str(array.store_path).removeprefix('file://')}/{key}"


@contextlib.contextmanager
def consolidated_v3():
    """Write consolidated metadata to a zarr v3 store without zarr's standing warning.

    zarr-python warns that consolidated metadata is not yet part of the v3 specification;
    we keep it because opening a store then costs one read (it matters on object storage),
    and zarr-python, which we pin, reads it.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
        yield


def _storage_failures() -> tuple[type[BaseException], ...]:
    """`OSError`, and what S3 clients raise untranslated (an unreachable endpoint)."""
    try:
        from botocore.exceptions import BotoCoreError
    except ImportError:  # no S3 support installed: fsspec raises OSError alone
        return (OSError,)
    return (OSError, BotoCoreError)


@dataclass(frozen=True)
class Store:
    """A zarr store at a path or fsspec URL, with the options that reach it.

    Built once from the command line's ``--output`` (or a store argument) and
    ``--storage-options`` (`Store.at`), then passed down: to the dask workers as it is
    (it pickles as its URL and options; each process makes its own file system).

    Attributes
    ----------
    url : str
        A path or fsspec URL (`Store.at` makes a local path absolute).
    storage_options : dict or None
        fsspec options (credentials, endpoint).
    """

    url: str
    storage_options: dict | None = field(default=None, hash=False)

    @classmethod
    def at(cls, url: str, storage_options: dict | None = None) -> Store:
        """The store at `url` as every process reads it: a local path absolute, ``~`` expanded.

        ``file://`` URLs become paths. A path is resolved here, in the runner, because zarr
        on the workers neither expands ``~`` nor shares the runner's working directory.

        Raises
        ------
        BadOptionError
            For storage options given with a local path (they apply to URLs only).
        """
        url = str(url)
        protocol, path = fsspec.core.split_protocol(url)
        if protocol not in (None, "file", "local"):
            return cls(url, storage_options)
        if storage_options:
            raise BadOptionError(
                f"--storage-options apply to URLs such as s3://bucket/run.zarr, not to the "
                f"local path {shown(url)}"
            )
        return cls(os.path.abspath(os.path.expanduser(path)))

    def __getstate__(self) -> dict:
        """Its URL and options: the file system is made again where it is unpickled."""
        return {"url": self.url, "storage_options": self.storage_options}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

    def other(self, url: str) -> Store:
        """The store at `url` on the same storage (the same options)."""
        return Store(url, self.storage_options)

    @functools.cached_property
    def _located(self) -> tuple:
        try:
            return fsspec.core.url_to_fs(self.url, **(self.storage_options or {}))
        except (TypeError, ValueError, ImportError) as error:
            raise BadOptionError(
                f"{self.url}: cannot open with these storage options ({error})"
            ) from None

    @property
    def fs(self):
        """The fsspec file system (`BadOptionError` if the options do not fit it)."""
        return self._located[0]

    @property
    def path(self) -> str:
        """The store's path on `fs`."""
        return self._located[1]

    @property
    def local(self) -> bool:
        """Whether the store is on a local file system (renames, folders)."""
        return "file" in self.fs.protocol

    @property
    def name(self) -> str:
        """The store's name in its folder: the last component of its URL."""
        return self.url.rstrip("/").rsplit("/", 1)[-1]

    def sibling(self, kind: str) -> Store:
        """The `kind` dataset of this store: beside it, ``NAME.KIND.zarr``."""
        stem = self.url.rstrip("/")
        if stem.endswith(".zarr"):
            stem = stem[: -len(".zarr")]
        return self.other(f"{stem}.{kind}.zarr")

    @property
    def stats(self) -> Store:
        """Where the statistics of this store live (beside it)."""
        return self.sibling("stats")

    def partial(self, suffix: str) -> Store:
        """A fresh store beside this one, to write into before it is moved here."""
        return self.other(f"{self.url.rstrip('/')}.partial-{suffix}")

    @contextlib.contextmanager
    def errors(self):
        """Turn a failure to reach or write storage into an `UnusableOutputError`.

        ``FileExistsError`` passes through: the writer's lock tells it from a failure.
        """
        try:
            yield
        except FileExistsError:
            raise
        except _storage_failures() as error:
            reason = getattr(error, "strerror", None) or str(error) or type(error).__name__
            raise UnusableOutputError(
                f"{shown(self.url)} cannot be written: {reason[:200]}"
            ) from None

    def exists(self) -> bool:
        """Whether anything is stored at the URL."""
        return self.fs.exists(self.path)

    def files(self, folder: str = "") -> list[str]:
        """Every file of the store (or of a `folder` in it), relative to it or to `folder`.

        A file at the URL (or at `folder`) itself is named '.'.
        """
        return sorted(self._walk(f"{self.path}/{folder}" if folder else self.path))

    def _walk(self, path: str) -> Iterator[str]:
        """The files under `path`, relative to it, one folder listed at a time.

        A caller that stops early stops the walk: `occupied` and `removable` look no
        further than the first file that decides (``output: /`` is not listed whole).
        """
        if not self.fs.isdir(path):
            if self.fs.exists(path):  # a file, or a device, a pipe...
                yield "."
            return
        root = path.rstrip("/") + "/"
        for folder, _, names in self.fs.walk(path):
            for name in names:
                full = f"{folder.rstrip('/')}/{name}"
                if full.startswith(root):
                    yield full[len(root) :]

    def occupied(self) -> bool:
        """Whether the store holds anything besides an older version's writer's lock.

        The first file tells (`service.store.lock.LEGACY_LOCK_NAME`: a run of this version
        keeps its lock beside the store).
        """
        return any(name != LEGACY_LOCK_NAME for name in self._walk(self.path))

    def special(self) -> bool:
        """Whether something that is neither a folder nor a regular file is at the URL."""
        if not self.local or not self.exists():
            return False
        return self.fs.info(self.path)["type"] not in ("directory", "file")

    def _metadata(self) -> dict | None:
        """The root group's ``zarr.json``; None if there is no readable group."""
        try:
            metadata = json.loads(self.fs.cat_file(f"{self.path}/zarr.json"))
        except (OSError, ValueError):
            return None
        if not isinstance(metadata, dict) or metadata.get("node_type") != "group":
            return None
        return metadata

    def attributes(self) -> dict | None:
        """The attributes of the zarr group; None if there is no readable group."""
        attributes = (self._metadata() or {}).get("attributes")
        return attributes if isinstance(attributes, dict) else None

    def kind(self) -> str | None:
        """What the store holds (its `KIND` attribute): ``samples``, ``statistics``..."""
        return (self.attributes() or {}).get(KIND)

    def _consolidated(self) -> dict:
        """The arrays the root group's consolidated metadata lists (empty: none listed)."""
        return ((self._metadata() or {}).get("consolidated_metadata") or {}).get("metadata") or {}

    def finished(self) -> bool:
        """Whether the group's metadata was consolidated.

        A write that stopped before leaves it unconsolidated (a run stopped while writing
        its template): a resume refuses such a store, ``--overwrite`` replaces it.
        """
        return bool(self._consolidated())

    def _arrays_written(self) -> list[str]:
        """The arrays of an unconsolidated group: its folders holding an array's ``zarr.json``."""
        names = []
        for entry in self.fs.ls(self.path, detail=False):
            name = entry.rstrip("/").rsplit("/", 1)[-1]
            try:
                metadata = json.loads(self.fs.cat_file(f"{self.path}/{name}/zarr.json"))
            except (OSError, ValueError):
                continue
            if isinstance(metadata, dict) and metadata.get("node_type") == "array":
                names.append(name)
        return names

    def removable(self, kind: str) -> list[str]:
        """The files of the `kind` dataset here, which may be deleted to replace it.

        Only what the store's own metadata lists may go: its group and array metadata, and
        chunk keys of the arrays that its consolidated metadata names (of a template whose
        write stopped before its metadata was consolidated, the arrays whose own metadata
        was written). Anything else in the
        folder (a user's file, a store of another kind) refuses the whole deletion, before
        anything is deleted.

        Parameters
        ----------
        kind : {'samples', 'statistics', 'detection'}
            What the store must hold (its `KIND` attribute).

        Returns
        -------
        list of str
            Paths relative to the store, an older version's writer's lock excluded; empty
            if nothing is there.

        Raises
        ------
        UnusableOutputError
            If something is there that is not such a store, or holds files it does not list.
        """
        if not self.occupied():
            return []
        attributes = self.attributes() or {}
        if KIND not in attributes and "oceanlidar_version" in attributes:
            raise UnusableOutputError(
                f"{self.url} was written by oceanlidar {shown(attributes['oceanlidar_version'])}, "
                "which did not record what a store holds; refusing to delete it (delete it by "
                "hand if it is yours to replace)"
            )
        if attributes.get(KIND) != kind:
            raise UnusableOutputError(
                f"{self.url} exists and is not an oceanlidar {kind} store; refusing to delete it"
            )
        arrays = self._consolidated() or self._arrays_written()
        listed = re.compile(
            r"zarr\.json|(?:"
            + "|".join(re.escape(name) for name in arrays)
            + r")/(?:zarr\.json|c(?:[./]\d+)*)"
        )
        files = []
        for name in self._walk(self.path):  # stopped at the first file not listed
            if not listed.fullmatch(name) and name != LEGACY_LOCK_NAME:
                raise UnusableOutputError(
                    f"{self.url} holds {shown(name)}, which the store's metadata does "
                    "not list; refusing to delete it (move that file away first)"
                )
            if name != LEGACY_LOCK_NAME:
                files.append(name)
        return sorted(files)

    def remove(self, files: list[str]) -> None:
        """Delete `files` (from `removable`) of the store, and the folders they empty.

        Those folders are every folder above a file up to the store's own: nested chunk
        keys (``auc/c/0/1``) leave ``auc/c/0``, then ``auc/c`` and ``auc`` empty.
        """
        if not files:
            return
        self.fs.rm([f"{self.path}/{name}" for name in files])
        if self.local:
            folders = {self.path}
            for name in files:
                while name := os.path.dirname(name):
                    folders.add(f"{self.path}/{name}")
            for folder in sorted(folders, key=len, reverse=True):
                with contextlib.suppress(OSError):  # not empty: a folder above
                    os.rmdir(folder)

    def move_to(self, target: Store) -> None:
        """Move the store to `target` (same file system; nothing may be there).

        On a file system this is one rename. Object storage has no rename: objects are
        copied, the group's metadata last (until it lands, nothing reads as a store at
        `target`), then deleted here.
        """
        if self.local:
            os.rename(self.path, target.path)
            return
        names = sorted(self.files(), key=lambda name: name == "zarr.json")
        self.fs.copy(
            [f"{self.path}/{name}" for name in names], [f"{target.path}/{name}" for name in names]
        )
        self.fs.rm([f"{self.path}/{name}" for name in names])

    def group(self, mode: str = "r") -> zarr.Group:
        """The store's zarr group: the one way the service opens it.

        ``r`` reads it from its consolidated metadata; ``r+`` writes whole chunks into the
        arrays the template created (their own metadata: region writes never touch it).
        """
        return zarr.open_group(
            store=self.url,
            mode=mode,
            zarr_format=3,
            use_consolidated=mode == "r",
            storage_options=self.storage_options,
        )

    def dataset(self, *, dask: bool = True) -> xr.Dataset:
        """The store as an xarray dataset, lazily.

        Dask, one chunk per zarr chunk; with ``dask=False``, xarray's lazily indexed
        arrays (one zarr call reads a whole array: what `service.dataset.open_dataset`
        loads its small arrays from and chunks its large ones by).

        Raises
        ------
        BadFileError
            If its gates are numbered from 0 (`old_gate_numbering`).
        """
        ds = xr.open_zarr(
            self.url,
            consolidated=True,
            storage_options=self.storage_options,
            **({} if dask else {"chunks": None}),
        )
        if "gate" in ds.coords and (problem := old_gate_numbering(ds["gate"].values, self.url)):
            raise BadFileError(problem)
        return ds

    def write(self, ds: xr.Dataset, *, mode: str, compute: bool = True, encoding=None) -> None:
        """Write `ds` as a zarr v3 store here, its metadata consolidated."""
        with consolidated_v3():
            ds.to_zarr(
                self.url,
                mode=mode,
                compute=compute,
                consolidated=True,
                zarr_format=3,
                encoding=encoding,
                storage_options=self.storage_options,
            )

    def update_attributes(self, **attributes) -> None:
        """Set the group's `attributes` in place and consolidate its metadata again."""
        group = self.group("r+")
        group.attrs.update(attributes)
        with consolidated_v3():
            zarr.consolidate_metadata(group.store, zarr_format=3)

    def lock(self, *, claim: str | None = None):
        """Hold the store's writer lock (`service.store.lock.writer_lock`); yields its token."""
        return writer_lock(self, claim=claim)

    def check_workers_see(self, token: str) -> None:
        """Check, on a worker, that it sees the lock (`service.store.lock.check_workers_see`)."""
        check_workers_see(self, token)

    def completed(self, samples=None) -> np.ndarray:
        """Boolean array: which samples are written (of `samples` alone, if given).

        The flags have one chunk per shard: one read per shard, whatever its samples;
        `samples` (indices, ascending) reads only the shards that hold them.

        Raises
        ------
        DamagedStoreError
            Naming a file of flags that cannot be read (`records`).
        """
        return self.records("completed", samples).astype(bool)

    def records(self, name: str, samples=None, *, group=None) -> np.ndarray:
        """A per-sample record (``completed``, a checksum) of every sample, or of `samples`.

        `samples`: indices, ascending (only the chunks that hold them are read); `group`:
        the store's, if already open (`group`).

        Raises
        ------
        DamagedStoreError
            Naming the record's files that cannot be read (empty, cut short, damaged: their
            CRC32C fails) and the remedy: ``run --resume --verify`` writes them again
            (`service.store.integrity.rebuild_records`).
        """
        array = (group or self.group())[name]
        if samples is not None:
            samples = np.asarray(samples, dtype=int)
            if not samples.size:
                return np.zeros(0, array.dtype)
        try:
            return array[:] if samples is None else array.get_orthogonal_selection((samples,))
        except Exception as error:
            size = int(array.chunks[0])
            files = [chunk_file(array, chunk * size) for chunk in self.unreadable(array)]
            raise DamagedStoreError(
                f"{', '.join(files) or chunk_file(array, 0)}: cannot be read (empty, cut short "
                f"or damaged: {type(error).__name__}); run the sweep again with --resume --verify "
                "to write it again (the samples it records are rendered again)"
            ) from None

    @staticmethod
    def unreadable(array) -> list[int]:
        """The chunks (along the samples, one a shard) of a zarr `array` that cannot be read."""
        size, total = int(array.chunks[0]), array.shape[0]
        bad = []
        for chunk, first in enumerate(range(0, total, size)):
            try:
                array[first : first + size]
            except Exception:
                bad.append(chunk)
        return bad

    def completed_after(self, before: np.ndarray) -> np.ndarray:
        """The completion flags after a run that found `before` (`completed`).

        Only a run's tasks write flags, each those of its own shard, and the run holds the
        store's writer lock: the flags of shards that held no missing sample are still
        `before`'s; only the others' are read again (one read a shard).
        """
        size = int(self.group()["completed"].chunks[0])  # one chunk a shard
        shards = np.unique(np.flatnonzero(~before) // size)
        samples = (shards[:, np.newaxis] * size + np.arange(size)).ravel()
        samples = samples[samples < before.size]
        after = before.copy()
        after[samples] = self.completed(samples)
        return after

    def mark_incomplete(self, samples: list[int]) -> None:
        """Clear the completion flags of `samples`, so that a resumed run renders them again.

        Their chunk is written even if every flag in it is cleared: a chunk of flags is
        absent only where no sample of its shard was ever written
        (`service.store.integrity.unflagged`).
        """
        if samples:
            flags = self.group("r+")["completed"].with_config({"write_empty_chunks": True})
            flags.set_orthogonal_selection((samples,), 0)
