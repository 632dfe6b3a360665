"""The store's layout: shards sized by bytes, one sample per chunk, and the codecs.

Samples are grouped in shards of consecutive samples (zarr v3 sharding), one file per
shard and array; inside a shard, one sample per chunk, so that reading one sample stays
one small read (`sharded`). The small per-sample arrays (the completion records, the
signal means, the target's effect and visibility) have one chunk per shard (`per_shard`).
Every chunk carries a CRC32C checksum. The shard size depends on the sweep alone
(`shard_size`), never on the cluster.
"""

from __future__ import annotations

import dask.array as da
import numpy as np
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec

from service.sweep import Plan

__all__ = [
    "CODECS",
    "CONVENTIONS",
    "COUNT_CODECS",
    "FLOAT_CODECS",
    "MAX_SHARD_SAMPLES",
    "MIN_SHARDS",
    "SHARD_BYTES",
    "lazy_array",
    "one_per_chunk",
    "per_shard",
    "shard_samples",
    "shard_size",
    "sharded",
]

SHARD_BYTES = 16 * 2**20
"""Uncompressed bytes a shard (and a task) aims at, unless ``--batch`` says otherwise
(`shard_size`; a sample larger than this is a shard of its own): large enough that a task's
fixed costs (opening the store, zarr's calls, dask's handling, some 20 ms) are a small share
of its rendering, small enough that a task's samples sit in a worker's memory at once."""
MIN_SHARDS = 8
"""Shards a sweep of at least that many samples is split into, at least (`shard_size`), so
that small sweeps still spread over the workers."""
MAX_SHARD_SAMPLES = 256
"""Most samples a shard holds by default (`shard_size`): tiny samples would otherwise make
a few huge tasks, few in flight at once, and a failed one reruns its samples one by one."""

FLAT_CHUNK_KEYS = {"name": "default", "separator": "."}
"""Chunk files named c.4.0.0.0.0 in the array's folder: one file per chunk, no folders to
create (each folder costs as much as a small file on the file systems measured)."""
CONVENTIONS = "CF-1.10"
CODECS = (ZstdCodec(), Crc32cCodec())
"""Compression, then a CRC32C checksum of every chunk: a damaged chunk fails to decode
instead of reading as other numbers."""
COUNT_CODECS = (BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle"), Crc32cCodec())
"""The same for the sharded unsigned arrays (counts, masks): LZ4 after a bit shuffle (Blosc,
a codec of the zarr v3 core specification). On 128-pixel six-gate uint32 counts it writes
ten times faster than zstd, reads three times faster, and takes a quarter fewer bytes:
the high bits of small counts, shuffled together, are long runs of zeros."""
FLOAT_CODECS = (BloscCodec(cname="zstd", clevel=3, shuffle="shuffle"), Crc32cCodec())
"""The same for the sharded float arrays (`expected`, the saved surface): zstd after a byte
shuffle, 15 % fewer bytes than zstd alone on a 257² surface and on 128-pixel images (the
float mantissas' low bytes are noise either way), decoded twice as fast."""


def lazy_array(shape: tuple, fill, dtype, *, multiple: int = 1) -> da.Array:
    """A dask array standing for data the template does not write (few, large chunks).

    The zarr chunking comes from the encoding: a dask graph with one chunk per sample
    would grow with the sweep (10⁶ samples: gigabytes in the client). Dask chunks hold a
    whole number of `multiple` leading indices (a shard).
    """
    rows = min(shape[0], max(multiple, 65536 // multiple * multiple))
    return da.full(shape, fill, dtype=dtype, chunks=(rows, *shape[1:]))


def one_per_chunk(shape: tuple, compressors: tuple = CODECS) -> dict:
    """Zarr encoding: one leading index (sample or point) per chunk, flat keys, checksums."""
    return {
        "chunks": (1, *shape),
        "chunk_key_encoding": FLAT_CHUNK_KEYS,
        "compressors": compressors,
    }


def sharded(shape: tuple, samples: int, dtype: np.dtype) -> dict:
    """Zarr encoding: shards of `samples` leading indices, one index per chunk inside.

    Unsigned arrays (counts, masks) are compressed by `COUNT_CODECS`, floats by
    `FLOAT_CODECS`.
    """
    compressors = COUNT_CODECS if np.dtype(dtype).kind == "u" else FLOAT_CODECS
    return {**one_per_chunk(shape, compressors), "shards": (samples, *shape)}


def per_shard(shape: tuple, samples: int) -> dict:
    """Zarr encoding: one chunk per shard of `samples` leading indices (small arrays)."""
    return {**one_per_chunk(shape), "chunks": (samples, *shape)}


def shard_size(plan: Plan, batch: int | None = None) -> int:
    """Samples per shard (and per task) of a new store of `plan`.

    `batch` if given (``--batch``); otherwise as many samples as fit in `SHARD_BYTES`
    uncompressed, at most `MAX_SHARD_SAMPLES`, but few enough to leave `MIN_SHARDS` shards,
    and at least one. The choice depends on the sweep alone, never on the cluster: the
    store's layout is the same on any number of workers. 128-pixel six-gate samples: 40 a
    shard; 512-pixel: 2.
    """
    if batch is not None:
        return batch
    by_bytes = min(SHARD_BYTES // plan.sample_bytes(), MAX_SHARD_SAMPLES)
    return max(1, min(by_bytes, plan.samples // MIN_SHARDS))


def shard_samples(group) -> int:
    """Samples per shard of a store's zarr group (`service.store.location.Store.group`)."""
    return int(group["completed"].chunks[0])
