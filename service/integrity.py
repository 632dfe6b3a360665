"""Samples written and read back whole: completion flags, checksums, valid values, `verify`.

A task writes a sample's chunks only if every value is valid (`invalid_values`), then its
CRC-32 checksum, then its completion flag (`write_samples`); `verify` reads completed
samples back against both, and `read_samples` names the sample whose chunk is damaged.
"""

from __future__ import annotations

import zlib

import numpy as np
import xarray as xr
import zarr

from service.storage import filesystem, list_files, root_attributes
from service.store import RENDERED_VARIABLES, open_group

__all__ = [
    "DamagedStoreError",
    "completed_samples",
    "invalid_values",
    "mark_incomplete",
    "read_samples",
    "sample_checksum",
    "verify",
    "write_samples",
]


def _chunk_samples(fs, folder: str) -> set[int]:
    """Sample indices of the chunks stored in an array's folder (flat keys ``c.S...``)."""
    return {
        int(name.split(".")[1])
        for name in list_files(fs, folder)
        if name.startswith("c.") and name.split(".")[1].isdigit()
    }


def completed_samples(url: str, *, storage_options: dict | None = None) -> np.ndarray:
    """Boolean array: which samples are written.

    A sample's completion flag is a chunk of its own, and a flag of 0 is no chunk at all
    (zarr stores no chunk that holds only the fill value), so the flags are read from one
    listing of the ``completed`` array, not from one read per sample.
    """
    fs, path = filesystem(url, storage_options)
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
    fs, path = filesystem(url, storage_options)
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
