"""Samples written and read back whole: completion flags, checksums, valid values, `verify`.

A task writes a sample only if every value is valid (`invalid_values`): its shard's chunks,
then its CRC-32 checksum, then its completion flag (`write_shard`); `verify` reads
completed samples back against both, and `read_samples` names the sample whose chunk is
damaged.
"""

from __future__ import annotations

import zlib

import numpy as np
import zarr

from service.inputs import SweepError
from service.storage import filesystem, list_files, removable_files, remove_files, stats_url
from service.store import RENDERED_VARIABLES, open_group, shard_samples, template

__all__ = [
    "DamagedStoreError",
    "completed_samples",
    "invalid_values",
    "mark_incomplete",
    "read_samples",
    "repair_labels",
    "sample_checksum",
    "stale_layout",
    "verify",
    "write_shard",
    "wrong_labels",
]


def _stored_shards(fs, folder: str) -> set[int]:
    """Shard indices of the shard files stored in an array's folder (flat keys ``c.K...``)."""
    return {
        int(name.split(".")[1])
        for name in list_files(fs, folder)
        if name.startswith("c.") and name.split(".")[1].isdigit()
    }


def completed_samples(url: str, *, storage_options: dict | None = None) -> np.ndarray:
    """Boolean array: which samples are written.

    The flags have one chunk per shard: one read per shard, whatever its samples.
    """
    group = zarr.open_group(
        store=url, mode="r", zarr_format=3, use_consolidated=True, storage_options=storage_options
    )
    return group["completed"][:].astype(bool)


def sample_checksum(arrays: list[np.ndarray]) -> int:
    """CRC-32 of a sample's rendered arrays, in `RENDERED_VARIABLES` order."""
    crc = 0
    for values in arrays:
        crc = zlib.crc32(np.ascontiguousarray(values), crc)
    return crc


def _stored(group) -> list[str]:
    """The rendered variables a store holds, in `RENDERED_VARIABLES` order."""
    return [name for name in RENDERED_VARIABLES if name in group]


def verify(url: str, storage_options: dict | None = None) -> list[tuple[int, str]]:
    """The samples marked complete whose chunks are missing, damaged or not theirs.

    Every chunk of every completed sample is read back, a shard at a time (the CRC32C
    codec finds a damaged chunk, and then the shard is read sample by sample to name
    it), and each sample's arrays are compared with the checksum its task recorded (which
    finds a chunk deleted, or swapped with another sample's). A shard file that is absent
    reads as the fill value: zarr writes no shard whose values all equal it (the masks and
    NaN signal means of a shard of samples without a target), so only a checksum that
    does not match says a sample is damaged or lost; a shard absent then is named.

    Returns
    -------
    list of tuple
        ``(sample, reason)``, by sample index.
    """
    fs, path = filesystem(url, storage_options)
    group = zarr.open_group(
        store=url, mode="r", zarr_format=3, use_consolidated=True, storage_options=storage_options
    )
    names = _stored(group)
    size = shard_samples(group)
    shards = {name: _stored_shards(fs, f"{path}/{name}") for name in [*names, "checksum"]}
    done = np.flatnonzero(group["completed"][:])
    problems = []
    for shard in np.unique(done // size):
        samples = [int(s) for s in done[done // size == shard]]
        missing = [name for name, stored in shards.items() if shard not in stored]
        mismatch = (
            f"no {' or '.join(missing)} shard"
            if missing
            else "its chunks do not match its checksum"
        )
        try:
            arrays = [group[name].get_orthogonal_selection((samples,)) for name in names]
        except Exception:
            arrays = None  # a damaged chunk: read its samples one by one below
        recorded = group["checksum"].get_orthogonal_selection((samples,))
        for i, sample in enumerate(samples):
            try:
                values = [a[i] for a in arrays] if arrays else [group[n][sample] for n in names]
            except Exception as error:
                problems.append((sample, f"a chunk cannot be read ({type(error).__name__})"))
                continue
            if sample_checksum(values) != int(recorded[i]):
                problems.append((sample, mismatch))
    return problems


def wrong_labels(url: str, plan, storage_options: dict | None = None) -> dict[str, str]:
    """The variables that follow from the sweep alone that a store holds wrongly.

    The labels, the platform track and the coordinates (`service.store.template`) are
    written once, with the store, and no sample's checksum covers them: a chunk of one
    lost (read back as the fill value: every ``target_present`` 0) or damaged (its CRC32C
    fails) is found here, by comparing every value with the plan's own (floats within
    1e-12 relative, so that the last bit of another machine's arithmetic is no damage).

    Parameters
    ----------
    url : str
        The store.
    plan : service.sweep.Plan
        Its sweep.

    Returns
    -------
    dict
        Name: ``"lost"`` (unreadable, absent, or every differing value the fill value: what
        `repair_labels` restores) or ``"differs"`` (readable values this installation
        computes otherwise: another numpy or scipy version drawing a design's points, or
        another layout; never overwritten), in the template's order. Empty: all intact.
    """
    group = zarr.open_group(
        store=url, mode="r", zarr_format=3, use_consolidated=True, storage_options=storage_options
    )
    return _wrong(group, template(plan, shard_samples(group))[0])


def stale_layout(url: str, plan, storage_options: dict | None = None) -> list[str]:
    """The rendered variables a store lacks, or holds in another shape than `plan`'s.

    A store written before a variable was added to `workers.labels.rendered_variables`
    (``target_effect``, ``target_effect_relative``, and ``target_visibility`` per frame,
    issue #24), by the same version number, cannot be resumed: its tasks would write
    samples the store has no room for.

    Returns
    -------
    list of str
        The variables, in `RENDERED_VARIABLES` order; empty when the layout is the plan's.
    """
    group = zarr.open_group(
        store=url, mode="r", zarr_format=3, use_consolidated=True, storage_options=storage_options
    )
    expected, _ = template(plan, shard_samples(group))
    return [
        name
        for name in RENDERED_VARIABLES
        if name in expected and (name not in group or group[name].shape != expected[name].shape)
    ]


def _wrong(group, expected) -> dict[str, str]:
    """`wrong_labels` of the store `group` against its `template` dataset `expected`."""
    wrong = {}
    for name, variable in expected.variables.items():
        if name in (*RENDERED_VARIABLES, "completed", "checksum"):
            continue
        try:
            array = group[name]
            stored = array[...]
        except Exception:  # absent, or a chunk that cannot be read
            wrong[str(name)] = "lost"
            continue
        if (kind := _compare(stored, variable.values, array.fill_value)) is not None:
            wrong[str(name)] = kind
    return wrong


def repair_labels(url: str, plan, storage_options: dict | None = None) -> list[str]:
    """Write the labels and coordinates `wrong_labels` finds lost again, from the plan.

    The statistics beside the store (computed with those labels; the caller has checked
    they are this store's, `service.stats.check_owner`) are deleted first, so that any
    later run computes them all again, even if this one is interrupted.

    Returns
    -------
    list of str
        The variables written again.

    Raises
    ------
    SweepError
        If some differ readably from what this installation computes (nothing changed).
    """
    group = open_group(url, storage_options)
    expected, _ = template(plan, shard_samples(group))
    wrong = _wrong(group, expected)
    if differing := [name for name, kind in wrong.items() if kind == "differs"]:
        raise SweepError(
            f"{url}: {', '.join(differing)} differ from what this installation computes for "
            "the sweep (another numpy or scipy version?): resuming would mix the two; "
            "nothing was changed"
        )
    if wrong:
        stats = stats_url(url)
        remove_files(
            stats, storage_options, removable_files(stats, storage_options, kind="statistics")
        )
        for name in wrong:
            group[name][...] = expected[name].values
    return list(wrong)


def _compare(stored: np.ndarray, values: np.ndarray, fill) -> str | None:
    """None if stored values equal the template's, else ``"lost"`` or ``"differs"``."""
    if stored.shape != values.shape:
        return "differs"
    if {"O", "U", "T"} & {stored.dtype.kind, values.dtype.kind}:
        stored, values = (
            np.array([str(v) for v in a.ravel()], dtype=object) for a in (stored, values)
        )
        wrong = stored != values
        filled = stored == str(fill if fill is not None else "")
    elif values.dtype.kind in "fc":
        wrong = ~np.isclose(stored, values, rtol=1e-12, atol=0.0, equal_nan=True)
        filled = (stored == fill) | (np.isnan(stored) & np.isnan(np.float64(fill)))
    else:
        wrong = stored != values
        filled = stored == fill
    if not wrong.any():
        return None
    return "lost" if filled[wrong].all() else "differs"


def mark_incomplete(url: str, samples: list[int], storage_options: dict | None = None) -> None:
    """Clear the completion flags of `samples`, so that a resumed run renders them again."""
    if samples:
        open_group(url, storage_options)["completed"].set_orthogonal_selection((samples,), 0)


NON_NEGATIVE = ("image", "expected", "expected_stderr")
"""Rendered variables that are counts, intensities or their errors: never below zero."""
FINITE = ("image", "expected", "expected_stderr", "surface_elevation")
"""Rendered variables that must be finite (the signal means are NaN without a target)."""


def invalid_values(sample: dict[str, np.ndarray], table: dict) -> str | None:
    """Why a rendered sample may not be stored, or None if every value is valid.

    Images, their Monte Carlo standard errors and surfaces must be finite, counts,
    intensities and errors non-negative, counts within their ``valid_max`` (the largest
    count the store's unsigned type holds), and the target mask 0 or 1: a sample that
    breaks any of these is never written nor marked complete.

    Parameters
    ----------
    sample : dict
        The sample's arrays by name (`workers.render.render_arrays`).
    table : dict
        Its scene's `workers.labels.rendered_variables` (the attributes: ``valid_max``).
    """
    for name in RENDERED_VARIABLES:
        if name not in sample:
            continue
        values = sample[name]
        largest = table[name][2].get("valid_max")
        if largest is not None and values.size and values.max() > largest:
            return (
                f"{name} holds {int(np.count_nonzero(values > largest))} count(s) over "
                f"{largest}, the most its {np.dtype(type(largest)).name} holds (a scene "
                "brighter than workers.labels.COUNT_HEADROOM allows)"
            )
        if name in FINITE and values.dtype.kind == "f" and not np.isfinite(values).all():
            count = int(np.count_nonzero(~np.isfinite(values)))
            return f"{name} holds {count} non-finite value(s) (NaN or inf)"
        if name in NON_NEGATIVE and values.dtype.kind != "u" and (values < 0).any():
            return f"{name} holds {int(np.count_nonzero(values < 0))} negative value(s)"
        if name == "target_mask" and (values > 1).any():
            return "target_mask holds values other than 0 and 1"
    return None


ZERO_WHEN_ABSENT = frozenset({"expected_stderr"})
"""Rendered variables a store may hold that a sample's renderer does not give: written as 0.
A sweep that varies ``transport.method`` stores ``expected_stderr`` for every sample
(`service.store.variable_table`); the small-angle renderer is deterministic, its error 0."""


class DamagedStoreError(RuntimeError):
    """A chunk of a store cannot be read back: the message names the sample."""


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


def write_shard(group, samples: dict[int, dict[str, np.ndarray]]) -> None:
    """Write the whole shard that holds `samples`, then mark them complete.

    `samples` maps each sample to its rendered arrays by name (one of `ZERO_WHEN_ABSENT`
    that a sample lacks, a small-angle sample's ``expected_stderr``, is written as 0). The
    shard's other samples already complete are read back and written again with the new
    ones (their bytes do not change); the rest stay at the fill value and incomplete.
    The caller owns the shard: no other task writes it meanwhile (`service.run`). Writes
    go straight to the zarr arrays the template created, one call per variable, each
    array opened once: xarray's region writes, and every lookup of an array in the group,
    read the store's metadata again, which costs more than compressing a small sample.
    Chunks holding only the fill value are written too (zarr's default compares every
    chunk, and the whole shard, with the fill value first: about 0.3 ms a 128-pixel
    sample); the values read back are the same either way.
    """
    names = (*RENDERED_VARIABLES, "checksum", "completed")
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
