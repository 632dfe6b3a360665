"""Nothing lost, nothing silently wrong: refusals before deletion, locks, checksums."""

import errno
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from conftest import TINY_SCENE, TINY_SWEEP, batch_of, on_cluster, start_cli, store_lock

import service.tasks
from service.admission import enclosing_store
from service.cli import main
from service.store import integrity, lock, shards
from service.store.location import KIND, Store
from service.store.template import create_store
from workers.dataset.variables import rendered_order
from workers.render import render_arrays


def sweep_file(folder, name="one", output="one.zarr", seed=3):
    path = folder / f"{name}.yaml"
    path.write_text(TINY_SCENE.format(name=name, seed=seed, realisations=5, output=output))
    return path


def snapshot(folder):
    """Every file under `folder` and its bytes."""
    return {
        p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


PER_SHARD = 2
"""Samples per shard of the `finished` store: shards [0, 1], [2, 3], [4]."""


@pytest.fixture(scope="module")
def finished(tmp_path_factory, session_cluster):
    """A folder with a complete five-sample store `one.zarr` and its statistics."""
    folder = tmp_path_factory.mktemp("finished")
    sweep = sweep_file(folder)
    with on_cluster(session_cluster), pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        assert main(["run", str(sweep), "--workers", "1", "--batch", str(PER_SHARD)]) == 0
    return folder


@pytest.fixture
def work(finished, tmp_path_factory, monkeypatch):
    """A copy of `finished` to damage, as the current directory.

    Its path is short: messages cut at 500 characters quote it several times (under
    pytest-xdist, tmp_path is longer).
    """
    folder = tmp_path_factory.mktemp("work")
    shutil.copytree(finished, folder, dirs_exist_ok=True)
    monkeypatch.chdir(folder)
    return folder


def test_statistics_never_replace_another_sweeps_store(work, capsys):
    # sweep "two" writes its samples where sweep "one" puts its statistics
    shutil.rmtree(work / "one.stats.zarr")
    shutil.copytree(work / "one.zarr", work / "one.stats.zarr")
    shutil.rmtree(work / "one.zarr")
    before = snapshot(work)
    for extra in ([], ["--overwrite"]):
        assert (
            main(["run", str(work / "one.yaml"), "--output", str(work / "one.zarr"), *extra]) == 2
        )
        assert "not an oceanlidar statistics store" in capsys.readouterr().err
        assert snapshot(work) == before
    shutil.copytree(work / "one.stats.zarr", work / "one.zarr")
    before = snapshot(work)
    assert main(["stats", str(work / "one.zarr")]) == 2
    assert "not an oceanlidar statistics store" in capsys.readouterr().err
    assert snapshot(work) == before


def test_two_outputs_never_share_their_statistics(work, capsys, cli, shared_cluster):
    # outputs "one" and "one.zarr" have one statistics path, one.stats.zarr: sweep "two"
    # written to "one" must not replace the statistics of sweep "one" (in one.zarr)
    assert Store(str(work / "one.stats.zarr")).attributes()["samples_store"] == "one.zarr"
    sweep_file(work, name="two", output="one", seed=4)
    refusal = f"holds the statistics of another store, {work / 'one.zarr'}"
    before = snapshot(work)
    for extra in ([], ["--overwrite"]):
        assert main(["run", "two.yaml", "--workers", "1", *extra]) == 2
        assert refusal in capsys.readouterr().err
        assert snapshot(work) == before
    # sweep "two" run elsewhere, its store then moved to "one" (its statistics left behind)
    result = cli("run", "two.yaml", "--output", "two.zarr", "--workers", 1, cwd=work)
    assert result.returncode == 0, result.stderr
    shutil.rmtree(work / "two.stats.zarr")
    (work / "two.zarr").rename(work / "one")
    before = snapshot(work)
    for command in (["run", "two.yaml", "--overwrite"], ["run", "two.yaml", "--resume"]):
        assert main([*command, "--workers", "1"]) == 2
        assert refusal in capsys.readouterr().err
        assert snapshot(work) == before
    assert main(["stats", "one"]) == 2
    assert refusal in capsys.readouterr().err
    assert snapshot(work) == before
    # statistics whose store is gone are the other's to replace
    shutil.rmtree(work / "one.zarr")
    assert main(["stats", "one"]) == 0
    assert Store(str(work / "one.stats.zarr")).attributes()["samples_store"] == "one"


def test_copied_statistics_are_named_as_a_copy_and_the_original_kept(work, capsys):
    # a store copied with its statistics: those still name the original as theirs
    original = snapshot(work / "one.stats.zarr")
    shutil.copytree(work / "one.zarr", work / "copy.zarr")
    shutil.copytree(work / "one.stats.zarr", work / "copy.stats.zarr")
    before = snapshot(work)
    assert main(["stats", "copy.zarr"]) == 2
    err = capsys.readouterr().err
    assert f"delete {work / 'copy.stats.zarr'}, a copy: {work / 'one.zarr'}'s are" in err
    assert "write this sweep to another output" not in err
    assert main(["info", "copy.zarr"]) == 0
    assert "statistics: (none)" in capsys.readouterr().out
    assert snapshot(work) == before
    shutil.rmtree(work / "copy.stats.zarr")  # as the message says: the original's are kept
    assert main(["stats", "copy.zarr"]) == 0
    assert snapshot(work / "one.stats.zarr") == original
    assert Store(str(work / "copy.stats.zarr")).attributes()["samples_store"] == "copy.zarr"


@pytest.mark.parametrize(
    "stranger",
    ["notes.txt", "image/mine.npy", "old/zarr.json"],
    ids=["file-in-store", "file-in-array-folder", "unlisted-folder"],
)
def test_overwrite_deletes_only_what_the_store_lists(work, capsys, stranger):
    path = work / "one.zarr" / stranger
    path.parent.mkdir(exist_ok=True)
    # a folder carrying the project's attribute is not a licence to delete it either
    path.write_text(json.dumps({"node_type": "group", "attributes": {KIND: "samples"}}))
    before = snapshot(work)
    assert main(["run", str(work / "one.yaml"), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert stranger in err and "does not list" in err
    assert snapshot(work) == before


def test_a_store_of_an_older_version_is_named_not_deleted(work, capsys):
    # stores written before the kind attribute: refused with the version that wrote them
    metadata = json.loads((work / "one.zarr" / "zarr.json").read_text())
    del metadata["attributes"][KIND]
    (work / "one.zarr" / "zarr.json").write_text(json.dumps(metadata))
    before = snapshot(work)
    assert main(["run", str(work / "one.yaml"), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "was written by oceanlidar" in err and "did not record" in err
    assert snapshot(work) == before


def test_a_store_of_an_earlier_layout_is_not_resumed(work, capsys):
    # a store of the same version written before target_effect was stored (issue #24): its
    # tasks would have nowhere to write it, its statistics nothing to read
    metadata = json.loads((work / "one.zarr" / "zarr.json").read_text())
    for name in ("target_effect", "target_effect_relative"):
        del metadata["consolidated_metadata"]["metadata"][name]
        shutil.rmtree(work / "one.zarr" / name)
    (work / "one.zarr" / "zarr.json").write_text(json.dumps(metadata))
    Store.at(str(work / "one.zarr")).mark_incomplete([4])
    before = snapshot(work)
    assert main(["run", str(work / "one.yaml"), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "(target_effect, target_effect_relative missing or shaped otherwise)" in err
    assert "--overwrite" in err
    assert main(["stats", str(work / "one.zarr")]) == 2
    assert "has no target_effect_relative" in capsys.readouterr().err
    assert snapshot(work) == before


def test_overwrite_checks_everything_before_deleting_anything(work, capsys):
    shutil.rmtree(work / "one.stats.zarr")
    (work / "one.stats.zarr").mkdir()
    (work / "one.stats.zarr" / "thesis.tex").write_text("precious")
    before = snapshot(work)
    assert main(["run", str(work / "one.yaml"), "--overwrite"]) == 2
    assert "not an oceanlidar statistics store" in capsys.readouterr().err
    assert snapshot(work) == before


def test_overwrite_replaces_a_store_and_its_statistics(work, cli, shared_cluster):
    before = snapshot(work / "one.zarr")
    command = ["run", work / "one.yaml", "--overwrite", "--workers", 1, "--batch", PER_SHARD]
    result = cli(*command, cwd=work)
    assert result.returncode == 0, result.stderr
    assert snapshot(work / "one.zarr") == before  # same sweep, same bytes
    assert not store_lock(work / "one.zarr").exists()
    assert sorted(p.name for p in work.iterdir()) == ["one.stats.zarr", "one.yaml", "one.zarr"]


def shard_index(work, variable, sample):
    """A sample's shard file, its bytes and the shard's index: (offset, length) per chunk.

    Zarr v3 sharding keeps the index at the end of the shard: two little-endian uint64 per
    inner chunk, then the index's CRC32C.
    """
    shard = next((work / "one.zarr" / variable).glob(f"c.{sample // PER_SHARD}.*"))
    data = bytearray(shard.read_bytes())
    index = np.frombuffer(bytes(data[-(16 * PER_SHARD + 4) : -4]), dtype="<u8").reshape(-1, 2)
    return shard, data, index.copy()


def damage(work, variable="image", sample=1):
    """Flip one byte in the middle of a sample's chunk, inside its shard."""
    shard, data, index = shard_index(work, variable, sample)
    offset, length = (int(v) for v in index[sample % PER_SHARD])
    data[offset + length // 2] ^= 0x01
    shard.write_bytes(bytes(data))


def swap_chunks(work, variable, first, second):
    """Swap two samples' chunks in their shard (its index rewritten, checksum and all)."""
    import google_crc32c

    shard, data, index = shard_index(work, variable, first)
    index[[first % PER_SHARD, second % PER_SHARD]] = index[[second % PER_SHARD, first % PER_SHARD]]
    table = index.astype("<u8").tobytes()
    crc = np.uint32(google_crc32c.value(table)).astype("<u4").tobytes()
    shard.write_bytes(bytes(data[: -(16 * PER_SHARD + 4)]) + table + crc)


def test_failed_statistics_keep_the_previous_ones(work, capsys):
    before = snapshot(work / "one.stats.zarr")
    damage(work)
    assert main(["stats", str(work / "one.zarr")]) == 1
    assert "sample 1: its image chunk cannot be read" in capsys.readouterr().err
    assert snapshot(work / "one.stats.zarr") == before
    assert sorted(p.name for p in work.iterdir()) == ["one.stats.zarr", "one.yaml", "one.zarr"]
    assert main(["info", str(work / "one.zarr")]) == 0
    assert str(work / "one.stats.zarr") in capsys.readouterr().out


@pytest.mark.parametrize(
    ("attack", "sample"),
    [
        (lambda work: next((work / "one.zarr" / "image").glob("c.2.*")).unlink(), 4),
        (lambda work: swap_chunks(work, "image", 0, 1), 0),
        (
            lambda work: shutil.copyfile(
                next((work / "one.zarr" / "image").glob("c.0.*")),
                next((work / "one.zarr" / "image").glob("c.1.*")),
            ),
            2,
        ),
    ],
    ids=["shard-lost", "chunks-swapped", "shard-copied-over-another"],
)
def test_statistics_refuse_samples_not_theirs_and_keep_the_previous_ones(
    work, capsys, attack, sample
):
    # every chunk's CRC32C holds: only the samples' checksums tell (issue #26 item 1)
    before = snapshot(work / "one.stats.zarr")
    attack(work)
    assert main(["stats", str(work / "one.zarr")]) == 1
    err = capsys.readouterr().err
    assert f"sample {sample}: its chunks do not match its checksum" in err
    assert "Traceback" not in err
    assert snapshot(work / "one.stats.zarr") == before
    assert sorted(p.name for p in work.iterdir()) == ["one.stats.zarr", "one.yaml", "one.zarr"]


def test_a_resume_that_skips_a_sample_writes_no_statistics(
    work, capsys, monkeypatch, shared_cluster
):
    import service.run

    def skipping(plan, todo, samples_per_shard):  # a planted fault of the runner
        return real(plan, [s for s in todo if s != 1], samples_per_shard)

    real = service.run.task_batches
    monkeypatch.setattr(service.run, "task_batches", skipping)
    Store.at("one.zarr").mark_incomplete([1, 3])
    before = snapshot(work / "one.stats.zarr")
    assert main(["run", "one.yaml", "--resume", "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert "1 sample unwritten: not marked complete after the run (no task" in err, err
    assert "\n  sample 1 (point 0" in err and "sample 3" not in err
    assert "statistics not written" in err
    assert snapshot(work / "one.stats.zarr") == before


def shard_file(work, variable, shard):
    """The file of a shard of an array (``c.1.0.0``, or ``c.1`` of a 1-D array)."""
    folder = work / "one.zarr" / variable
    return next(p for p in folder.iterdir() if p.name.split(".")[:2] == ["c", str(shard)])


def written_before(work, issue):
    """The store as written before `issue`: #37, its samples' CRC-32 and CRC32C of their
    arrays alone (not of which sample they are); #26, their CRC-32 alone."""
    root = work / "one.zarr"
    meta = json.loads((root / "zarr.json").read_text())
    arrays = meta["consolidated_metadata"]["metadata"]
    bound = arrays.pop("checksum_bound")
    if issue == 37:
        (root / "checksum_bound").rename(root / "checksum_crc32c")
        arrays["checksum_crc32c"] = bound
    else:
        shutil.rmtree(root / "checksum_bound")
    (root / "zarr.json").write_text(json.dumps(meta))
    if issue == 37:
        group = Store.at(str(root)).group("r+")
        names = [name for name in rendered_order() if name in group]
        group["checksum_crc32c"][:] = [
            shards.sample_checksum([group[name][s] for name in names], "checksum_crc32c")
            for s in range(group["completed"].shape[0])
        ]


def swap_shards(work, first, second, *, source=None):
    """Swap shards `first` and `second` of every per-sample array, checksums and flags too
    (or, with `source`, a store's folder, copy its shard `second` over `first`'s)."""
    for folder in (work / "one.zarr").iterdir():
        files = {
            p.name.split(".")[1]: p
            for p in (folder.iterdir() if folder.is_dir() else ())
            if p.name.startswith("c.")
        }
        if str(first) not in files or str(second) not in files:
            continue
        a, b = files[str(first)], files[str(second)]
        if source is not None:
            shutil.copyfile(source / folder.name / b.name, a)
            continue
        data = a.read_bytes()
        a.write_bytes(b.read_bytes())
        b.write_bytes(data)


READER_ATTACKS = {
    # every chunk's CRC32C holds in each: only the samples' checksums and flags tell
    "shard-lost": (lambda work: shard_file(work, "image", 2).unlink(), [4]),
    "chunks-swapped": (lambda work: swap_chunks(work, "image", 0, 1), [0, 1]),
    "shard-copied-over-another": (
        lambda work: shutil.copyfile(shard_file(work, "image", 0), shard_file(work, "image", 1)),
        [2, 3],
    ),
}


@pytest.mark.parametrize(
    ("old", "kind"),
    [(None, "checksum_bound"), (37, "checksum_crc32c"), (26, "checksum")],
    ids=["bound", "crc32c-of-older-stores", "crc32-of-older-stores"],
)
@pytest.mark.parametrize("attack", READER_ATTACKS)
def test_the_training_reader_returns_no_sample_that_is_not_its_own(work, attack, old, kind):
    from service.dataset import SampleDataset
    from service.errors import DamagedStoreError

    intact = SampleDataset("one.zarr", arrays=("image", "target_mask", "target_signal"))
    expected = intact.__getitems__(range(5))
    if old:
        written_before(work, old)
    assert SampleDataset("one.zarr").checksum == kind
    damage_it, damaged = READER_ATTACKS[attack]
    damage_it(work)
    reader = SampleDataset("one.zarr", arrays=("image", "target_mask", "target_signal"))
    assert len(reader) == 5
    for item in range(5):
        if item in damaged:
            with pytest.raises(DamagedStoreError, match=f"sample {item}: its arrays do not"):
                reader[item]
        else:
            for name, values in reader[item].items():
                assert values.tobytes() == expected[item][name].tobytes(), (item, name)


def test_the_training_reader_refuses_a_store_whose_completion_flags_are_lost(work, capsys):
    from service.dataset import SampleDataset
    from service.errors import DamagedStoreError

    # clearing flags, as --resume --verify does, is no loss: the flags' chunk is written
    Store.at("one.zarr").mark_incomplete([0, 1])
    assert shard_file(work, "completed", 0).exists()
    assert SampleDataset("one.zarr").sample_index.tolist() == [2, 3, 4]
    shard_file(work, "completed", 1).unlink()  # samples 2 and 3 would read as never written
    with pytest.raises(DamagedStoreError, match="samples 2, 3 hold checksums but their"):
        SampleDataset("one.zarr")
    assert main(["info", "one.zarr", "--verify"]) == 1
    out = capsys.readouterr().out
    assert "  sample 2: not counted complete: its checksum is stored but its completion" in out
    assert "--resume --verify to recompute them" in out


def assert_repaired(work, cli, original, *, written, kept):
    """``run --resume --verify`` rewrites `written` samples, keeps `kept`, gives `original`."""
    result = cli("run", "one.yaml", "--resume", "--verify", "--workers", 1, cwd=work)
    assert result.returncode == 0, result.stderr
    assert f"wrote {written} samples" in result.stderr
    assert f"{kept} already complete" in result.stderr
    assert snapshot(work / "one.zarr") == original
    assert main(["info", "one.zarr", "--verify"]) == 0


def test_verify_finds_damaged_missing_and_swapped_samples_and_resume_redoes_them(
    work, capsys, cli, shared_cluster
):
    # layout: shards [0, 1], [2, 3], [4]; a repair rewrites a shard with the samples in it
    # that are intact (sample 2 beside the damaged 3) to the same bytes
    original = snapshot(work / "one.zarr")
    swap_chunks(work, "image", 0, 1)
    damage(work, "target_mask", sample=3)
    next((work / "one.zarr" / "image").glob("c.2.*")).unlink()
    assert main(["info", "one.zarr"]) == 0
    assert "5/5 complete" in capsys.readouterr().out  # the flags alone cannot tell
    assert main(["info", "one.zarr", "--verify"]) == 1
    out = capsys.readouterr().out
    assert "verified: 1 of 5 complete samples read back intact" in out
    assert "sample 0: damaged or missing: its chunks do not match its checksum" in out
    assert "sample 1: damaged or missing: its chunks do not match its checksum" in out
    assert "sample 3: damaged or missing: a chunk cannot be read" in out
    assert "sample 4: damaged or missing: no image shard" in out
    assert "sample 2:" not in out
    assert_repaired(work, cli, original, written=4, kept=1)


@pytest.mark.parametrize("attack", ["shards-swapped", "shard-of-another-seed"])
def test_a_shard_of_another_sample_or_store_fails_every_check(
    work, capsys, cli, shared_cluster, attack
):
    # issue #37 item 2: every file of shards 0 and 1 swapped, checksums and flags included,
    # or shard 1 copied from a store of the same sweep with another seed: every chunk's
    # CRC32C and every checksum of the arrays alone hold; only a checksum that covers which
    # sample it is (index, point, realisation, sweep, seed) tells
    from service.dataset import SampleDataset
    from service.errors import DamagedStoreError

    original = snapshot(work / "one.zarr")
    statistics = snapshot(work / "one.stats.zarr")
    if attack == "shards-swapped":
        swap_shards(work, 0, 1)
        damaged = [0, 1, 2, 3]
    else:
        other = work / "other"
        other.mkdir()
        sweep = sweep_file(other, seed=4)
        with pytest.MonkeyPatch.context() as patch:
            patch.chdir(other)
            assert main(["run", str(sweep), "--workers", "1", "--batch", str(PER_SHARD)]) == 0
        swap_shards(work, 1, 1, source=other / "one.zarr")
        shutil.rmtree(other)
        damaged = [2, 3]
    assert snapshot(work / "one.zarr") != original
    capsys.readouterr()
    assert main(["info", "one.zarr", "--verify"]) == 1
    out = capsys.readouterr().out
    assert f"verified: {5 - len(damaged)} of 5 complete samples read back intact" in out
    for sample in damaged:
        assert f"sample {sample}: damaged or missing: its chunks do not match" in out
    assert "do not cover which sample" not in out
    # stats refuses and keeps the correct statistics
    assert main(["stats", "one.zarr"]) == 1
    err = capsys.readouterr().err
    assert f"sample {damaged[0]}: its chunks do not match its checksum" in err
    assert "Traceback" not in err
    assert snapshot(work / "one.stats.zarr") == statistics
    reader = SampleDataset("one.zarr")
    for item in range(5):
        if item in damaged:
            with pytest.raises(DamagedStoreError, match=f"sample {item}: its arrays do not"):
                reader[item]
        else:
            assert int(reader[item]["sample"]) == item
    assert_repaired(work, cli, original, written=len(damaged), kept=5 - len(damaged))


def test_checksums_of_an_older_store_are_read_and_say_what_they_miss(work, capsys):
    # issue #37 item 2: a store written before it (checksums of the arrays alone) is read
    # and checked as before, and info --verify says which damage those cannot see
    written_before(work, 37)
    swap_shards(work, 0, 1)
    assert main(["info", "one.zarr", "--verify"]) == 0
    out = capsys.readouterr().out
    assert "verified: 5 of 5 complete samples read back intact" in out
    assert "its checksums (written before issue #37) do not cover which sample they are" in out
    damage(work, "image", sample=1)
    assert main(["info", "one.zarr", "--verify"]) == 1
    assert "sample 1: damaged or missing" in capsys.readouterr().out


@pytest.mark.parametrize("record", ["completed", "checksum_bound"])
def test_an_empty_record_file_is_named_and_written_again(
    work, capsys, cli, shared_cluster, record
):
    # issue #37 item 6: a zero-length file of completion flags or checksums (shard 1:
    # samples 2 and 3) ended in tracebacks naming nothing to delete
    from service.dataset import SampleDataset
    from service.errors import DamagedStoreError

    original = snapshot(work / "one.zarr")
    statistics = snapshot(work / "one.stats.zarr")
    shard_file(work, record, 1).write_bytes(b"")
    named = f"one.zarr/{record}/c.1"
    commands = [["info", "one.zarr", "--verify"], ["stats", "one.zarr"]]
    if record == "completed":  # a complete store's resume reads no checksum
        commands += [["info", "one.zarr"], ["run", "one.yaml", "--resume", "--workers", "1"]]
    for argv in commands:
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert named in err and "--resume --verify" in err, (argv, err)
        assert "Traceback" not in err, argv
    with pytest.raises(DamagedStoreError, match=f"{named}.*--resume --verify"):
        SampleDataset("one.zarr")[2]
    assert snapshot(work / "one.stats.zarr") == statistics
    result = cli("run", "one.yaml", "--resume", "--verify", "--workers", 1, cwd=work)
    assert result.returncode == 0, result.stderr
    assert f"its {record} record could not be read (written again)" in result.stderr
    assert "wrote 2 samples" in result.stderr and "3 already complete" in result.stderr
    assert snapshot(work / "one.zarr") == original
    assert main(["info", "one.zarr", "--verify"]) == 0


def test_info_verify_names_every_record_file_that_cannot_be_read(work, capsys):
    # the issue #37 trial: a zero-length file of the CRC-32 checksums, which no reader
    # checks against since checksum_bound, passed info --verify ("16 of 16 intact")
    path = shard_file(work, "checksum", 1)
    kept = path.read_bytes()
    path.write_bytes(b"")
    try:
        assert main(["info", "one.zarr", "--verify"]) == 1
        err = capsys.readouterr().err
        assert "one.zarr/checksum/c.1" in err and "--resume --verify" in err, err
    finally:
        path.write_bytes(kept)
    assert main(["info", "one.zarr", "--verify"]) == 0


def test_edited_labels_stop_the_readers(work, capsys):
    # issue #37 item 5: no sample's checksum covers the labels; stats and the training
    # reader compare them with the sweep's, as info --verify does
    from service.dataset import SampleDataset
    from service.errors import DamagedStoreError

    statistics = snapshot(work / "one.stats.zarr")
    present = __import__("zarr").open_array(work / "one.zarr" / "target_present", mode="r+")
    present[2] = 0  # the fill value: as a chunk lost reads
    assert main(["stats", "one.zarr"]) == 1
    err = capsys.readouterr().err
    assert "its target_present are lost or unreadable" in err and "--resume --verify" in err
    assert "Traceback" not in err
    assert snapshot(work / "one.stats.zarr") == statistics
    with pytest.raises(DamagedStoreError, match="its target_present are lost or unreadable"):
        SampleDataset("one.zarr")
    present[2] = 1
    platform = __import__("zarr").open_array(work / "one.zarr" / "platform_z", mode="r+")
    platform[0] = platform[0] + 1.0  # no fill value: edited, or computed otherwise
    with pytest.raises(DamagedStoreError, match="its platform_z differ from what its sweep"):
        SampleDataset("one.zarr")
    assert main(["stats", "one.zarr"]) == 1
    assert "--overwrite" in capsys.readouterr().err


def test_a_truncated_shard_is_written_again_whole(work, capsys, cli, shared_cluster):
    # issue #26 item 10: zarr reads a shard's old file before writing it, so a shard whose
    # index is cut off failed every repair ("checksum do not match"); shards [0, 1], [2, 3], [4]
    original = snapshot(work / "one.zarr")
    shard = next((work / "one.zarr" / "image").glob("c.1.*"))
    shard.write_bytes(shard.read_bytes()[: len(shard.read_bytes()) // 2])
    assert main(["info", "one.zarr", "--verify"]) == 1
    out = capsys.readouterr().out
    assert "sample 2: damaged" in out and "sample 3: damaged" in out
    assert_repaired(work, cli, original, written=2, kept=3)


def test_lost_or_damaged_labels_are_found_and_written_again(work, capsys, cli, shared_cluster):
    # no sample's checksum covers the labels and coordinates the store was created with: a
    # lost chunk reads back as the fill value (every target_present 0), a damaged one fails
    from service.run import execute
    from service.sweep import load_sweep

    original = snapshot(work / "one.zarr")
    statistics = xr.open_zarr(work / "one.stats.zarr").load()
    for name in ("target_present", "realisation"):
        for chunk in [p for p in (work / "one.zarr" / name / "c").rglob("*") if p.is_file()]:
            chunk.unlink()
    chunk = next(p for p in (work / "one.zarr" / "platform_z" / "c").rglob("*") if p.is_file())
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x01
    chunk.write_bytes(bytes(data))
    assert main(["info", "one.zarr", "--verify"]) == 1
    out = capsys.readouterr().out
    assert "verified: 5 of 5 complete samples read back intact" in out
    assert "lost or unreadable: target_present, platform_z, realisation" in out
    assert "not as this installation computes" not in out
    # a repair interrupted before its statistics: they go with the wrong labels, so that
    # any later run computes them all again
    cancelled = threading.Event()
    cancelled.set()
    Store.at("one.zarr").mark_incomplete([4])  # work left, for the cancel to stop
    plan = load_sweep(work / "one.yaml")
    quiet = open(os.devnull, "w")
    result = execute(
        plan,
        Store.at("one.zarr"),
        workers=1,
        resume=True,
        verify=True,
        cancel=cancelled,
        progress_stream=quiet,
    )
    assert result.relabelled == ["target_present", "platform_z", "realisation"]
    assert result.interrupted and not snapshot(work / "one.stats.zarr")  # its files deleted
    result = cli("run", "one.yaml", "--resume", "--workers", 1, cwd=work)
    assert result.returncode == 0, result.stderr
    assert snapshot(work / "one.zarr") == original
    xr.testing.assert_identical(xr.open_zarr(work / "one.stats.zarr").load(), statistics)
    assert main(["info", "one.zarr", "--verify"]) == 0
    assert "lost or unreadable: none" in capsys.readouterr().out
    # the CLI's repair says what it wrote again
    for chunk in [
        p for p in (work / "one.zarr" / "target_present" / "c").rglob("*") if p.is_file()
    ]:
        chunk.unlink()
    result = cli("run", "one.yaml", "--resume", "--verify", "--workers", 1, cwd=work)
    assert result.returncode == 0, result.stderr
    assert "written again from the sweep: target_present" in result.stderr
    assert snapshot(work / "one.zarr") == original


def test_labels_computed_otherwise_here_are_refused_not_overwritten(work, capsys, cli):
    # readable labels that differ from this installation's (another scipy drawing a
    # design's points): resuming would mix them, so nothing is rewritten
    zarr_array = __import__("zarr").open_array(work / "one.zarr" / "platform_z", mode="r+")
    zarr_array[0] = zarr_array[0] + 1.0
    before = snapshot(work / "one.zarr")
    assert main(["info", "one.zarr", "--verify"]) == 1
    out = capsys.readouterr().out
    assert "not as this installation computes them: platform_z" in out
    assert "--resume --verify" not in out
    result = cli("run", "one.yaml", "--resume", "--verify", "--workers", 1, cwd=work)
    assert (
        result.returncode == 2 and "platform_z differ from what this installation" in result.stderr
    )
    assert snapshot(work / "one.zarr") == before


def test_shards_of_samples_without_a_target_verify_intact(tmp_path):
    # the masks (0) and signal means (NaN) of a shard of samples without a target hold only
    # the fill value: written since 2026-11-24, absent from stores of older versions (zarr's
    # default stores no such shard), which must verify intact too
    from service.run import render_shard, task_batches
    from service.sweep import parse_sweep

    plan = parse_sweep(TINY_SWEEP.format(name="e", seed=3, realisations=2, output="e.zarr"))
    url = str(tmp_path / "e.zarr")
    create_store(plan, Store(url), samples_per_shard=2)
    for _, jobs in task_batches(plan, range(plan.samples), 2):
        assert render_shard(Store(url), jobs) == []
    for name in ("target_mask", "target_signal", "background_signal"):
        shards = sorted((tmp_path / "e.zarr" / name).glob("c.*"))
        assert [p.name.split(".")[1] for p in shards] == ["0", "1"]
        assert integrity.verify(Store(url)) == []
        shards[1].unlink()  # as an older version left it
    assert integrity.verify(Store(url)) == []
    # a shard lost whose values were not all fill is still found, and named
    next((tmp_path / "e.zarr" / "image").glob("c.1.*")).unlink()
    problems = integrity.verify(Store(url))
    assert [sample for sample, _ in problems] == [2, 3]
    assert all(reason.startswith("no image or target_mask") for _, reason in problems)


def test_damaged_statistics_are_named_and_written_again(
    tmp_path, monkeypatch, capsys, shared_cluster
):
    monkeypatch.chdir(tmp_path)
    sweep = tiny_sweep(tmp_path, realisations=1)
    assert main(["run", str(sweep), "--workers", "1"]) == 0
    chunk = next((tmp_path / "t.stats.zarr" / "image_mean").glob("c.0.*"))
    data = bytearray(chunk.read_bytes())
    data[-1] ^= 0x01  # the chunk's stored checksum
    chunk.write_bytes(bytes(data))
    assert main(["plot", "t.zarr", "--output", "p.png"]) == 1
    err = capsys.readouterr().err
    assert "t.stats.zarr: a chunk cannot be read" in err and "oceanlidar stats" in err
    assert main(["stats", "t.zarr"]) == 0
    assert main(["plot", "t.zarr", "--output", "p.png"]) == 0


def write_lock(work, at=None, **holder):
    record = {"host": socket.gethostname(), "since": "2026-01-01T00:00:00+00:00", **holder}
    (at or store_lock(work / "one.zarr")).write_text(json.dumps({"token": "x", **record}))


@pytest.mark.parametrize("legacy", [False, True], ids=["beside", "in-the-store-as-before"])
def test_a_locked_store_is_refused_and_a_dead_holders_lock_taken_over(work, capsys, legacy):
    # a lock an older version left in the store (issue #27 moved it beside) still counts
    at = work / "one.zarr" / lock.LEGACY_LOCK_NAME if legacy else store_lock(work / "one.zarr")
    write_lock(work, at, host="elsewhere", pid=1)
    before = snapshot(work)
    for command in (["run", str(work / "one.yaml"), "--overwrite"], ["stats", "one.zarr"]):
        assert main([*command[:1], *(str(work / c) for c in command[1:2]), *command[2:]]) == 2
        err = capsys.readouterr().err
        assert "locked by another run (host elsewhere" in err
        assert str(at) in err
        assert snapshot(work) == before
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    write_lock(work, at, pid=dead.pid)
    assert main(["stats", str(work / "one.zarr")]) == 0
    assert not at.exists() and not store_lock(work / "one.zarr").exists()


def test_a_stale_lock_on_a_read_only_file_system_is_refused_cleanly(work, capsys, monkeypatch):
    # the takeover's guard file raised OSError: a traceback (issue #26 item 11)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    write_lock(work, pid=dead.pid)
    before = snapshot(work)

    def read_only(fs, path, data):  # O_CREAT | O_EXCL: an existing file says so first
        if os.path.exists(path):
            raise FileExistsError(errno.EEXIST, "File exists", path)
        raise OSError(errno.EROFS, "Read-only file system", path)

    monkeypatch.setattr(lock, "_create_exclusive", read_only)
    for command in (["run", "one.yaml", "--resume"], ["stats", "one.zarr"]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "cannot be written: Read-only file system" in err, err
        assert "Traceback" not in err
    assert snapshot(work) == before


def test_two_fresh_runs_racing_for_one_output(tmp_path):
    sweep = sweep_file(tmp_path)
    runs = [
        start_cli("run", sweep, "--workers", 1, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    errors = [run.communicate(timeout=300)[1] for run in runs]
    codes = sorted(run.returncode for run in runs)
    assert codes == [0, 2], errors
    loser = errors[[run.returncode for run in runs].index(2)]
    assert "locked by another run" in loser or "already exists" in loser
    assert "Traceback" not in loser
    assert main(["info", str(tmp_path / "one.zarr")]) == 0


def test_a_sample_with_non_finite_values_is_reported_and_never_marked_complete(
    tmp_path, monkeypatch, capsys, threads
):
    def poisoned(scene, *, seed):
        sample = render_arrays(scene, seed=seed)
        if (seed.point, seed.realisation) == (1, 1):
            sample["expected"][0, 0, 0, 0] = np.nan
        return sample

    monkeypatch.setattr(service.tasks, "render_samples", batch_of(poisoned))
    sweep = tmp_path / "nan.yaml"
    sweep.write_text(TINY_SWEEP.format(name="nan", seed=1, realisations=3, output="n.zarr"))
    output = tmp_path / "n.zarr"
    assert (
        main(["run", str(sweep), "--output", str(output), "--batch", "3", "--workers", "1"]) == 1
    )
    err = capsys.readouterr().err
    assert "1 sample not stored: expected holds 1 non-finite value" in err
    assert "\n  sample 4 (point 1: target.shape='none'; realisation 1)\n" in err
    assert "expected holds 1 non-finite value" in err and "Traceback" not in err
    ds = xr.open_zarr(output)
    assert ds["completed"].values.tolist() == [1, 1, 1, 1, 0, 1]
    # its shard [3, 4, 5] holds samples 3 and 5; sample 4 stays at the fill value
    assert (ds["image"].values[4] == 0).all() and ds["image"].values[[3, 5]].any()
    assert not (tmp_path / "n.stats.zarr").exists()


@pytest.mark.parametrize(
    ("output", "options", "message"),
    [
        (
            "memory://m.zarr",
            ["--workers", "1"],
            "the workers do not see the store 'memory://m.zarr'",
        ),
        ("/sys/o.zarr", [], "'/sys/o.zarr' cannot be written: Operation not permitted"),
        ("x" * 300 + ".zarr", [], "cannot be written: File name too long"),
        ("o.zarr", ["--storage-options", '{"anon": true}'], "apply to URLs such as s3://"),
        ("o.zarr", ["--scheduler", "tls://127.0.0.1:9"], "a tls:// scheduler needs"),
        ("/dev/null", [], "/dev/null exists and is neither a folder nor a regular file"),
        ("/dev/null", ["--overwrite"], "/dev/null exists and is neither a folder nor a"),
    ],
    ids=[
        "memory",
        "read-only",
        "long-component",
        "options-for-a-path",
        "tls-without-tls",
        "device",
        "device-overwritten",
    ],
)
def test_outputs_that_cannot_be_written_are_refused_before_rendering(
    tmp_path, output, options, message, cli, shared_cluster
):
    sweep = sweep_file(tmp_path)
    result = cli("run", sweep, "--output", output, *options, cwd=tmp_path)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.yaml"]


GROUP = '{"zarr_format": 3, "node_type": "group", "attributes": {}}'


def test_only_a_store_above_an_output_refuses_it(tmp_path, monkeypatch):
    # a review's find: the walk read the working directory ('' above an absolute path) and
    # any zarr group above, so a run started in, or writing below, some other zarr group
    # was refused; the service's data root bounds its own walk
    foreign = tmp_path / "group"
    foreign.mkdir()
    (foreign / "zarr.json").write_text(GROUP)
    monkeypatch.chdir(foreign)
    assert enclosing_store(Store.at(tmp_path / "out" / "run.zarr")) is None
    assert enclosing_store(Store.at(foreign / "run.zarr")) is None
    (foreign / "zarr.json").write_text(GROUP.replace("{}", '{"oceanlidar_dataset": "samples"}'))
    assert enclosing_store(Store.at(foreign / "a" / "run.zarr")) == str(foreign)
    assert enclosing_store(Store.at(foreign / "run.zarr"), within=str(foreign)) is None


@pytest.mark.parametrize("options", [[], ["--resume"], ["--overwrite"]])
@pytest.mark.parametrize("inner", ["a.zarr/x.zarr", "a.zarr/image/deep/x.zarr"])
def test_an_output_inside_a_store_is_refused(tmp_path, inner, options, cli):
    # the service refused an output inside a store; `run` wrote one there, exit 0, and the
    # outer store could no longer be replaced (a trial of issue #27's changes)
    outer = tmp_path / "a.zarr"
    (outer / "image").mkdir(parents=True)
    (outer / "zarr.json").write_text(GROUP.replace("{}", '{"oceanlidar_dataset": "samples"}'))
    (outer / "image" / "zarr.json").write_text('{"zarr_format": 3, "node_type": "array"}')
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    sweep = sweep_file(tmp_path)
    result = cli("run", sweep, "--output", tmp_path / inner, *options, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert "lies inside the store '" in result.stderr and "Traceback" not in result.stderr
    after = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert after == sorted([*before, sweep.relative_to(tmp_path)])


@pytest.mark.parametrize("options", [[], ["--overwrite"]], ids=["run", "overwrite"])
def test_a_large_folder_as_output_is_refused_at_its_first_file(tmp_path, monkeypatch, options):
    # output: / walked the whole file system before refusing (issue #26 item 6)
    from fsspec.implementations.local import LocalFileSystem

    big = tmp_path / "big"
    for folder in range(40):
        (big / f"d{folder:02}").mkdir(parents=True)
        (big / f"d{folder:02}" / "f").write_text("a user's file")
    listed = []
    ls = LocalFileSystem.ls

    def counted(self, path, *args, **kwargs):
        listed.append(path)
        return ls(self, path, *args, **kwargs)

    sweep = sweep_file(tmp_path)
    before = snapshot(tmp_path)
    monkeypatch.setattr(LocalFileSystem, "ls", counted)
    assert main(["run", str(sweep), "--output", str(big), *options]) == 2
    inside = [path for path in listed if path.startswith(str(big / "d"))]
    assert 1 <= len(inside) <= 2, inside  # the first folder with a file decides
    assert snapshot(tmp_path) == before


def test_empty_storage_options_with_a_local_store_are_no_options(work, capsys):
    # zarr refused them unused, exit 1 (issue #26 item 11; holds since Store.at, issue #25)
    assert Store.at("one.zarr", {}).storage_options is None
    for command in (["info", "one.zarr"], ["stats", "one.zarr"]):
        assert main([*command, "--storage-options", "{}"]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_home_and_file_urls_reach_the_workers_as_paths(tmp_path, cli, shared_cluster):
    # the session's workers keep their own HOME: a "~" must reach them expanded
    sweep = sweep_file(tmp_path)
    (tmp_path / "home").mkdir()
    for output in ("~/h.zarr", f"file://{tmp_path}/f.zarr"):
        result = cli(
            "run",
            sweep,
            "--output",
            output,
            "--workers",
            1,
            cwd="/",
            env={"HOME": tmp_path / "home"},
        )
        assert result.returncode == 0, result.stderr
    assert main(["info", str(tmp_path / "home" / "h.zarr")]) == 0
    assert main(["info", str(tmp_path / "f.zarr")]) == 0


def tiny_sweep(folder, realisations=3):
    sweep = folder / "t.yaml"
    sweep.write_text(
        TINY_SWEEP.format(name="t", seed=1, realisations=realisations, output="t.zarr")
    )
    return sweep


def test_a_frozen_task_is_given_up_and_named(tmp_path, monkeypatch, capsys, threads):
    release = threading.Event()

    def frozen(scene, *, seed):
        if (seed.point, seed.realisation) == (0, 2):
            release.wait(timeout=3)  # frozen well past the task timeout
        return render_arrays(scene, seed=seed)

    monkeypatch.setattr(service.tasks, "render_samples", batch_of(frozen))
    command = ["run", str(tiny_sweep(tmp_path)), "--output", str(tmp_path / "t.zarr")]
    options = ["--batch", "1", "--workers", "2", "--task-timeout", "1"]
    started = time.monotonic()
    assert main([*command, *options]) == 1
    assert time.monotonic() - started < 60
    release.set()
    err = capsys.readouterr().err
    # tasks queued behind the frozen one on its worker may be given up too
    assert "stuck: no result 1 s after submission (a frozen worker?); given up" in err
    assert "\n  sample 2 (point 0: target.shape='sphere'; realisation 2)\n" in err
    assert "statistics not written" in err


def test_a_full_disk_stops_the_run_with_one_message(tmp_path, monkeypatch, capsys, threads):
    tasks = set()

    def full(group, samples):
        tasks.add(min(samples))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(shards, "write_shard", full)
    sweep = tiny_sweep(tmp_path, realisations=10)
    assert main(["run", str(sweep), "--output", str(tmp_path / "t.zarr"), "--batch", "1"]) == 1
    err = capsys.readouterr().err
    assert err.count("No space left on device") == 1
    assert "stopped: " in err and "run again with --resume" in err
    assert len(tasks) < 20 // 2


def test_the_template_is_built_without_rendering_a_sample(tmp_path, monkeypatch):
    import tracemalloc

    from service.sweep import parse_sweep

    def no_render(*args, **kwargs):
        raise AssertionError("the template rendered a frame")

    monkeypatch.setattr("workers.fast.stages.frame_light", no_render)

    text = TINY_SCENE.format(name="big", seed=1, realisations=2, output="big.zarr")
    text = text.replace("pixels: 16", "pixels: 1024").replace(
        "scene:", "scene:\n  sequence: {frames: 16}"
    )
    plan = parse_sweep(text, max_memory=None)  # the workers would need it, not the template
    assert plan.sample_bytes() > 2**24  # one sample: over 16 MiB
    tracemalloc.start()
    try:
        create_store(plan, Store(str(tmp_path / "big.zarr")))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2**25  # under 32 MiB
    ds = xr.open_zarr(tmp_path / "big.zarr")
    assert ds["image"].shape == (2, 16, 1, 1024, 1024) and ds["image"].dtype.kind == "u"
    assert ds["target_mask"].shape == (2, 16, 1024, 1024) and ds["target_mask"].dtype == np.uint8
    assert ds["image"].attrs["long_name"] == "photoelectron count with shot noise"


def test_the_local_lock_is_taken_atomically(tmp_path, monkeypatch):
    # Two runs that both look before the other creates the lock must not both get it:
    # here every "is it there?" answers no, so only an exclusive create refuses the second
    # (fsspec's mode="create" checks, then writes, and would let both through).
    from fsspec.implementations.local import LocalFileSystem

    from service.errors import LockedError

    url = str(tmp_path / "race.zarr")
    monkeypatch.setattr(LocalFileSystem, "exists", lambda self, path, **kwargs: False)
    with Store(url).lock():
        with pytest.raises(LockedError, match="locked by another run"):
            with Store(url).lock():
                pass


def test_a_lock_of_the_same_claim_is_taken_over_from_any_host(tmp_path):
    # The batch service claims a job's store with the job's id; restarted (as process 1 of
    # a new container, in a pod with another host name), it takes over its own job's lock,
    # and nobody else's.
    from service.errors import LockedError

    url = tmp_path / "claimed.zarr"
    url.mkdir()
    held = {"host": "an-earlier-pod", "pid": 1, "token": "gone", "since": "?", "claim": "job a"}
    store_lock(url).write_text(json.dumps(held))
    for claim in (None, "job b"):
        with pytest.raises(LockedError, match="locked by another run"):
            with Store(str(url)).lock(claim=claim):
                pass
        assert json.loads(store_lock(url).read_text()) == held
    with Store(str(url)).lock(claim="job a") as token:
        holder = json.loads(store_lock(url).read_text())
        assert holder["token"] == token and holder["claim"] == "job a"
    assert not store_lock(url).exists()


def test_a_stale_lock_is_taken_over_by_one_run_only(tmp_path, monkeypatch):
    # Two runs find the same dead holder at the same moment (a barrier right after the
    # staleness check): only one may end up holding the lock, and the other is refused
    # with the message, not a traceback. Removing the lock without the guard lets the
    # second run delete the first one's fresh lock, and both write.
    from service.errors import InputError

    url = tmp_path / "stale.zarr"
    url.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = {"host": socket.gethostname(), "pid": dead.pid, "token": "gone", "since": "?"}
    store_lock(url).write_text(json.dumps(stale))
    both_looked = threading.Barrier(2, timeout=10)
    is_stale = lock._is_stale

    def looked(holder, claim):
        answer = is_stale(holder, claim)
        both_looked.wait()
        return answer

    monkeypatch.setattr(lock, "_is_stale", looked)
    outcomes = []

    def take():
        try:
            with Store(str(url)).lock() as token:
                outcomes.append(("held", token))
                time.sleep(0.5)  # still holding while the other run tries
        except InputError as error:
            outcomes.append(("refused", str(error)))
        except Exception as error:  # a crash is an outcome to report
            outcomes.append(("crashed", repr(error)))

    runs = [threading.Thread(target=take) for _ in range(2)]
    for run in runs:
        run.start()
    for run in runs:
        run.join(timeout=30)
    assert sorted(kind for kind, _ in outcomes) == ["held", "refused"], outcomes
    assert "locked by another run" in dict(outcomes)["refused"]
    assert not store_lock(url).exists()
    assert not Path(f"{store_lock(url)}{lock.TAKEOVER_SUFFIX}").exists()


def test_a_cluster_slow_to_shut_down_does_not_fail_a_finished_run(monkeypatch, caplog):
    # A loaded machine: a worker outlives the close's deadline after the run has written
    # everything. The old client turned that into a TimeoutError traceback and exit 1.
    from distributed import LocalCluster

    import service.cluster

    class SlowToClose(LocalCluster):
        def close(self, *args, **kwargs):
            super().close(*args, **kwargs)
            raise TimeoutError

    def threaded(*, config=None, **options):  # threads: no nanny to take `config`
        return SlowToClose(**{**options, "processes": False, "protocol": "tcp://"})

    monkeypatch.setattr(service.cluster, "LocalCluster", threaded)
    with service.cluster.dask_client(workers=1, scheduler=None) as client:
        assert client.submit(sum, [1, 2]).result() == 3
    assert "did not shut down" in caplog.text
