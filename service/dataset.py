"""Reading a store: as an xarray dataset, and sample by sample for training.

`open_dataset` is `xarray.open_zarr` with the small per-sample variables (labels, swept
parameters, completion flags, signal means) loaded eagerly, so that boolean selection and
``groupby`` work without ``.compute()``, and CF attributes typed like their variable.
`SampleDataset` is a map-style dataset in PyTorch's protocol (``__len__``,
``__getitem__``, and ``__getitems__`` for whole batches) returning numpy arrays, without
depending on torch: it reads a sample's chunk straight from its shard file (one ranged
read, the shard's index read once), checks its CRC32C and decompresses it, and opens the
store once per process (so it can be handed to a ``torch.utils.data.DataLoader`` with
worker processes). README, "The dataset".
"""

from __future__ import annotations

import json
import os

import google_crc32c
import numpy as np
import xarray as xr
import zarr
from numcodecs import Blosc, Zstd

from service.integrity import DamagedStoreError
from service.storage import filesystem

__all__ = ["SampleDataset", "open_dataset"]

EMPTY = 2**64 - 1
"""Offset and length of an inner chunk that a shard does not hold (the fill value)."""

SMALL_DIMENSIONS = frozenset({"sample", "frame", "gate"})
"""Variables with only these dimensions are loaded eagerly (bytes per sample: tens)."""
TYPED_ATTRIBUTES = ("flag_values", "valid_min", "valid_max")
"""Attributes that CF wants of the variable's type (zarr's JSON attributes lose it)."""


def open_dataset(url: str, *, storage_options: dict | None = None) -> xr.Dataset:
    """Open a sweep's store (or its statistics) with the small variables in memory.

    Parameters
    ----------
    url : str
        A path or fsspec URL.
    storage_options : dict, optional
        fsspec options (credentials, endpoint).

    Returns
    -------
    xarray.Dataset
        Images and masks lazy (dask, one sample per chunk); every variable whose
        dimensions are among ``sample``, ``frame`` and ``gate`` loaded.
    """
    ds = xr.open_zarr(url, consolidated=True, storage_options=storage_options)
    small = [name for name, v in ds.variables.items() if set(v.dims) <= SMALL_DIMENSIONS]
    loaded = ds[small].load()
    ds = ds.assign(loaded.data_vars).assign_coords(loaded.coords)
    for variable in ds.variables.values():
        for name in TYPED_ATTRIBUTES:
            if name in variable.attrs:
                variable.attrs[name] = np.asarray(variable.attrs[name], dtype=variable.dtype)
    return ds


DECODERS = {"zstd": Zstd, "blosc": Blosc}
"""numcodecs decoders of the inner compressors `service.store` has written (Blosc frames
carry their own settings; zstd before November 2026)."""


def _endian(codec: dict) -> str:
    """The byte order of a ``bytes`` codec entry of zarr.json (absent: single bytes)."""
    return codec.get("configuration", {}).get("endian", "little")


class _Shards:
    """One sharded array of a store, read straight from its shard files.

    The layout is `service.store`'s: shards of consecutive samples along the first axis,
    one sample per inner chunk, inner codecs bytes (little-endian), zstd or Blosc (whose
    frames carry their own settings) and CRC32C, and the shard's index at its end (two
    little-endian uint64 per chunk, then its CRC32C), chunk files named ``c.4.0.0.0.0``.
    Any other layout, which zarr would read but this reader would misread, is refused.
    """

    def __init__(self, fs, root: str, name: str) -> None:
        meta = json.loads(fs.cat_file(f"{root}/{name}/zarr.json"))
        sharding = meta["codecs"][0]
        config = sharding.get("configuration", {})
        codecs = config.get("codecs", [])
        index = config.get("index_codecs", [])
        names = [codec["name"] for codec in (*codecs, *index)]
        keys = meta["chunk_key_encoding"]
        if (
            sharding["name"] != "sharding_indexed"
            or len(codecs) != 3
            or names[1] not in DECODERS
            or names[:1] + names[2:] != ["bytes", "crc32c", "bytes", "crc32c"]
            or _endian(codecs[0]) != "little"
            or _endian(index[0]) != "little"
            or config.get("index_location", "end") != "end"
            or (keys["name"], keys.get("configuration", {}).get("separator")) != ("default", ".")
        ):
            raise ValueError(f"{root}: {name} is not stored in shards as service.store writes")
        self.fs, self.name = fs, name
        self.per_shard = int(meta["chunk_grid"]["configuration"]["chunk_shape"][0])
        self.shape = tuple(config["chunk_shape"][1:])
        self.dtype = np.dtype(meta["data_type"]).newbyteorder("<")
        self.fill = np.asarray(meta["fill_value"]).astype(self.dtype)
        self.key = f"{root}/{name}/c.{{}}" + ".0" * (len(meta["shape"]) - 1)
        self.indexes: dict[int, np.ndarray | None] = {}
        self.codec = DECODERS[names[1]]()

    def _index(self, shard: int) -> np.ndarray | None:
        """The shard's (offset, length) per sample; None if it holds nothing."""
        if shard not in self.indexes:
            size = 16 * self.per_shard + 4
            try:
                tail = self.fs.cat_file(self.key.format(shard), start=-size)
            except FileNotFoundError:
                self.indexes[shard] = None
                return None
            self._check(tail, f"shard {shard}'s index")
            self.indexes[shard] = np.frombuffer(tail[:-4], "<u8").reshape(-1, 2)
        return self.indexes[shard]

    def _check(self, data: bytes, what: str) -> None:
        if google_crc32c.value(data[:-4]) != int.from_bytes(data[-4:], "little"):
            raise DamagedStoreError(
                f"{what} of {self.name} fails its checksum; run the sweep again with "
                "--resume --verify to recompute it"
            )

    def read(self, sample: int) -> np.ndarray:
        """The sample's array (the fill value where it was never written)."""
        shard, position = divmod(int(sample), self.per_shard)
        index = self._index(shard)
        if index is None or index[position, 0] == EMPTY:
            return np.full(self.shape, self.fill, self.dtype)
        offset, length = (int(v) for v in index[position])
        data = self.fs.cat_file(self.key.format(shard), start=offset, end=offset + length)
        self._check(data, f"sample {sample}: its chunk")
        values = np.frombuffer(self.codec.decode(data[:-4]), self.dtype)
        return values.reshape(self.shape)


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

    Notes
    -----
    Item ``i`` is the ``i``-th written sample, `sample_index` maps it to the store's
    ``sample``. An item is a dict of numpy arrays (one per name, without the ``sample``
    dimension) plus ``sample``. Arrays are read-only views of the decompressed chunk. A
    chunk whose CRC32C fails raises `service.integrity.DamagedStoreError` naming it.
    """

    def __init__(
        self,
        url: str,
        *,
        arrays=("image", "target_mask"),
        labels=("target_present", "target_visibility"),
        completed_only: bool = True,
        storage_options: dict | None = None,
    ) -> None:
        self.url = url
        self.storage_options = storage_options
        self.arrays = tuple(arrays)
        group = self._open()
        missing = [name for name in (*self.arrays, *labels) if name not in group]
        if missing:
            known = ", ".join(sorted(group.array_keys()))
            raise KeyError(f"{url} has no {', '.join(missing)}; it has {known}")
        completed = group["completed"][:].astype(bool)
        self.sample_index = (
            np.flatnonzero(completed) if completed_only else np.arange(completed.size)
        )
        self.labels = {name: group[name][:] for name in labels}
        self._shards, self._pid = None, None

    def _open(self):
        return zarr.open_group(
            store=self.url,
            mode="r",
            zarr_format=3,
            use_consolidated=True,
            storage_options=self.storage_options,
        )

    def _readers(self) -> dict[str, _Shards]:
        """The arrays' shard readers, made once per process (a forked worker remakes them)."""
        if self._shards is None or self._pid != os.getpid():
            fs, root = filesystem(self.url, self.storage_options)
            self._shards = {name: _Shards(fs, root, name) for name in self.arrays}
            self._pid = os.getpid()
        return self._shards

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_shards": None, "_pid": None}

    def __len__(self) -> int:
        return int(self.sample_index.size)

    def __getitem__(self, index: int) -> dict[str, np.ndarray]:
        if not -len(self) <= index < len(self):
            raise IndexError(f"item {index} of a dataset of {len(self)} samples")
        return self.__getitems__([index])[0]

    def __getitems__(self, indices) -> list[dict[str, np.ndarray]]:
        """A batch of items (what a ``DataLoader`` with automatic batching asks for)."""
        samples = self.sample_index[np.asarray(indices, dtype=np.int64)]
        readers = self._readers()
        return [
            {
                "sample": np.int64(sample),
                **{name: reader.read(sample) for name, reader in readers.items()},
                **{name: values[sample] for name, values in self.labels.items()},
            }
            for sample in samples
        ]
