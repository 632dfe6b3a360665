"""Whole shards: written with their checksums and completion flags, read back chunk by chunk.

A task writes a whole shard (`write_shard`): the shard's complete samples read back and
written again with its new ones, then their CRC-32 checksums (`sample_checksum`), then
their completion flags. `read_samples` reads samples back and names the one whose chunk is
damaged; `ShardReader` reads one sample's chunk straight from its shard file (one ranged
read, the shard's index read once), for training readers (`service.dataset`).
"""

from __future__ import annotations

import json
import zlib

import google_crc32c
import numpy as np
from numcodecs import Blosc, Zstd

from service.errors import DamagedStoreError
from service.store.location import Store
from workers.variables import rendered_order

__all__ = [
    "ZERO_WHEN_ABSENT",
    "ShardReader",
    "read_samples",
    "read_verified",
    "sample_checksum",
    "write_shard",
]

EMPTY = 2**64 - 1
"""Offset and length of an inner chunk that a shard does not hold (the fill value)."""

ZERO_WHEN_ABSENT = frozenset({"expected_stderr"})
"""Rendered variables a store may hold that a sample's renderer does not give: written as 0.
A sweep that varies ``transport.method`` stores ``expected_stderr`` for every sample
(`service.store.template.store_variables`); the small-angle renderer is deterministic,
its error 0."""


def sample_checksum(arrays: list[np.ndarray]) -> int:
    """CRC-32 of a sample's rendered arrays, in `workers.variables.rendered_order`."""
    crc = 0
    for values in arrays:
        crc = zlib.crc32(np.ascontiguousarray(values), crc)
    return crc


def read_samples(array, samples: list[int]) -> np.ndarray:
    """The chunks of `samples` (ascending) from a one-sample-per-chunk array.

    Consecutive samples are read as one slice (zarr's orthogonal selection costs several
    times more per sharded chunk).

    Raises
    ------
    DamagedStoreError
        Naming the first sample whose chunk fails to decode (a checksum that does not
        match, truncated or foreign bytes).
    """
    first = samples[0] if len(samples) else 0
    try:
        if list(samples) == list(range(first, first + len(samples))):
            return array[first : first + len(samples)]
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


def read_verified(group, samples: list[int]) -> dict[str, np.ndarray]:
    """Every rendered array of `samples` (ascending, marked complete), checked.

    Each sample's arrays are compared with the checksum its task recorded, as
    `service.store.integrity.verify` compares them: a shard file lost (read back as the
    fill value), copied over another, or with chunks swapped inside it fails as a chunk
    that cannot be decoded does.

    Parameters
    ----------
    group : zarr.Group
        The store's (`service.store.location.Store.group`).
    samples : list of int
        Samples marked complete, ascending.

    Returns
    -------
    dict
        Name: array of the samples' values, for every rendered variable the store holds,
        in `workers.variables.rendered_order`.

    Raises
    ------
    DamagedStoreError
        Naming the first sample whose chunk cannot be read or whose arrays do not match its
        checksum.
    """
    names = [name for name in rendered_order() if name in group]
    read = {name: read_samples(group[name], samples) for name in names}
    recorded = read_samples(group["checksum"], samples)
    for i, sample in enumerate(samples):
        if sample_checksum([read[name][i] for name in names]) != int(recorded[i]):
            raise DamagedStoreError(
                f"sample {sample}: its chunks do not match its checksum (a shard lost, or "
                "another's); run the sweep again with --resume --verify to recompute it"
            )
    return read


def write_shard(group, samples: dict[int, dict[str, np.ndarray]]) -> None:
    """Write the whole shard that holds `samples`, then mark them complete.

    `samples` maps each sample to its rendered arrays by name (one of `ZERO_WHEN_ABSENT`
    that a sample lacks, a small-angle sample's ``expected_stderr``, is written as 0). The
    shard's other samples already complete are read back and written again with the new
    ones (their bytes do not change); the rest stay at the fill value and incomplete.
    `group` is the store's, opened to write (`service.store.location.Store.group`). The
    caller owns the shard: no other task writes it meanwhile (`service.run`). Writes
    go straight to the zarr arrays the template created, one call per variable, each
    array opened once: xarray's region writes, and every lookup of an array in the group,
    read the store's metadata again, which costs more than compressing a small sample.
    Chunks holding only the fill value are written too (zarr's default compares every
    chunk, and the whole shard, with the fill value first: about 0.3 ms a 128-pixel
    sample); the values read back are the same either way.
    """
    names = (*rendered_order(), "checksum", "completed")
    arrays = {
        name: array.with_config({"write_empty_chunks": True})
        for name in names
        if (array := group.get(name)) is not None
    }
    completed, stored = arrays.pop("completed"), arrays.pop("checksum")
    size = int(completed.chunks[0])
    first = min(samples) // size * size
    region = slice(first, min(first + size, completed.shape[0]))
    done = completed[region].astype(bool)
    kept = [first + int(i) for i in np.flatnonzero(done) if first + int(i) not in samples]
    blocks = {}
    for name, array in arrays.items():
        block = np.full((region.stop - first, *array.shape[1:]), array.fill_value, array.dtype)
        if kept:
            block[[k - first for k in kept]] = read_samples(array, kept)
        for sample, rendered in samples.items():
            zero = name in ZERO_WHEN_ABSENT
            block[sample - first] = rendered.get(name, 0) if zero else rendered[name]
        blocks[name] = block
    checksums = stored[region]
    for sample in samples:
        checksums[sample - first] = sample_checksum([b[sample - first] for b in blocks.values()])
    for name, block in blocks.items():
        arrays[name][region] = block
    stored[region] = checksums
    done[[s - first for s in samples]] = True
    completed[region] = done.astype(np.uint8)


DECODERS = {"zstd": Zstd, "blosc": Blosc}
"""numcodecs decoders of the inner compressors `service.store.layout` has written (Blosc frames
carry their own settings; zstd before November 2026)."""


def _endian(codec: dict) -> str:
    """The byte order of a ``bytes`` codec entry of zarr.json (absent: single bytes)."""
    return codec.get("configuration", {}).get("endian", "little")


class ShardReader:
    """One sharded array of a store, read straight from its shard files.

    The layout is `service.store.layout`'s: shards of consecutive samples along the first
    axis, one sample per inner chunk, inner codecs bytes (little-endian), zstd or Blosc
    (whose frames carry their own settings) and CRC32C, and the shard's index at its end
    (two little-endian uint64 per chunk, then its CRC32C), chunk files named
    ``c.4.0.0.0.0``. Any other layout, which zarr would read but this reader would
    misread, is refused.

    Parameters
    ----------
    store : Store
        The store.
    name : str
        The array.
    """

    def __init__(self, store: Store, name: str) -> None:
        fs, root = store.fs, store.path
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
            raise ValueError(
                f"{root}: {name} is not stored in shards as service.store.layout writes"
            )
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
