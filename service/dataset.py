"""Reading a store: as an xarray dataset, and sample by sample for training.

`open_dataset` is the way to analyse a store with xarray: the small per-sample variables
(labels, swept parameters, completion flags, signal means) loaded eagerly, so that boolean
selection and ``groupby`` work without ``.compute()``; the large arrays (images, masks)
lazy in dask chunks of one whole shard each, read straight from the shard files
(`service.store.shards.ShardReader.read_shard`: one task per shard, where ``xr.open_zarr``
makes one per sample); ``sample`` indexed by (point, realisation); CF attributes typed
like their variable.
`SampleDataset` is a map-style dataset in PyTorch's protocol (``__len__``,
``__getitem__``, and ``__getitems__`` for whole batches) returning numpy arrays, without
depending on torch: it reads a sample's chunks straight from their shard files (one ranged
read each, the shard's index read once), checks their CRC32C, decompresses them, and checks
the sample as ``info --verify`` does (marked complete, its arrays matching the checksum its
task recorded); it opens the store once per process (so it can be handed to a
``torch.utils.data.DataLoader`` with worker processes). README, "The dataset".
"""

from __future__ import annotations

import os
import warnings

import dask.array as da
import numpy as np
import xarray as xr
from dask.base import tokenize

from service.errors import BadFileError, DamagedStoreError
from service.inputs import position
from service.store.integrity import check_labels, unflagged, verify
from service.store.location import Store, old_gate_numbering
from service.store.shards import (
    CHECKSUMS,
    ShardReader,
    sample_checksum,
    sample_identity,
    verified_by,
)
from workers.dataset.variables import rendered_order

__all__ = ["SampleDataset", "image_type", "open_dataset"]

SMALL_DIMENSIONS = frozenset({"sample", "frame", "gate"})
"""Variables with only these dimensions are loaded eagerly (bytes per sample: tens)."""
TYPED_ATTRIBUTES = ("flag_values", "valid_min", "valid_max")
"""Attributes that CF wants of the variable's type (zarr's JSON attributes lose it)."""


def open_dataset(
    url: str, *, storage_options: dict | None = None, verify: bool = False
) -> xr.Dataset:
    """Open a sweep's store (or its statistics) for analysis: the way to read it with xarray.

    Parameters
    ----------
    url : str
        A path or fsspec URL.
    storage_options : dict, optional
        fsspec options (credentials, endpoint).
    verify : bool, optional
        Read every completed sample of a samples store back first, as ``oceanlidar info
        --verify`` does (`service.store.integrity.verify`: every chunk's CRC32C, each
        sample's arrays against its checksum), and its labels and coordinates; ``completed``
        then reads 0 for every sample that fails (a warning names them; their large arrays
        read as fill values, never decoded), so that ``ds.isel(sample=ds.completed == 1)``
        keeps only the samples intact, and reads. Without it
        (the default: nothing read but the small variables), ``completed`` is the flag
        each task set, and a damaged chunk fails only when its values are computed.

    Returns
    -------
    xarray.Dataset
        Every variable whose dimensions are among ``sample``, ``frame`` and ``gate``
        loaded (numpy). A store's sharded arrays (``image``, ``target_mask``, ...) lazy,
        one dask chunk per shard along ``sample`` (the shard size read from the store's
        metadata), each read whole from its file and every chunk's CRC32C checked. A
        store's ``sample`` is indexed by (``point``, ``realisation``), a pandas MultiIndex:
        ``ds.sel(point=3, realisation=5)`` is one sample, ``ds.sel(point=3)`` a point's
        samples along ``realisation``, ``ds.groupby("point")`` groups by point,
        ``ds.unstack("sample")`` lays the samples out on (point, realisation). netCDF
        holds no MultiIndex: ``ds.reset_index("sample").to_netcdf(path)``.
    """
    store = Store(url, storage_options)
    group = store.group()
    ds = store.dataset(dask=False)
    small = [name for name, v in ds.variables.items() if set(v.dims) <= SMALL_DIMENSIONS]
    # the per-sample records read through `Store.records`: a damaged file is named
    records = [name for name in ("completed", *CHECKSUMS) if name in small and name in ds]
    loaded = ds[[name for name in small if name not in records]].load()
    loaded = loaded.assign({name: ds[name].copy(data=store.records(name)) for name in records})
    damaged = frozenset()
    if verify and store.kind() == "samples":
        flags, damaged = _verified(store)
        loaded["completed"] = loaded["completed"].copy(data=flags)
    ds = ds.assign(loaded.data_vars).assign_coords(loaded.coords)
    large = {
        name: _lazy(store, group, v, damaged)
        for name, v in ds.data_vars.items()
        if name not in small
    }
    ds = ds.assign(large)
    if "sample" in ds.dims and {"point", "realisation"} <= set(ds.coords):
        ds = ds.set_index(sample=["point", "realisation"])
    for name in ds.dims:
        if name in ds.variables:  # CF: a coordinate variable has no _FillValue (netCDF's)
            ds.variables[name].encoding["_FillValue"] = None
    for variable in ds.variables.values():
        for name in TYPED_ATTRIBUTES:
            if name in variable.attrs:
                variable.attrs[name] = np.asarray(variable.attrs[name], dtype=variable.dtype)
    return ds


def _verified(store: Store) -> tuple[np.ndarray, frozenset[int]]:
    """A samples store's completion flags, 0 for the samples `verify` finds damaged; those.

    Its labels and coordinates are checked too (`service.store.integrity.check_labels`).
    """
    if reason := check_labels(store):
        warnings.warn(f"{store.url}: labels and coordinates not checked ({reason})", stacklevel=3)
    flags = store.records("completed").copy()
    if lost := unflagged(store):
        warnings.warn(
            f"{store.url}: samples {_listed(lost)} hold checksums but their completion flags "
            "are lost (or a run stopped while writing them): completed reads 0 for them; run "
            "the sweep again with --resume --verify to recompute them",
            stacklevel=3,
        )
    damaged = [sample for sample, _ in verify(store)]
    if damaged:
        flags[damaged] = 0
        warnings.warn(
            f"{store.url}: samples {_listed(damaged)} marked complete fail their checks: "
            "completed reads 0 for them (`oceanlidar info --verify` says why); run the sweep "
            "again with --resume --verify to recompute them",
            stacklevel=3,
        )
    return flags, frozenset(damaged)


def _lazy(store: Store, group, variable: xr.DataArray, damaged=frozenset()) -> xr.DataArray:
    """A large variable as a dask array: a sharded one in chunks of one shard each.

    Read whole by `service.store.shards.ShardReader.read_shard`, one task per shard (the
    `damaged` samples, whose ``completed`` reads 0, not decoded: fill values); an array in
    a layout that reader does not know by zarr, in chunks of a shard; an array without
    shards (the statistics' images) in its zarr chunks.
    """
    name = str(variable.name)
    chunks = dict(variable.encoding["preferred_chunks"])
    shards = group[name].shards
    if shards is None:
        return variable.chunk(chunks)
    try:
        reader = ShardReader(store, name)
    except ValueError:  # not service.store.layout's: zarr reads it
        return variable.chunk({**chunks, "sample": shards[0]})
    samples = variable.shape[0]
    blocks = tuple(
        min(reader.per_shard, samples - first) for first in range(0, samples, reader.per_shard)
    )
    data = da.map_blocks(
        _read_block,
        chunks=(blocks, *((size,) for size in variable.shape[1:])),
        dtype=reader.dtype,
        meta=np.empty((0,) * variable.ndim, reader.dtype),
        name=f"read-{name}-{tokenize(store.url, name, variable.shape, sorted(damaged))}",
        reader=reader,
        blocks=blocks,
        damaged=damaged,
    )
    return variable.copy(data=data)


def _read_block(
    *, reader: ShardReader, blocks: tuple[int, ...], damaged: frozenset, block_id
) -> np.ndarray:
    """Dask chunk `block_id` of `reader`'s array: its whole shard, `damaged` samples skipped."""
    shard = block_id[0]
    return reader.read_shard(shard, blocks[shard], damaged)


class SampleDataset:
    """The samples of a store, one by one or in batches, as numpy arrays: for training.

    A map-style dataset in PyTorch's protocol without depending on torch: pass it to
    ``torch.utils.data.DataLoader`` as it is (``num_workers`` > 0 works: each worker
    process opens the store for itself), or index it directly.

    Parameters
    ----------
    url : str
        The store: a path or fsspec URL.
    arrays : sequence of str, optional
        Per-sample arrays read from the shards at each access (``image``,
        ``target_mask``, ``expected`` if stored, ``expected_stderr`` of a Monte Carlo
        sweep, ``surface_elevation`` if saved).
    labels : sequence of str, optional
        Per-sample variables held in memory from the start (read once): labels,
        signal means, swept parameters by their variable names (``target_depth``).
    completed_only : bool, optional
        Index only the samples written (the default); otherwise every sample, and those
        not written read as fill values.
    storage_options : dict, optional
        fsspec options.
    image_dtype : numpy dtype, optional
        The type ``image`` is returned in, converted after the sample is checked (e.g.
        ``np.float32``: exact for counts up to 2²⁴; torch's ``mean`` and ``max`` refuse the
        ``uint32`` of 128-pixel ML(DC) stores). Default: as stored (``valid_max`` says its
        range), the narrowest unsigned type holding the counts, or float32.

    Notes
    -----
    Item ``i`` is the ``i``-th written sample, `sample_index` maps it to the store's
    ``sample``. An item is a dict of numpy arrays (one per name, without the ``sample``
    dimension) plus ``sample``. Every array is writable and the item's own (the chunk
    decompressed into it, a label copied), so a ``DataLoader``'s default collate takes it
    without a warning and changing it changes nothing else.

    Each sample returned is checked as ``oceanlidar info --verify`` checks it: every chunk's
    CRC32C, and every rendered array the store holds (those not asked for too: the
    checksum covers them all) against the checksum its task recorded (CRC32C, or CRC-32 in a
    store written before issue #26: `service.store.shards.verified_by`), which finds a shard
    file lost (read as fill values), copied over another's, or with chunks swapped inside
    it. A sample that fails, or is no longer marked complete, raises
    `service.errors.DamagedStoreError` naming it; so does opening a store that has lost
    the completion flags of samples it holds (`service.store.integrity.unflagged`), which
    would otherwise drop out of the index. With ``completed_only=False`` the samples not
    marked complete are returned unchecked (fill values, or a partial write's).
    """

    def __init__(
        self,
        url: str,
        *,
        arrays=("image", "target_mask"),
        labels=("target_present", "target_visibility"),
        completed_only: bool = True,
        storage_options: dict | None = None,
        image_dtype=None,
    ) -> None:
        self.store = Store(url, storage_options)
        self.arrays = tuple(arrays)
        group = self.store.group()
        missing = [name for name in (*self.arrays, *labels) if name not in group]
        if missing:
            known = ", ".join(sorted(group.array_keys()))
            raise KeyError(f"{url} has no {', '.join(missing)}; it has {known}")
        image = group.get("image")
        self.image_dtype = (
            None
            if image_dtype is None
            else image_type(image_dtype, stored=image.dtype, largest=image.attrs.get("valid_max"))
        )
        if "gate" in group and (problem := old_gate_numbering(group["gate"][:], url)):
            raise BadFileError(problem)
        if lost := unflagged(self.store):
            raise DamagedStoreError(
                f"{url}: samples {_listed(lost)} hold checksums but their completion flags are "
                "lost (or a run stopped while writing them); run the sweep again with --resume "
                "--verify to recompute them"
            )
        if reason := check_labels(self.store):
            warnings.warn(f"{url}: labels and coordinates not checked ({reason})", stacklevel=2)
        self.checked = tuple(name for name in rendered_order() if name in group)
        self.checksum = verified_by(group)
        self.attributes = group.attrs.asdict()
        self.completed_only = completed_only
        completed = self.store.completed()
        self.sample_index = (
            np.flatnonzero(completed) if completed_only else np.arange(completed.size)
        )
        self.labels = {name: group[name][:] for name in labels}
        self._shards, self._pid = None, None

    def _readers(self) -> dict[str, ShardReader]:
        """The arrays' shard readers, made once per process (a forked worker remakes them)."""
        if self._shards is None or self._pid != os.getpid():
            store = self.store.other(self.store.url)  # its file system made in this process
            names = {*self.arrays, *self.checked, self.checksum, "completed"}
            self._shards = {name: ShardReader(store, name) for name in names}
            self._pid = os.getpid()
        return self._shards

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_shards": None, "_pid": None}

    def __len__(self) -> int:
        return int(self.sample_index.size)

    def __getitem__(self, index: int) -> dict[str, np.ndarray]:
        return self.__getitems__([index])[0]

    def __getitems__(self, indices) -> list[dict[str, np.ndarray]]:
        """A batch of items (what a ``DataLoader`` with automatic batching asks for).

        Raises
        ------
        TypeError
            For an index that is not an integer (``1.5``, ``True``: `service.inputs.position`).
        IndexError
            For one outside ``-len(self)..len(self) - 1``.
        """
        picked = [position(index, "a SampleDataset index") for index in indices]
        if outside := [index for index in picked if not -len(self) <= index < len(self)]:
            raise IndexError(f"item {outside[0]} of a dataset of {len(self)} samples")
        samples = self.sample_index[np.asarray(picked, dtype=np.int64)]
        return [
            {
                "sample": np.int64(sample),
                **self._arrays(int(sample)),
                **{name: _own(values[sample]) for name, values in self.labels.items()},
            }
            for sample in samples
        ]

    def _arrays(self, sample: int) -> dict[str, np.ndarray]:
        """The sample's arrays asked for, checked (`DamagedStoreError` naming it)."""
        readers = self._readers()
        read = {name: readers[name].read(sample) for name in {*self.checked, *self.arrays}}
        flagged = bool(readers["completed"].read(sample))
        if self.completed_only and not flagged:
            raise DamagedStoreError(
                f"sample {sample}: no longer marked complete in {self.store.url} (a run "
                "recomputing it, or its flags lost); open the dataset again once it is"
            )
        identity = sample_identity(self.attributes, sample)
        checksum = sample_checksum([read[name] for name in self.checked], self.checksum, identity)
        if flagged and checksum != readers[self.checksum].read(sample):
            raise DamagedStoreError(
                f"sample {sample}: its arrays do not match its checksum (a shard file lost, "
                "or another's); run the sweep again with --resume --verify to recompute it"
            )
        if self.image_dtype is not None and "image" in self.arrays:
            read["image"] = read["image"].astype(self.image_dtype)
        return {name: read[name] for name in self.arrays}


def image_type(asked, *, stored: np.dtype, largest=None) -> np.dtype:
    """The type `asked` for a store's images, if it holds every value they can hold.

    Parameters
    ----------
    asked : numpy dtype
        The reader's ``image_dtype``.
    stored : numpy dtype
        The store's (or sweep's) image type.
    largest : int, optional
        The largest count it holds (its ``valid_max``); default the most `stored` holds.

    Raises
    ------
    ValueError
        Naming ``image_dtype``: a type that is not a number, an integer type for images
        that are not counts (it would truncate them), or one whose largest value is below
        `largest` (``uint8`` would wrap a count of 3434 to 106). Float types
        round counts beyond their mantissa (float32: 2²⁴) but never wrap.
    """
    dtype = np.dtype(asked)
    if dtype.kind not in "uif":
        raise ValueError(f"image_dtype {dtype}: not an integer or float type")
    if stored.kind == "f" and dtype.kind != "f":
        raise ValueError(
            f"image_dtype {dtype}: the images are {stored} (not counts): an integer type "
            "would truncate them; ask for a float type"
        )
    if stored.kind == "f" and largest is None:
        return dtype
    top = np.iinfo(stored).max if largest is None else int(largest)
    most = int(np.iinfo(dtype).max) if dtype.kind in "ui" else float(np.finfo(dtype).max)
    if most < top:
        raise ValueError(
            f"image_dtype {dtype}: holds values up to {most}, and the images counts up to "
            f"{top} (their valid_max): it would wrap them; ask for {stored} or float32"
        )
    return dtype


def _own(value):
    """A label's value for an item: a copy of an array (not a view of the labels held)."""
    return value.copy() if isinstance(value, np.ndarray) else value


def _listed(samples: list[int]) -> str:
    """Samples named briefly: the first few, then a count."""
    more = f" and {len(samples) - 3} more" if len(samples) > 3 else ""
    return ", ".join(map(str, samples[:3])) + more
