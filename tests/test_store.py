"""The store's layout (issue #10): shards owned by one task, compact counts, the reader,
xarray ergonomics, CF conventions, statistics of a resumed run."""

import itertools
import json
import os
import pickle
import shutil
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import zarr
from conftest import TINY_SCENE, batch_of, cf_failures

import service.tasks
from service.dataset import SampleDataset, image_type, open_dataset
from service.errors import DamagedStoreError, InputError
from service.run import execute, render_shard, task_batches
from service.stats import write_statistics
from service.store import integrity, layout, shards, template
from service.store.location import Store
from service.store.template import create_store
from service.sweep import parse_sweep
from workers.dataset.labels import rendered_arrays
from workers.dataset.variables import count_dtype, rendered_order, variables
from workers.render import render, render_arrays
from workers.settings.seeds import SampleSeed

SWEEP = (
    TINY_SCENE.replace("receiver: {{pixels: 16, ", "receiver: {{pixels: 8, ")
    + """\
sweep:
  parameters:
    target.depth: {{values: [3.0, 6.0]}}
    target.shape: {{values: [sphere, none]}}
"""
)
"""Four points of tiny samples (8 px, one gate)."""


def tiny_plan(realisations=3, **replace):
    text = SWEEP.format(name="t", seed=4, realisations=realisations, output="t.zarr")
    for old, new in replace.items():
        text = text.replace(old, new)
    return parse_sweep(text)


def fill(plan, url, samples_per_shard=2):
    """A store of `plan` with every sample written, in this process (no cluster)."""
    create_store(plan, Store(url), samples_per_shard=samples_per_shard)
    for _, jobs in task_batches(plan, range(plan.samples), samples_per_shard):
        render_shard(Store(url), jobs)


@pytest.fixture(scope="module")
def filled(tmp_path_factory):
    plan = tiny_plan()
    url = str(tmp_path_factory.mktemp("filled") / "t.zarr")
    fill(plan, url)
    return plan, url


def test_counts_take_the_narrowest_unsigned_type_and_overflow_is_refused(tmp_path, cli):
    widths = {}
    for photons in (10, 2000, 1e6):
        scene = tiny_plan(**{"white_plane_photons: 100": f"white_plane_photons: {photons}"})
        widths[photons] = count_dtype(scene.scenes[0])
    assert widths == {10: np.uint8, 2000: np.uint16, 1e6: np.uint32}
    # a bright white target just under the sea could exceed uint32: refused, field named
    sweep = tmp_path / "bright.yaml"
    sweep.write_text(
        TINY_SCENE.format(name="b", seed=1, realisations=1, output="b.zarr").replace(
            "white_plane_photons: 100}",
            "white_plane_photons: 1.0e9}\n  target: {reflectance: 1.0, depth: 0.5}",
        )
    )
    result = cli("run", sweep, cwd=tmp_path)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "scene.radiometry: a white plane under the sea would give 1e+09" in result.stderr
    assert "unsigned 32-bit" in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bright.yaml"]


def test_a_count_beyond_its_type_is_never_wrapped_and_never_stored():
    scene = tiny_plan().scenes[0]
    assert count_dtype(scene) == np.uint8
    expected = np.full((1, 1, 8, 8), 0.5, np.float32)
    image = np.zeros((1, 1, 8, 8), np.float32)
    image[0, 0, 2, 3] = 300.0  # over uint8's 255
    mask = np.zeros((1, 8, 8), np.uint8)
    arrays = rendered_arrays(scene, expected, image, mask, None, free=expected)
    assert arrays["image"].dtype == np.float32 and float(arrays["image"].max()) == 300.0
    reason = integrity.invalid_values(arrays, scene)
    assert reason is not None and "image holds 1 count(s) over 255" in reason


def test_the_store_holds_the_widest_counts_any_point_needs(tmp_path):
    photons = "radiometry.white_plane_photons: {values: [10, 2000]}"
    plan = tiny_plan(realisations=1, **{"target.shape: {values: [sphere, none]}": photons})
    assert [count_dtype(scene) for scene in plan.scenes[:2]] == [np.uint8, np.uint16]
    # the types parse_sweep worked out while validating, which the plan keeps, are these
    assert plan.image_dtypes == {s: count_dtype(s) for s in plan.scenes}
    url = str(tmp_path / "w.zarr")
    fill(plan, url)
    ds = xr.open_zarr(url)
    assert ds["image"].dtype == np.uint16 and ds["image"].attrs["valid_max"] == 65535
    alone = render(plan.scenes[0], seed=SampleSeed(root=4, point=0, realisation=0))
    assert alone["image"].dtype == np.uint8
    assert np.array_equal(ds["image"].values[0], alone["image"].values)


@pytest.mark.parametrize(
    ("photons", "counts", "stored"),
    [(100, np.uint8, np.float32), (100_000, np.uint32, np.float64)],
    ids=["8-bit", "32-bit"],
)
def test_a_sweep_of_counts_and_float_images_stores_both_exactly(tmp_path, photons, counts, stored):
    # an ICCD gain makes a point's image float32 beside the counts of a gain of 1; float32
    # holds counts exactly up to 2^24 only
    plan = tiny_plan(
        realisations=1,
        **{
            "target.shape: {values: [sphere, none]}": "noise.gain: {values: [1.0, 10.0]}",
            "white_plane_photons: 100": f"white_plane_photons: {photons}",
        },
    )
    kinds = [variables(scene)["image"].dtype for scene in plan.scenes]
    # depths 3 and 6 m, gains 1 and 10: the shallow target's counts are the widest
    assert kinds[0] == counts and kinds[1] == kinds[3] == np.float32
    url = str(tmp_path / "g.zarr")
    fill(plan, url)
    ds = xr.open_zarr(url)
    assert ds["image"].dtype == stored and "valid_max" not in ds["image"].attrs
    assert ds["image"].attrs["long_name"].startswith("by point: ICCD output count")
    assert "; or photoelectron count" in ds["image"].attrs["long_name"]
    for point, scene in enumerate(plan.scenes):
        alone = render(scene, seed=SampleSeed(root=4, point=point, realisation=0))
        assert np.array_equal(ds["image"].values[point], alone["image"].values)
    # the plan's size (limits, shard size) counts every point's image in the store's type
    stored_bytes = sum(ds[name].nbytes for name in rendered_order() if name in ds)
    assert plan.total_bytes() == stored_bytes
    assert plan.sample_bytes() == stored_bytes // plan.samples


def test_expected_images_are_stored_only_when_asked(filled, tmp_path):
    plan, url = filled
    assert "expected" not in xr.open_zarr(url)
    text = plan.text.replace("sweep:\n", "store: {expected: true}\nsweep:\n")
    with_expected = parse_sweep(text)
    assert with_expected.digest != plan.digest
    other = str(tmp_path / "e.zarr")
    fill(with_expected, other)
    ds, bare = xr.open_zarr(other), xr.open_zarr(url)
    alone = render(plan.scenes[1], seed=SampleSeed(root=4, point=1, realisation=2))
    assert ds["expected"].values[5].tobytes() == alone["expected"].values.tobytes()
    for name in ("image", "target_mask", "target_signal", "background_signal", "checksum"):
        if name != "checksum":
            assert ds[name].values.tobytes() == bare[name].values.tobytes(), name
    assert with_expected.sample_bytes() > plan.sample_bytes()
    # the training reader decodes the Blosc codecs of counts and of floats
    item = SampleDataset(other, arrays=("expected", "image"))[5]
    assert item["expected"].tobytes() == alone["expected"].values.tobytes()
    assert item["image"].tobytes() == alone["image"].values.tobytes()
    for value in ("maybe", "1"):
        bad = text.replace("expected: true", f"expected: {value}")
        with pytest.raises(Exception, match=r"store\.expected"):
            parse_sweep(bad)


def test_shards_fill_their_bytes_and_counts_are_compressed_by_shuffled_lz4(tmp_path, monkeypatch):
    plan = tiny_plan(realisations=50)  # 200 tiny samples: the shard count rule binds
    assert layout.shard_size(plan) == plan.samples // layout.MIN_SHARDS == 25
    assert layout.shard_size(plan, 3) == 3
    for realisations, size in ((5, 2), (1, 1), (1000, layout.MAX_SHARD_SAMPLES)):
        small = tiny_plan(realisations=realisations)  # 20: 10 shards; 4: 4; 4000: 16
        assert layout.shard_size(small) == size
        assert -(-small.samples // size) >= min(layout.MIN_SHARDS, small.samples)
    monkeypatch.setattr(layout, "SHARD_BYTES", 5 * plan.sample_bytes() + 1)
    assert layout.shard_size(plan) == 5
    url = str(tmp_path / "s.zarr")
    create_store(plan, Store(url))
    group = zarr.open_group(url, mode="r")
    assert layout.shard_samples(group) == 5 and group["image"].shards[0] == 5
    assert group["image"].dtype.kind == "u"
    for name in ("image", "target_mask"):
        blosc = group[name].compressors[0].to_dict()
        assert blosc["name"] == "blosc", name
        assert blosc["configuration"]["cname"] == "lz4", name
        assert blosc["configuration"]["shuffle"] == "bitshuffle", name
    assert group["target_signal"].compressors[0].to_dict()["name"] == "zstd"
    with_expected = parse_sweep(plan.text.replace("sweep:\n", "store: {expected: true}\nsweep:\n"))
    create_store(with_expected, Store(str(tmp_path / "e.zarr")))
    blosc = zarr.open_array(str(tmp_path / "e.zarr" / "expected")).compressors[0].to_dict()
    assert blosc["configuration"]["cname"] == "zstd"
    assert blosc["configuration"]["shuffle"] == "shuffle"
    assert len(shards.read_samples(group["image"], [4, 5])) == 2  # readable, unwritten


def test_one_task_per_shard_and_a_failed_shard_rerun_one_sample_at_a_time(
    tmp_path, monkeypatch, threads
):
    """No two tasks ever write one shard at once: each shard's writes are timed."""
    writes: dict[int, list] = {}
    lock = threading.Lock()
    original = shards.write_shard

    def timed(group, samples):
        started = time.monotonic()
        time.sleep(0.05)  # widen the window an overlap would need
        original(group, samples)
        with lock:
            writes.setdefault(min(samples) // 3, []).append((started, time.monotonic()))

    def poisoned(scene, *, seed):
        if (seed.point, seed.realisation) == (1, 1):
            raise RuntimeError("poison")
        return render_arrays(scene, seed=seed)

    monkeypatch.setattr(shards, "write_shard", timed)
    monkeypatch.setattr(service.tasks, "render_samples", batch_of(poisoned))
    plan = tiny_plan(realisations=3)
    url = str(tmp_path / "p.zarr")
    result = execute(
        plan, Store.at(url), workers=2, batch_size=3, progress_stream=open(os.devnull, "w")
    )
    # sample 4 (point 1, realisation 1) fails alone; 3 and 5 of its shard are written
    assert [(start, count) for start, count, _ in result.failed] == [(4, 1)]
    done = Store(url).completed()
    assert done.tolist() == [True] * 4 + [False] + [True] * 7
    assert len(writes[1]) == 2  # samples 3 and 5, one task each, after the failed shard
    for shard, spans in writes.items():
        spans.sort()
        for (_, end), (start, _) in itertools.pairwise(spans):
            assert start >= end, f"shard {shard} written by two tasks at once"
    monkeypatch.undo()
    reference = str(tmp_path / "r.zarr")
    fill(plan, reference, samples_per_shard=3)
    ours, theirs = xr.open_zarr(url), xr.open_zarr(reference)
    keep = np.flatnonzero(done)
    for name in ("image", "target_mask", "target_signal", "checksum"):
        assert ours[name].values[keep].tobytes() == theirs[name].values[keep].tobytes(), name
    # the failed sample stays at each array's fill value (NaN for the floats), not zeros
    # (a planted bug that wrote zeros survived the suite: issue #38's fifteen)
    group = zarr.open_group(url, mode="r")
    for name in ("target_signal", "background_signal", "target_effect_relative"):
        assert np.isnan(group[name].fill_value), name
        assert np.isnan(group[name][4]).all(), name


def test_a_shard_whose_task_is_given_up_goes_to_no_other_task(tmp_path, monkeypatch, threads):
    """A stuck task may still write its shard: its shard's other samples are not rerun."""
    renders: dict[int, int] = {}
    release = threading.Event()

    def frozen_then_poisoned(scene, *, seed):
        sample = seed.point * 3 + seed.realisation
        renders[sample] = renders.get(sample, 0) + 1
        if sample == 3 and renders[sample] > 1 + threads.RETRIES:
            release.wait(timeout=8)  # frozen in its own task, after the shard's task failed
        if sample == 4:
            raise RuntimeError("poison")
        return render_arrays(scene, seed=seed)

    monkeypatch.setattr(service.tasks, "render_samples", batch_of(frozen_then_poisoned))
    plan = tiny_plan(realisations=3)
    url = str(tmp_path / "s.zarr")
    result = execute(
        plan,
        Store.at(url),
        workers=1,
        batch_size=3,
        task_timeout=3.0,
        progress_stream=open(os.devnull, "w"),
    )
    release.set()
    # shard [3, 4, 5]: its task failed on 4; alone, 3 froze and was given up; 4 and 5 of
    # its shard were never given to another task
    assert result.stuck == [(3, 1), (4, 1), (5, 1)] and result.failed == []
    assert 5 not in renders
    done = Store(url).completed().tolist()  # 3: its own task may write it late
    assert done[:3] + done[4:] == [True] * 3 + [False, False] + [True] * 6


def test_open_dataset_selects_by_gate_and_groups_by_swept_parameters(filled):
    _, url = filled
    ds = open_dataset(url)
    assert ds["gate"].values.tolist() == [1]  # numbered as every picture counts (issue #27)
    assert ds.sel(gate=1).image.dims == ("sample", "frame", "y", "x")
    assert ds["frame"].values.tolist() == [0]
    depth = ds["target_depth"]
    assert isinstance(depth.data, np.ndarray)  # loaded: no .compute() needed
    assert depth.attrs["parameter"] == "target.depth" and depth.attrs["units"] == "m"
    assert ds["target_shape"].attrs["parameter"] == "target.shape"
    assert isinstance(ds["image"].data, type(xr.open_zarr(url)["image"].data))  # lazy
    means = ds["target_signal"].groupby("target_depth").mean(...)
    assert means["target_depth"].values.tolist() == [3.0, 6.0]
    deep = ds.isel(sample=ds["target_depth"] == 6.0)
    assert deep.sizes["sample"] == 6 and (deep["point"] >= 2).all()
    flags = ds["target_visibility"].attrs["flag_values"]
    assert flags.dtype == ds["target_visibility"].dtype == np.uint8
    assert ds["image"].attrs["valid_max"].dtype == ds["image"].dtype
    write_statistics(Store(url))
    stats = open_dataset(Store(url).stats.url)
    assert stats["gate"].values.tolist() == [1]
    assert stats.sel(gate=1)["target_contrast"].dims == ("point",)
    assert stats["target_depth"].attrs["parameter"] == "target.depth"


def test_a_cf_checker_passes_a_small_export_and_its_statistics(filled, tmp_path):
    _, url = filled
    exported = open_dataset(url).reset_index("sample")  # netCDF has no MultiIndex
    assert cf_failures(exported, tmp_path / "export.nc") == []
    stats = write_statistics(Store(url))  # issue #27: it had no history attribute
    assert cf_failures(open_dataset(stats.url), tmp_path / "stats.nc") == []


def test_a_store_whose_lock_is_held_is_listed_without_warnings(filled):
    # issue #27: the lock was a file in the store, and zarr warns of every file there that
    # is not part of the hierarchy whenever it lists the store's members
    _, url = filled
    with Store(url).lock(), warnings.catch_warnings():
        warnings.simplefilter("error")
        members = dict(zarr.open_group(url, mode="r", use_consolidated=False).members())
        unconsolidated = xr.open_zarr(url, consolidated=False)
    assert "image" in members and "image" in unconsolidated


def test_the_training_reader_returns_the_stores_samples(filled, tmp_path):
    plan, url = filled
    partial = str(tmp_path / "partial.zarr")
    create_store(plan, Store(partial), samples_per_shard=2)
    _, jobs = next(task_batches(plan, [2, 3], 2))
    render_shard(Store(partial), jobs)
    reader = SampleDataset(partial, labels=("target_present", "target_depth"))
    assert len(reader) == 2 and reader.sample_index.tolist() == [2, 3]
    ds = xr.open_zarr(url)
    item = reader[1]
    assert int(item["sample"]) == 3
    assert item["image"].tobytes() == ds["image"].values[3].tobytes()
    assert item["target_mask"].dtype == np.uint8 and item["target_depth"] == 3.0
    with pytest.raises(IndexError):
        reader[2]
    full = SampleDataset(url, arrays=("image",), labels=("target_visibility",))
    batch = full.__getitems__([7, 0, 11, 7])
    assert [int(b["sample"]) for b in batch] == [7, 0, 11, 7]
    for b in batch:
        assert b["image"].tobytes() == ds["image"].values[int(b["sample"])].tobytes()
        visibility = ds["target_visibility"].values[int(b["sample"])]
        assert b["target_visibility"].tolist() == visibility.tolist()
    again = pickle.loads(pickle.dumps(full))  # as a DataLoader hands it to a worker
    assert again._shards is None
    assert again[5]["image"].tobytes() == ds["image"].values[5].tobytes()
    with pytest.raises(KeyError, match="has no expected"):
        SampleDataset(url, arrays=("expected",))
    # a flipped byte in sample 2's chunk (shard 1, first chunk) fails its CRC32C, named
    shard = next(Path(partial, "target_mask").glob("c.1.*"))
    data = bytearray(shard.read_bytes())
    data[3] ^= 0x01
    shard.write_bytes(bytes(data))
    damaged = SampleDataset(partial)
    assert damaged[1]["image"].tobytes() == ds["image"].values[3].tobytes()
    with pytest.raises(DamagedStoreError, match="sample 2: its chunk of target_mask"):
        damaged[0]


def test_the_training_reader_returns_writable_arrays_of_their_own(filled):
    # issue #27 item 9: a DataLoader's default collate warns of read-only arrays (torch's
    # as_tensor), and changing an item's label must not change the labels held
    _, url = filled
    reader = SampleDataset(url, labels=("target_present", "target_visibility"))
    batch = reader.__getitems__([0, 3])  # a sphere, then no target
    for item in (*batch, reader[3]):
        for name in ("image", "target_mask", "target_visibility"):
            assert item[name].flags.writeable and item[name].flags.owndata, name
    stored = xr.open_zarr(url)["target_visibility"].values[0]
    batch[0]["target_visibility"][...] = 99
    batch[0]["image"][...] = 0
    assert reader[0]["target_visibility"].tolist() == stored.tolist()
    # what default_collate does with numpy items: one array per key, stacked
    collated = {name: np.stack([item[name] for item in batch]) for name in batch[0]}
    assert collated["image"].shape == (2, *reader[3]["image"].shape)
    assert collated["target_present"].tolist() == [1, 0]


def test_the_training_reader_converts_images_to_the_type_asked_for(filled):
    # uint32 counts, on which torch's mean and max fail, as float32 on request
    _, url = filled
    counts = SampleDataset(url)[3]
    floats = SampleDataset(url, image_dtype=np.float32)
    item = floats[3]
    assert counts["image"].dtype.kind == "u" and item["image"].dtype == np.float32
    assert np.array_equal(item["image"], counts["image"])
    assert item["target_mask"].dtype == np.uint8  # the mask as stored
    assert floats.__getitems__([3])[0]["image"].dtype == np.float32


def test_the_training_reader_refuses_positions_and_types_that_would_misread(filled):
    # issue #37 items 5 and 7: reader[1.5] and reader[True] returned sample 1, and an image
    # type narrower than the store's counts wrapped them silently
    _, url = filled
    reader = SampleDataset(url)
    for index in (1.5, True, np.float64(2.0), np.bool_(False)):
        with pytest.raises(TypeError, match="a SampleDataset index must be an integer"):
            reader[index]
    with pytest.raises(TypeError, match=r"must be an integer, got 1\.0"):
        reader.__getitems__([0, 1.0])
    assert int(reader[np.int64(1)]["sample"]) == 1 and int(reader[-1]["sample"]) == 11
    with pytest.raises(IndexError):
        reader[12]
    largest = zarr.open_array(Path(url, "image"), mode="r").attrs["valid_max"]
    assert largest > np.iinfo(np.int8).max
    with pytest.raises(
        ValueError,
        match=f"image_dtype int8: holds values up to 127, and the images counts up to {largest}",
    ):
        SampleDataset(url, image_dtype=np.int8)
    assert SampleDataset(url, image_dtype=np.uint16)[0]["image"].dtype == np.uint16


def test_an_edited_swept_coordinate_stops_the_readers(filled, tmp_path, cli):
    # issue #37 item 5: the labels and swept coordinates, which no sample's checksum covers,
    # are compared with the sweep's as info --verify compares them
    _, url = filled
    copy = tmp_path / "t.zarr"
    shutil.copytree(url, copy)
    with pytest.MonkeyPatch.context() as patch:  # intact: their checksum, no sweep parsed
        patch.setattr(integrity, "stored_plan", None)
        assert integrity.check_labels(Store(str(copy))) == ""
    depth = zarr.open_array(copy / "target_depth", mode="r+")
    depth[0] = 9.0
    with pytest.raises(DamagedStoreError, match="its target_depth differ from what its sweep"):
        SampleDataset(str(copy))
    result = cli("stats", copy, cwd=tmp_path)
    assert result.returncode == 1 and "its target_depth differ" in result.stderr
    assert "Traceback" not in result.stderr and not Path(tmp_path, "t.stats.zarr").exists()


def test_open_dataset_verified_marks_damaged_samples_incomplete(filled, tmp_path):
    # issue #37 item 4: the README's ds.isel(sample=ds.completed == 1) kept samples whose
    # chunks fail their CRC32C, or whose arrays are not theirs
    _, url = filled
    copy = tmp_path / "t.zarr"
    shutil.copytree(url, copy)
    shard = next(Path(copy, "target_mask").glob("c.1.*"))  # samples 2 and 3
    data = bytearray(shard.read_bytes())
    data[3] ^= 0x01  # sample 2's chunk
    shard.write_bytes(bytes(data))
    next(Path(copy, "image").glob("c.4.*")).unlink()  # samples 8 and 9
    assert open_dataset(str(copy)).completed.values.all()  # the flags as tasks set them
    with pytest.warns(UserWarning, match="samples 2, 8, 9 marked complete fail their checks"):
        ds = open_dataset(str(copy), verify=True)
    assert np.flatnonzero(ds.completed.values == 0).tolist() == [2, 8, 9]
    kept = ds.isel(sample=ds.completed == 1)
    assert kept.sizes["sample"] == 9
    intact = open_dataset(url)
    for name in ("image", "target_mask"):
        assert np.array_equal(kept[name].values, intact[name].values[ds.completed.values == 1])


@pytest.mark.parametrize("record", ["completed", "checksum_bound"])
def test_open_dataset_names_a_record_file_that_cannot_be_read(filled, tmp_path, record):
    # the issue #37 trial: a zero-length record file made open_dataset (verify or not)
    # raise zarr's "Stored and computed checksum do not match", naming nothing
    _, url = filled
    copy = tmp_path / "t.zarr"
    shutil.copytree(url, copy)
    Path(copy, record, "c.1").write_bytes(b"")
    for verify in (False, True):
        with pytest.raises(DamagedStoreError, match=rf"{record}/c\.1: cannot be read.*--resume"):
            open_dataset(str(copy), verify=verify)


def test_open_dataset_verified_says_which_completion_flags_are_lost(filled, tmp_path):
    # the issue #37 trial: a lost chunk of completion flags dropped its samples from the
    # README's recipe without a word, where info --verify and SampleDataset name them
    _, url = filled
    copy = tmp_path / "t.zarr"
    shutil.copytree(url, copy)
    Path(copy, "completed", "c.1").unlink()
    with pytest.warns(UserWarning, match="samples 2, 3 hold checksums but their completion"):
        ds = open_dataset(str(copy), verify=True)
    assert np.flatnonzero(ds.completed.values == 0).tolist() == [2, 3]


def test_an_image_type_too_narrow_is_refused_without_a_warning():
    # the issue #37 trial: float16 against counts up to 140 297 printed numpy's "overflow
    # encountered in cast" before the refusal
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="image_dtype float16: holds values up to"):
            image_type(np.float16, stored=np.dtype(np.uint32), largest=140_297)
        assert image_type(np.float32, stored=np.dtype(np.uint32), largest=140_297) == np.float32


def test_a_store_numbering_its_gates_from_0_is_refused_until_renumbered(filled, tmp_path, cli):
    # issue #27 item 4: stores written before it number their gates 0..N-1; read, resumed,
    # reduced or evaluated now they would mix the two numberings: refused with the remedy
    _, url = filled
    old = tmp_path / "t.zarr"
    shutil.copytree(url, old)
    gate = zarr.open_group(str(old), mode="r+")["gate"]
    gate[:] = gate[:] - 1
    sweep = tmp_path / "t.yaml"
    sweep.write_text(SWEEP.format(name="t", seed=4, realisations=3, output="t.zarr"))
    for reader in (open_dataset, SampleDataset):  # the training reader too (a trial's find)
        with pytest.raises(InputError, match=r"numbers its gates from 0.*renumber it in place"):
            reader(str(old))
    for command in (["stats", old], ["detect", old], ["info", old], ["run", sweep, "--resume"]):
        result = cli(*command, cwd=tmp_path)
        assert result.returncode == 2, command
        assert "numbers its gates from 0" in result.stderr and "Traceback" not in result.stderr
        assert "not an oceanlidar" not in result.stderr, command
    assert not Store(str(old)).stats.occupied()  # nothing written beside it
    # the remedy the message points to (README, "The dataset")
    group = zarr.open_group(str(old), mode="r+")
    group["gate"][:] = group["gate"][:] + 1
    assert open_dataset(str(old))["gate"].values.tolist() == [1]
    assert len(SampleDataset(str(old))) == Store(str(old)).completed().sum() > 0
    assert cli("stats", old, cwd=tmp_path).returncode == 0
    assert open_dataset(Store(str(old)).stats.url)["gate"].values.tolist() == [1]


def test_the_training_reader_reads_stores_of_zstd_shards(tmp_path, monkeypatch):
    # stores written before Blosc (November 2026) hold zstd shards
    monkeypatch.setattr(layout, "COUNT_CODECS", layout.CODECS)
    monkeypatch.setattr(layout, "FLOAT_CODECS", layout.CODECS)
    plan = tiny_plan(realisations=1)
    url = str(tmp_path / "z.zarr")
    fill(plan, url)
    assert zarr.open_array(f"{url}/image").compressors[0].to_dict()["name"] == "zstd"
    ds = xr.open_zarr(url)
    item = SampleDataset(url)[3]
    for name in ("image", "target_mask"):
        assert item[name].tobytes() == ds[name].values[3].tobytes(), name


def test_the_training_reader_refuses_shards_it_would_misread(filled, tmp_path):
    # zarr reads these layouts; the reader, which decodes the shard files itself, does not
    _, url = filled
    changes = {
        "index at the start": ("index_location", "start"),
        "big-endian index": (
            "index_codecs",
            [{"name": "bytes", "configuration": {"endian": "big"}}, {"name": "crc32c"}],
        ),
        "chunk files in folders": (
            "chunk_key_encoding",
            {"name": "default", "configuration": {"separator": "/"}},
        ),
    }
    for what, (key, value) in changes.items():
        copy = tmp_path / what.replace(" ", "-")
        shutil.copytree(url, copy)
        path = copy / "image" / "zarr.json"
        meta = json.loads(path.read_text())
        place = meta if key == "chunk_key_encoding" else meta["codecs"][0]["configuration"]
        place[key] = value
        path.write_text(json.dumps(meta))
        reader = SampleDataset(str(copy))
        with pytest.raises(ValueError, match=r"image is not stored in shards as service\.store"):
            reader[0]


def test_statistics_after_resume_recompute_only_the_points_written(tmp_path, cli, shared_cluster):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(SWEEP.format(name="s", seed=4, realisations=3, output="s.zarr"))
    command = ["run", sweep, "--workers", 1, "--batch", 3]
    assert cli(*command, cwd=tmp_path).returncode == 0
    stats = tmp_path / "s.stats.zarr"
    full = xr.open_zarr(stats).load()
    chunks = {p: p.stat().st_mtime_ns for p in stats.rglob("c.*")}
    Store.at(str(tmp_path / "s.zarr")).mark_incomplete([4, 5])  # point 1's samples
    time.sleep(0.01)
    result = cli(*command, "--resume", cwd=tmp_path)
    assert result.returncode == 0 and "wrote 2 samples" in result.stderr, result.stderr
    after = {p: p.stat().st_mtime_ns for p in stats.rglob("c.*")}
    touched = {p.relative_to(stats).as_posix() for p in chunks if after[p] != chunks[p]}
    # the statistics store stayed in place; only point 1's chunks were written again, and
    # point 0's, whose cnr_without_target reads its twin point 1's samples (issue #27), and
    # the one chunk of every point's sample count
    assert "samples/c.0" in touched
    touched.remove("samples/c.0")
    assert touched and all(name.split("/")[-1][:3] in ("c.0", "c.1") for name in touched)
    assert {"cnr_without_target/c.0.0", "image_mean/c.1.0.0.0"} <= touched
    again = xr.open_zarr(stats).load()
    for name in full.data_vars:
        assert full[name].values.tobytes() == again[name].values.tobytes(), name
    # an update stopped after writing its counts, before recording how complete it is:
    # the next one that has nothing to compute still records it (a review's find)
    Store(str(stats)).update_attributes(samples_complete=3)
    write_statistics(Store(str(tmp_path / "s.zarr")), points=np.array([], dtype=int))
    assert Store(str(stats)).attributes()["samples_complete"] == full.attrs["samples_complete"]
    # statistics damaged beyond their images: recomputed whole, and equal
    (stats / "samples" / "c.0").write_bytes(b"garbage")
    write_statistics(Store(str(tmp_path / "s.zarr")), points=np.array([1]))
    for name in full.data_vars:
        assert full[name].values.tobytes() == xr.open_zarr(stats)[name].values.tobytes()


def test_a_complete_store_resumes_reading_per_shard_not_per_sample(
    tmp_path, cli, shared_cluster, monkeypatch
):
    # two complete stores of two shards, with 4 and with 16 samples (and points) a shard:
    # a resume that has nothing to do reads the same from either (its flags a shard at a
    # time, the statistics' counts at once), never a chunk per sample or per point
    reads = {}
    for per_shard in (4, 16):
        depths = [3.0 + 0.1 * i for i in range(2 * per_shard)]
        sweep = tmp_path / f"d{per_shard}.yaml"
        sweep.write_text(
            TINY_SCENE.format(name="d", seed=2, realisations=1, output=f"d{per_shard}.zarr")
            + f"sweep:\n  parameters:\n    target.depth: {{values: {depths}}}\n"
        )
        command = ["run", sweep, "--workers", 1, "--batch", per_shard]
        assert cli(*command, cwd=tmp_path).returncode == 0
        keys = []
        with monkeypatch.context() as patch:
            for method in ("get", "get_partial_values"):
                counted = getattr(zarr.storage.LocalStore, method)

                async def count(self, key, *args, _counted=counted, _keys=keys, **kwargs):
                    _keys.append(key if isinstance(key, str) else "partial")
                    return await _counted(self, key, *args, **kwargs)

                patch.setattr(zarr.storage.LocalStore, method, count)
            result = cli(*command, "--resume", cwd=tmp_path)
        assert result.returncode == 0 and "wrote 0 samples" in result.stderr, result.stderr
        reads[per_shard] = sorted(keys)
    assert any(key.startswith("completed/c.") for key in reads[4]), reads[4]
    assert reads[4] == reads[16], reads


@pytest.mark.parametrize(
    "swept",
    ["platform.altitude: {values: [30.0, 40.0]}", "platform.nadir_deg: {values: [0.0, 10.0]}"],
    ids=["altitude", "nadir"],
)
def test_a_surface_saved_under_a_footprint_sweep_asks_for_an_explicit_spacing(swept):
    # the default spacing follows the footprint, so the stored grid would change shape;
    # the message says so rather than blaming surface.spacing, which the sweep leaves alone
    plan = parse_sweep(
        TINY_SCENE.format(name="f", seed=1, realisations=1, output="f.zarr").replace(
            "spacing: 0.1, ", ""
        )
        + f"  save_surface: true\nsweep:\n  parameters:\n    {swept}\n"
    )
    with pytest.raises(InputError) as error:
        template.check_uniform(plan)
    message = str(error.value)
    assert "default surface.spacing follows the receiver's footprint" in message
    for field in ("platform.altitude", "platform.nadir_deg", "receiver.field_of_view_deg"):
        assert field in message
    assert "set surface.spacing (and surface.coarse_patches) explicitly" in message
    assert "cannot vary" not in message
    fixed = parse_sweep(plan.text.replace("grid_size: 32,", "grid_size: 32, spacing: 0.1,"))
    template.check_uniform(fixed)  # with the spacing given the sweep is accepted


def test_a_swept_spacing_with_a_saved_surface_is_refused_by_name():
    plan = parse_sweep(
        TINY_SCENE.format(name="f", seed=1, realisations=1, output="f.zarr")
        + "  save_surface: true\nsweep:\n  parameters:\n"
        + "    surface.spacing: {values: [0.1, 0.2]}\n"
    )
    with pytest.raises(InputError, match=r"sweep.parameters.surface.spacing: cannot vary"):
        template.check_uniform(plan)
