"""Samples read back against their checksums, labels against the plan, values checked.

A task writes a sample only if every value is valid (`invalid_values`, by the rules of
`workers.dataset.variables`), then its checksum and its completion flag
(`service.store.shards.write_shard`); `verify` reads completed samples back against both.
The labels and coordinates, written once with the template, are compared with the plan's
(`wrong_labels`) and written again where lost (`repair_labels`).
"""

from __future__ import annotations

import contextlib

import numpy as np

from service.errors import DamagedStoreError, InputError, UnusableOutputError
from service.store.layout import shard_samples
from service.store.location import Store
from service.store.shards import CHECKSUMS, sample_checksum, sample_identity, verified_by
from service.store.template import (
    LABELS_CHECKSUM,
    label_names,
    labels_checksum,
    rendered_shapes,
    template,
)
from service.sweep import Plan, parse_sweep
from workers.dataset.variables import Rule, rendered, rendered_order, variables
from workers.settings.scene import Scene

IMAGE_AXES = ("y", "x")
"""The pixels' coordinates (`workers.dataset.labels.image_axes`, issue #27): a store written
before them has none, and lacks nothing (it resumes without them)."""

__all__ = [
    "check_labels",
    "invalid_values",
    "rebuild_records",
    "repair_labels",
    "stale_layout",
    "stored_plan",
    "unflagged",
    "verify",
    "wrong_labels",
]


def _stored_shards(store: Store, name: str) -> set[int]:
    """Shard indices of the shard files stored in an array's folder (flat keys ``c.K...``)."""
    return {
        int(name.split(".")[1])
        for name in store.files(name)
        if name.startswith("c.") and name.split(".")[1].isdigit()
    }


def _stored(group) -> list[str]:
    """The rendered variables a store holds, in `workers.dataset.variables.rendered_order`."""
    return [name for name in rendered_order() if name in group]


def verify(store: Store) -> list[tuple[int, str]]:
    """The samples marked complete whose chunks are missing, damaged or not theirs.

    Every chunk of every completed sample is read back, a shard at a time (the CRC32C
    codec finds a damaged chunk, and then the shard is read sample by sample to name
    it), and each sample's arrays are compared with the checksum its task recorded
    (`service.store.shards.verified_by`; which finds a chunk deleted, or swapped with
    another sample's, and, where it covers the sample's identity (stores written since
    issue #37, `service.store.shards.BOUND`), a shard's files swapped with another
    shard's, checksums included, or copied from another store). A shard file that is absent
    reads as the fill value: zarr writes no shard whose values all equal it (the masks and
    NaN signal means of a shard of samples without a target), so only a checksum that
    does not match says a sample is damaged or lost; a shard absent then is named.

    Returns
    -------
    list of tuple
        ``(sample, reason)``, by sample index.
    """
    group = store.group()
    names = _stored(group)
    size = shard_samples(group)
    kind, attrs = verified_by(group), group.attrs.asdict()
    shards = {name: _stored_shards(store, name) for name in [*names, kind]}
    done = np.flatnonzero(store.records("completed", group=group))
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
        recorded = store.records(kind, samples, group=group)
        for i, sample in enumerate(samples):
            try:
                values = [a[i] for a in arrays] if arrays else [group[n][sample] for n in names]
            except Exception as error:
                problems.append((sample, f"a chunk cannot be read ({type(error).__name__})"))
                continue
            if sample_checksum(values, kind, sample_identity(attrs, sample)) != int(recorded[i]):
                problems.append((sample, mismatch))
    return problems


def unflagged(store: Store) -> list[int]:
    """The samples whose checksums are stored but whose shard's completion flags are not.

    A task writes a shard, then its samples' checksums, then their completion flags, and
    every write of the flags writes their chunk (`service.store.shards.write_shard`,
    `service.store.location.Store.mark_incomplete`): a chunk of checksums without its chunk
    of flags is a chunk of flags lost (its samples would read as never written: a store
    that shrinks) or a task stopped between the two writes. Either way `--resume`
    renders them again.

    Returns
    -------
    list of int
        The samples with a checksum recorded in those shards, ascending.
    """
    group = store.group()
    size = shard_samples(group)
    lost = sorted(_stored_shards(store, "checksum") - _stored_shards(store, "completed"))
    samples = []
    for shard in lost:
        first = shard * size
        last = min(first + size, group["checksum"].shape[0])
        recorded = store.records("checksum", range(first, last), group=group)
        samples += [first + int(i) for i in np.flatnonzero(recorded)]
    return samples


def rebuild_records(store: Store) -> list[tuple[int, str]]:
    """Write again the chunks of completion flags and checksums that cannot be read.

    A shard's chunk of ``completed`` or of a checksum that is empty, cut short or damaged
    (`service.store.location.Store.records` names it) says nothing of its samples: both
    are written again as "not written" (the damaged file deleted first: zarr would read it
    before writing a chunk at the array's end), so that a resumed run renders the shard's
    samples again and records them afresh. What ``run --resume --verify`` does first.

    Returns
    -------
    list of tuple
        ``(sample, reason)`` for every sample of those shards, by sample index.
    """
    group = store.group("r+")
    names = ["completed", *(kind for kind in CHECKSUMS if kind in group)]
    size, total = shard_samples(group), group["completed"].shape[0]
    lost: dict[int, list[str]] = {}
    for name in names:
        for shard in store.unreadable(group[name]):
            lost.setdefault(shard, []).append(name)
    rebuilt = []
    for shard, which in sorted(lost.items()):
        region = slice(shard * size, min((shard + 1) * size, total))
        for name in names:
            array = group[name].with_config({"write_empty_chunks": True})
            (array.store_path / array.metadata.encode_chunk_key((shard,))).delete_sync()
            array[region] = 0
        reason = f"its {' and '.join(which)} record could not be read (written again)"
        rebuilt += [(sample, reason) for sample in range(region.start, region.stop)]
    return rebuilt


def stored_plan(store: Store) -> tuple[Plan | None, str]:
    """The sweep a samples store holds, read again here, or None and why not.

    Returns
    -------
    plan : Plan or None
        None if its sweep does not load here (a measurement file it names is not here) or
        reads otherwise (a measurement file changed since: another ``sweep_sha256``).
    reason : str
        Why not; empty with a plan.
    """
    attributes = store.attributes() or {}
    try:
        plan = parse_sweep(attributes["sweep"], max_memory=None)
    except InputError as error:
        return None, f"its sweep does not load here: {error}"
    except KeyError:
        return None, "it records no sweep"
    if plan.digest != attributes.get("sweep_sha256"):
        return None, "its sweep reads other files here"
    return plan, ""


def check_labels(store: Store) -> str:
    """Refuse a store whose labels or coordinates are not its sweep's (`wrong_labels`).

    What ``info --verify`` reports, checked before a reader (``stats``, ``detect``,
    `service.dataset.SampleDataset`) reads samples under those labels. A store written
    since issue #37 records the checksum of the labels its template wrote
    (`service.store.template.LABELS_CHECKSUM`): labels that match it pass at the cost of
    reading them (the sweep's labels cost about 15 ms a point to compute again); any
    other, and an older store's, are compared with the sweep's (`wrong_labels`).

    Returns
    -------
    str
        Empty if checked; else why they could not be (`stored_plan`), for the caller to say.

    Raises
    ------
    DamagedStoreError
        Naming the variables lost (``run --resume --verify`` writes them again) or
        differing from what the sweep gives here (edited, or another numpy or scipy
        version: nothing here repairs them).
    """
    group = store.group()
    recorded = group.attrs.get(LABELS_CHECKSUM)
    if recorded is not None:  # one read of each: no sweep to parse, no scene to set up
        with contextlib.suppress(Exception):  # one unreadable: compared below, named
            stored = {name: group[name][...] for name in label_names(group.array_keys())}
            if labels_checksum(stored) == recorded:
                return ""
    plan, reason = stored_plan(store)
    if plan is None:
        return reason
    wrong = wrong_labels(store, plan)
    if lost := [name for name, kind in wrong.items() if kind == "lost"]:
        raise DamagedStoreError(
            f"{store.url}: its {', '.join(lost)} are lost or unreadable (written with the store, "
            "from its sweep); run the sweep again with --resume --verify to write them again"
        )
    if differing := [name for name, kind in wrong.items() if kind == "differs"]:
        raise DamagedStoreError(
            f"{store.url}: its {', '.join(differing)} differ from what its sweep gives (edited, "
            "or written by another numpy or scipy version): its samples would be read under "
            "wrong labels; write the sweep again with --overwrite"
        )
    return ""


def wrong_labels(store: Store, plan: Plan) -> dict[str, str]:
    """The variables that follow from the sweep alone that a store holds wrongly.

    The labels, the platform track and the coordinates (`service.store.template`) are
    written once, with the store, and no sample's checksum covers them: a chunk of one
    lost (read back as the fill value: every ``target_present`` 0) or damaged (its CRC32C
    fails) is found here, by comparing every value with the plan's own (floats within
    1e-12 relative, so that the last bit of another machine's arithmetic is no damage).

    Parameters
    ----------
    store : Store
        The store.
    plan : Plan
        Its sweep.

    Returns
    -------
    dict
        Name: ``"lost"`` (unreadable, absent, or every differing value the fill value: what
        `repair_labels` restores) or ``"differs"`` (readable values this installation
        computes otherwise: another numpy or scipy version drawing a design's points, or
        another layout; never overwritten), in the template's order. Empty: all intact.
    """
    group = store.group()
    return _wrong(group, template(plan, shard_samples(group))[0])


def stale_layout(store: Store, plan: Plan) -> list[str]:
    """The rendered variables a store lacks, or holds in another shape than `plan`'s.

    A store written before a variable was added to `workers.dataset.variables.variables`
    (``target_effect``, ``target_effect_relative``, and ``target_visibility`` per frame,
    issue #24), by the same version number, cannot be resumed: its tasks would write
    samples the store has no room for.

    Returns
    -------
    list of str
        The variables, in `workers.dataset.variables.rendered_order`; empty when the layout is the
        plan's.
    """
    group = store.group()
    return [
        name
        for name, shape in rendered_shapes(plan).items()
        if name not in group or group[name].shape != (plan.samples, *shape)
    ]


def _wrong(group, expected) -> dict[str, str]:
    """`wrong_labels` of the store `group` against its `template` dataset `expected`."""
    wrong = {}
    for name, variable in expected.variables.items():
        if name in (*rendered_order(), "completed", *CHECKSUMS):
            continue
        if name in IMAGE_AXES and name not in group:  # a store written before them
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


def repair_labels(store: Store, plan: Plan) -> list[str]:
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
    UnusableOutputError
        If some differ readably from what this installation computes (nothing changed).
    """
    group = store.group("r+")
    expected, _ = template(plan, shard_samples(group))
    wrong = _wrong(group, expected)
    if differing := [name for name, kind in wrong.items() if kind == "differs"]:
        raise UnusableOutputError(
            f"{store.url}: {', '.join(differing)} differ from what this installation computes for "
            "the sweep (another numpy or scipy version?): resuming would mix the two; "
            "nothing was changed"
        )
    if wrong:
        store.stats.remove(store.stats.removable("statistics"))
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


def invalid_values(sample: dict[str, np.ndarray], scene: Scene) -> str | None:
    """Why a rendered sample may not be stored, or None if every value is valid.

    Each rendered variable keeps its `workers.dataset.variables.Rule`: images, their Monte Carlo
    standard errors and surfaces finite, counts, intensities and errors non-negative,
    counts within their ``valid_max`` (the largest count the store's unsigned type holds),
    and the target mask one of its flags (0 or 1). A sample that breaks any of these is
    never written nor marked complete.

    Parameters
    ----------
    sample : dict
        The sample's arrays by name (`workers.render.render_arrays`).
    scene : Scene
        Its scene (its `workers.dataset.variables.variables` give the rules and ``valid_max``).
    """
    for name, variable in rendered(variables(scene)).items():
        if name not in sample:
            continue
        values, rule = sample[name], variable.rule
        largest = variable.attrs.get("valid_max")
        if largest is not None and values.size and values.max() > largest:
            return (
                f"{name} holds {int(np.count_nonzero(values > largest))} count(s) over "
                f"{largest}, the most its {np.dtype(type(largest)).name} holds (a scene "
                "brighter than workers.dataset.variables.COUNT_HEADROOM allows)"
            )
        finite = rule in (Rule.FINITE, Rule.NON_NEGATIVE)
        if finite and values.dtype.kind == "f" and not np.isfinite(values).all():
            count = int(np.count_nonzero(~np.isfinite(values)))
            return f"{name} holds {count} non-finite value(s) (NaN or inf)"
        if rule is Rule.NON_NEGATIVE and values.dtype.kind != "u" and (values < 0).any():
            return f"{name} holds {int(np.count_nonzero(values < 0))} negative value(s)"
        flags = variable.attrs.get("flag_values")
        if rule is Rule.FLAG and (values > flags.max()).any():
            return f"{name} holds values other than {' and '.join(map(str, flags))}"
    return None
