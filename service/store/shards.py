"""Whole shards: written with their checksums and completion flags, read back chunk by chunk.

A task writes a whole shard (`write_shard`): the shard's complete samples read back and
written again with its new ones, then their CRC-32 checksums (`sample_checksum`), then
their completion flags. `read_samples` reads samples back and names the one whose chunk is
damaged, `read_verified` checks them against their checksums too; `ShardReader` reads one
sample's chunk straight from its shard file (one ranged read, the shard's index read once),
for training readers, or a whole shard at once, for xarray's (`service.dataset`).
"""

from __future__ import annotations

import json
import zlib

import google_crc32c
import numpy as np
from numcodecs import Blosc, Zstd

from service.errors import DamagedStoreError
from service.store.location import Store, chunk_file
from workers.dataset.variables import rendered_order

__all__ = [
    "BOUND",
    "CHECKSUMS",
    "ZERO_WHEN_ABSENT",
    "ShardReader",
    "checks_identity",
    "read_samples",
    "read_verified",
    "sample_checksum",
    "sample_identity",
    "verified_by",
    "write_shard",
]

EMPTY = 2**64 - 1
"""Offset and length of an inner chunk that a shard does not hold (the fill value)."""

ZERO_WHEN_ABSENT = frozenset({"expected_stderr"})
"""Rendered variables a store may hold that a sample's renderer does not give: written as 0.
A sweep that varies ``transport.method`` stores ``expected_stderr`` for every sample
(`service.store.template.store_variables`); the small-angle renderer is deterministic,
its error 0."""


CHECKSUMS = {
    "checksum": lambda crc, values: zlib.crc32(values, crc),
    "checksum_crc32c": google_crc32c.extend,
    "checksum_bound": google_crc32c.extend,
}
"""A sample's checksums by the array that records them: CRC-32 of its rendered arrays
(every store), CRC32C of them (stores written from issue #26 to #37: the same check,
computed in hardware, 12 times faster here, 2.3 against 28 GB/s), and CRC32C of the
sample's identity (`sample_identity`) followed by its rendered arrays (stores written
since issue #37: what `verified_by` chooses where it is recorded)."""

BOUND = frozenset({"checksum_bound"})
"""The checksums that cover which sample the arrays are (`sample_identity`), not only
their bytes: a shard's files swapped with another shard's, checksums included, or copied
from a store of another seed or sweep, fail them."""


VERIFIED_BY = ("checksum_bound", "checksum_crc32c", "checksum")
"""The checksums a store's samples are checked against, the first it records (`verified_by`)."""


def sample_identity(attrs, sample: int) -> bytes:
    """Which sample `sample` of the store whose root attributes are `attrs` is, as bytes.

    The sample's index, point and realisation, and the store's sweep (``sweep_sha256``,
    the hash of the sweep with its seed) and ``seed``: what a `BOUND` checksum covers
    before the sample's arrays.
    """
    point, realisation = divmod(int(sample), int(attrs["realisations"]))
    return (
        f"oceanlidar sample {int(sample)} point {point} realisation {realisation} "
        f"sweep {attrs['sweep_sha256']} seed {attrs['seed']}"
    ).encode()


def sample_checksum(
    arrays: list[np.ndarray], kind: str = "checksum", identity: bytes = b""
) -> int:
    """The `kind` checksum (`CHECKSUMS`) of a sample's arrays (`rendered_order`'s order).

    `identity` (`sample_identity`) comes first in a `BOUND` checksum; the others ignore it.
    """
    extend = CHECKSUMS[kind]
    crc = extend(0, identity) if kind in BOUND else 0
    for values in arrays:
        crc = extend(crc, np.ascontiguousarray(values))
    return crc


def verified_by(group) -> str:
    """The checksum a store's samples are checked against: the most it records.

    The `BOUND` one (stores written since issue #37), else CRC32C (since issue #26), else
    CRC-32.
    """
    return next(kind for kind in VERIFIED_BY if kind in group)


def checks_identity(group) -> bool:
    """Whether a store's checksums find a sample's arrays at another sample's place.

    Stores written before issue #37 record checksums of the arrays alone: a shard's files
    swapped with another's, checksums included, pass them.
    """
    return verified_by(group) in BOUND


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
                reason = f"{type(error).__name__}: {str(error)[:120].rstrip('.')}"
                raise DamagedStoreError(
                    f"sample {sample}: its {array.basename} chunk cannot be read ({reason}; "
                    f"file {chunk_file(array, sample)}); run the sweep again with --resume "
                    "--verify to recompute it"
                ) from None
        raise


def read_verified(group, samples: list[int]) -> dict[str, np.ndarray]:
    """Every rendered array of `samples` (ascending, marked complete), checked.

    Each sample's arrays are compared with the checksum its task recorded, as
    `service.store.integrity.verify` compares them: a shard file lost (read back as the
    fill value), copied over another, or with chunks swapped inside it fails as a chunk
    that cannot be decoded does; where the checksums are `BOUND` (stores written since
    issue #37), so do a shard's files swapped with another shard's, checksums included,
    and a shard copied from another store.

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
        in `workers.dataset.variables.rendered_order`.

    Raises
    ------
    DamagedStoreError
        Naming the first sample whose chunk cannot be read or whose arrays do not match its
        checksum.
    """
    names = [name for name in rendered_order() if name in group]
    read = {name: read_samples(group[name], samples) for name in names}
    kind, attrs = verified_by(group), group.attrs.asdict()
    recorded = read_samples(group[kind], samples)
    for i, sample in enumerate(samples):
        values = [read[name][i] for name in names]
        if sample_checksum(values, kind, sample_identity(attrs, sample)) != int(recorded[i]):
            raise DamagedStoreError(
                f"sample {sample}: its chunks do not match its checksum (a shard lost, or "
                "another sample's or store's); run the sweep again with --resume --verify to "
                "recompute it"
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
    names = (*rendered_order(), *CHECKSUMS, "completed")
    arrays = {
        name: array.with_config({"write_empty_chunks": True})
        for name in names
        if (array := group.get(name)) is not None
    }
    completed = arrays.pop("completed")
    stored = {kind: arrays.pop(kind) for kind in CHECKSUMS if kind in arrays}  # CRC32C: new
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
    checksums = {kind: array[region] for kind, array in stored.items()}
    attrs = group.attrs.asdict()
    for sample in samples:
        values = [block[sample - first] for block in blocks.values()]
        identity = sample_identity(attrs, sample)
        for kind, recorded in checksums.items():
            recorded[sample - first] = sample_checksum(values, kind, identity)
    for name, block in blocks.items():
        _write_whole(arrays[name], region, block)
    for kind, array in stored.items():
        array[region] = checksums[kind]
    done[[s - first for s in samples]] = True
    completed[region] = done.astype(np.uint8)


def _write_whole(array, region: slice, block: np.ndarray) -> None:
    """Write `block` over the samples `region` of `array`, a whole shard (or chunk).

    Zarr reads a shard's old file before writing it, even when the write covers all of
    it; a shard whose index is damaged (a truncated or overwritten file) fails that read
    on every attempt. `block` holds everything the shard keeps, so the damaged file is
    removed and the shard written afresh.
    """
    try:
        array[region] = block
    except ValueError:  # the old shard's index does not decode: CRC32C or size
        if array.shards is None:
            raise
        shard = (region.start // array.shards[0],) + (0,) * (array.ndim - 1)
        (array.store_path / array.metadata.encode_chunk_key(shard)).delete_sync()
        array[region] = block


DECODERS = {"zstd": Zstd, "blosc": Blosc}
"""numcodecs decoders of the inner compressors `service.store.layout` has written (Blosc frames
carry their own settings; zstd before November 2026)."""


def _endian(codec: dict) -> str:
    """The byte order of a ``bytes`` codec entry of zarr.json (absent: single bytes)."""
    return codec.get("configuration", {}).get("endian", "little")


class ShardReader:
    """One per-sample array of a store, read straight from its files.

    The layouts are `service.store.layout`'s, samples along the first axis: a sharded array
    (shards of consecutive samples, one sample per inner chunk, the shard's index at its
    end: two little-endian uint64 per chunk, then its CRC32C), or a small array with one
    chunk per shard (the completion flags, checksums, signal means), read whole once and
    kept. Codecs: bytes (little-endian), zstd or Blosc (whose frames carry their own
    settings), CRC32C; chunk files named ``c.4.0.0.0.0``. Any other layout, which zarr
    would read but this reader would misread, is refused.

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
        outer = meta["codecs"][0]
        self.sharded = outer["name"] == "sharding_indexed"
        config = outer.get("configuration", {}) if self.sharded else {}
        codecs = config.get("codecs", []) if self.sharded else meta["codecs"]
        index = config.get("index_codecs", []) if self.sharded else []
        names = [codec["name"] for codec in (*codecs, *index)]
        keys = meta["chunk_key_encoding"]
        tail = ["bytes", "crc32c", "bytes", "crc32c"] if self.sharded else ["bytes", "crc32c"]
        if (
            len(codecs) != 3
            or names[1] not in DECODERS
            or names[:1] + names[2:] != tail
            or _endian(codecs[0]) != "little"
            or (self.sharded and _endian(index[0]) != "little")
            or config.get("index_location", "end") != "end"
            or (keys["name"], keys.get("configuration", {}).get("separator")) != ("default", ".")
        ):
            shards = "in shards " if self.sharded else ""
            raise ValueError(
                f"{root}: {name} is not stored {shards}as service.store.layout writes"
            )
        self.fs, self.name = fs, name
        self.per_shard = int(meta["chunk_grid"]["configuration"]["chunk_shape"][0])
        self.shape = tuple(config["chunk_shape"][1:] if self.sharded else meta["shape"][1:])
        self.dtype = np.dtype(meta["data_type"]).newbyteorder("<")
        self.fill = np.asarray(meta["fill_value"]).astype(self.dtype)
        self.key = f"{root}/{name}/c.{{}}" + ".0" * (len(meta["shape"]) - 1)
        self.indexes: dict[int, np.ndarray | None] = {}
        self.codec = DECODERS[names[1]]()

    def _index(self, shard: int) -> np.ndarray | None:
        """What is kept of a shard, read once: None if its file is absent.

        A sharded array's (offset, length) per sample; a small array's values.
        """
        if shard not in self.indexes:
            size = 16 * self.per_shard + 4
            try:
                if self.sharded:
                    data = self.fs.cat_file(self.key.format(shard), start=-size)
                else:
                    data = self.fs.cat_file(self.key.format(shard))
            except FileNotFoundError:
                self.indexes[shard] = None
                return None
            if self.sharded:
                self.indexes[shard] = self._shard_index(data, shard)
            else:
                what = f"samples {shard * self.per_shard}+: their chunk"
                self._check(data, what, shard)
                try:
                    values = np.frombuffer(self.codec.decode(data[:-4]), self.dtype)
                    self.indexes[shard] = values.reshape(-1, *self.shape)
                except (RuntimeError, ValueError):  # a chunk of other bytes
                    self._refuse(what, shard)
        return self.indexes[shard]

    def _shard_index(self, data: bytes, shard: int) -> np.ndarray:
        """Shard `shard`'s index, checked: (offset, length) per sample.

        `data` is the shard file or its tail.
        """
        tail = data[-(16 * self.per_shard + 4) :]
        if len(tail) < 16 * self.per_shard + 4:  # cut short: no whole index
            self._refuse(f"shard {shard}'s index", shard)
        self._check(tail, f"shard {shard}'s index", shard)
        return np.frombuffer(tail[:-4], "<u8").reshape(-1, 2)

    def _check(self, data: bytes, what: str, shard: int) -> None:
        """Refuse `data` (bytes of shard `shard`'s file, then their CRC32C) if damaged."""
        if len(data) < 4 or google_crc32c.value(data[:-4]) != int.from_bytes(data[-4:], "little"):
            self._refuse(what, shard)

    def _refuse(self, what: str, shard: int):
        """`DamagedStoreError`: `what` of this array, in shard `shard`'s file, is damaged."""
        raise DamagedStoreError(
            f"{what} of {self.name} fails its checksum (file {self.key.format(shard)}, empty, "
            "cut short or damaged); run the sweep again with --resume --verify to recompute it"
        )

    def read(self, sample: int) -> np.ndarray:
        """The sample's array (the fill value where it was never written), writable, its own.

        A chunk is decompressed into a new array (no read-only view of the decompressed
        bytes); a small array's values are copied from what is kept of its shard.
        """
        shard, position = divmod(int(sample), self.per_shard)
        index = self._index(shard)
        if index is None or (self.sharded and index[position, 0] == EMPTY):
            return np.full(self.shape, self.fill, self.dtype)
        if not self.sharded:
            return index[position].copy()
        offset, length = (int(v) for v in index[position])
        data = self.fs.cat_file(self.key.format(shard), start=offset, end=offset + length)
        return self._decoded(data, sample)

    def read_shard(self, shard: int, samples: int, skip=frozenset()) -> np.ndarray:
        """The first `samples` samples of a sharded array's shard `shard`, decoded.

        The shard file is read whole, once (its index not kept); fill values where a sample
        was never written, and for the samples in `skip` (known damaged: never decoded):
        what a dask chunk of a shard reads (`service.dataset.open_dataset`).
        """
        values = np.full((samples, *self.shape), self.fill, self.dtype)
        first = shard * self.per_shard
        if set(range(first, first + samples)) <= skip:
            return values
        try:
            data = self.fs.cat_file(self.key.format(shard))
        except FileNotFoundError:
            return values
        index = self._shard_index(data, shard)
        for position, (offset, length) in enumerate(index[:samples].tolist()):
            if offset != EMPTY and first + position not in skip:
                chunk = data[offset : offset + length]
                values[position] = self._decoded(chunk, first + position)
        return values

    def _decoded(self, data: bytes, sample: int) -> np.ndarray:
        """A sample's chunk (its bytes with their CRC32C) checked and decompressed."""
        shard = sample // self.per_shard
        self._check(data, f"sample {sample}: its chunk", shard)
        values = np.empty(self.shape, self.dtype)
        try:
            self.codec.decode(data[:-4], out=values)
        except (RuntimeError, ValueError):  # CRC32C passed, other bytes (written so)
            self._refuse(f"sample {sample}: its chunk", shard)
        return values
