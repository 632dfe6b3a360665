"""Training without disk: `SweepStream` renders what the store holds, once per item."""

import itertools

import numpy as np
import pytest
from conftest import TINY_SCENE, TINY_SWEEP, on_cluster
from torch.utils.data import DataLoader

from service.cli import main
from service.dataset import SampleDataset
from service.stream import SweepStream
from service.sweep import load_sweep

NAMES = ("image", "target_mask", "target_present", "target_visibility")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, session_cluster):
    """A tiny sweep of 2 points x 5 realisations, and its store written by `run`."""
    folder = tmp_path_factory.mktemp("stream")
    path = folder / "sweep.yaml"
    output = folder / "tiny.zarr"
    path.write_text(TINY_SWEEP.format(name="tiny", seed=11, realisations=5, output=output))
    with on_cluster(session_cluster):
        assert main(["run", str(path), "--workers", "1"]) == 0
    return load_sweep(path), str(output)


def test_items_are_the_stores_samples_byte_for_byte(sweep):
    plan, store = sweep
    stream = SweepStream(plan, realisations=plan.realisations, arrays=NAMES[:2], labels=NAMES[2:])
    stored = SampleDataset(store, arrays=NAMES[:2], labels=NAMES[2:])
    items = list(stream)
    assert len(items) == len(stream) == len(stored) == 10
    for item in items:
        sample = int(item["sample"])
        assert sample == item["point"] * plan.realisations + item["realisation"]
        reference = stored[sample]  # every sample written: item i is sample i
        for name in NAMES:
            a, b = np.asarray(item[name]), np.asarray(reference[name])
            assert (a.dtype, a.shape, a.tobytes()) == (b.dtype, b.shape, b.tobytes()), name
    # realisation by realisation: both points of realisation 0 first, in a seeded order
    assert [int(i["realisation"]) for i in items] == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4]
    for r in range(5):
        assert [int(i["point"]) for i in items[2 * r : 2 * r + 2]] == list(stream.order(r))
    in_order = SweepStream(plan, realisations=2, arrays=(), labels=(), shuffle=False)
    assert [(int(i["point"]), int(i["realisation"])) for i in in_order] == [
        (0, 0),
        (1, 0),
        (0, 1),
        (1, 1),
    ]


def test_workers_share_the_items_without_duplicates(sweep):
    plan, _ = sweep
    stream = SweepStream(plan, realisations=3, first=1, arrays=("image",), labels=())
    loader = DataLoader(stream, batch_size=None, num_workers=2)
    seen = [(int(item["point"]), int(item["realisation"])) for item in loader]
    assert len(seen) == len(set(seen)) == 6
    assert set(seen) == set(itertools.product(range(2), range(1, 4)))


def test_an_endless_stream_draws_fresh_realisations(sweep):
    plan, store = sweep
    stream = SweepStream(plan, points=[0], first=plan.realisations, realisations=None)
    with pytest.raises(TypeError, match="no length"):
        len(stream)
    fresh = list(itertools.islice(stream, 12))  # beyond any count the sweep knows
    assert [int(i["realisation"]) for i in fresh] == list(range(5, 17))
    assert all(int(i["sample"]) == -1 for i in fresh)
    images = [i["image"].tobytes() for i in fresh]
    stored = SampleDataset(store, arrays=("image",), labels=())
    known = {stored[s]["image"].tobytes() for s in range(plan.realisations)}
    assert len(set(images)) == 12 and not set(images) & known
    # the same seed scheme: realisation 7 again is the same sample
    again = SweepStream(plan, points=[0], first=7, realisations=1)
    assert next(iter(again))["image"].tobytes() == images[2]


def test_bad_arguments_name_themselves(sweep):
    plan, _ = sweep
    with pytest.raises(ValueError, match="points"):
        SweepStream(plan, points=[2])
    with pytest.raises(ValueError, match="realisations"):
        SweepStream(plan, realisations=0)
    with pytest.raises(KeyError, match="surface_elevation"):
        SweepStream(plan, arrays=("surface_elevation",))


def test_a_backend_that_cannot_render_is_refused_as_the_stream_is_made(tmp_path):
    # issue #39 item 5: a bad device or a Monte Carlo point on torch was found only when an
    # item rendered (in a DataLoader's worker); now as the stream is made, the field named
    import torch

    from service.sweep import parse_sweep

    text = TINY_SWEEP.format(name="t", seed=1, realisations=2, output="t.zarr")
    plan = parse_sweep(text)
    with pytest.raises(ValueError, match=r"^device: 'tpu' is neither 'cpu' nor 'cuda'"):
        SweepStream(plan, device="tpu")
    with pytest.raises(ValueError, match=r"^device: the numpy backend runs on the cpu"):
        SweepStream(plan, backend="numpy", device="cuda:0")
    if not torch.cuda.is_available():  # a CUDA device implies torch, as --device does
        with pytest.raises(ValueError, match=r"^device: 'cuda' asked, but this machine has no"):
            SweepStream(plan, device="cuda")
    carlo = parse_sweep(
        text.replace(
            "target.shape: {values: [sphere, none]}",
            "transport.method: {values: [small_angle, monte_carlo]}",
        )
    )
    with pytest.raises(ValueError, match="--backend torch: point 1 renders by Monte Carlo"):
        SweepStream(carlo, backend="torch")
    SweepStream(carlo, backend="torch", points=[0])  # the points drawn only


def test_items_render_on_the_backend_chosen(tmp_path):
    # torch's items are those `render_arrays` gives on torch (its own noise), byte for byte
    from service.sweep import parse_sweep
    from workers.render import render_arrays
    from workers.settings.seeds import SampleSeed

    plan = parse_sweep(TINY_SWEEP.format(name="t", seed=1, realisations=1, output="t.zarr"))
    stream = SweepStream(
        plan, realisations=1, arrays=("image",), labels=(), shuffle=False, backend="torch"
    )
    for item in stream:
        point = int(item["point"])
        seed = SampleSeed(root=1, point=point, realisation=0)
        on_torch = render_arrays(plan.scenes[point], seed=seed, backend="torch")
        on_numpy = render_arrays(plan.scenes[point], seed=seed)
        assert item["image"].tobytes() == on_torch["image"].tobytes()
        assert item["image"].tobytes() != on_numpy["image"].tobytes()


def test_positions_and_image_types_that_would_misread_are_refused(sweep):
    # issue #37 items 5 and 7: points=[0.7] rendered point 0, realisations=2.5 failed later,
    # and an image type narrower than the counts wrapped them (3434 as uint8: 106)
    plan, _ = sweep
    for options, name in (
        ({"points": [0.7]}, "points' entries"),
        ({"points": [True]}, "points' entries"),
        ({"realisations": 2.5}, "realisations"),
        ({"first": 1.0}, "first"),
    ):
        with pytest.raises(TypeError, match=f"{name} must be an integer"):
            SweepStream(plan, **options)
    assert SweepStream(plan, points=[np.int64(1)], realisations=np.int32(2)).points == (1,)
    largest = SweepStream(plan).dtypes["image"]
    with pytest.raises(ValueError, match="image_dtype int8: holds values up to 127"):
        SweepStream(plan, image_dtype=np.int8)
    assert np.iinfo(largest).max > 127
    assert SweepStream(plan, image_dtype=np.float32).dtypes["image"] == np.float32


DETECTION_GRID = """\
sweep:
  method: grid
  parameters:
    target.depth: {values: [3.0, 6.0, 9.0]}
    surface.wind_speed: {values: [3.0, 10.0]}
    water.preset: {values: [clear_ocean, coastal]}
    target.shape: {values: [sphere, none]}
"""
"""`configs/detection-study.yaml`'s grid: 24 points, the target's presence alternating."""


def test_workers_batches_mix_the_labels(tmp_path):
    # issue #37 item 3: worker k of 2 took items k, k + 2, ... in point order, so every
    # batch was all targets or none. Now each realisation's 24 points come in a seeded
    # order: a batch of 8 of one worker is 8 of a random 12 of them, all one label with
    # probability about 2 C(12,8)/C(24,8) = 0.0013 (seed fixed: the same batches each time)
    path = tmp_path / "grid.yaml"
    text = TINY_SCENE.format(name="grid", seed=7, realisations=2, output="grid.zarr")
    path.write_text(text + DETECTION_GRID)
    stream = SweepStream(path, realisations=2, arrays=(), labels=("target_present",))
    loader = DataLoader(stream, batch_size=8, num_workers=2)
    batches = [(b["target_present"].tolist(), b["point"].tolist()) for b in loader]
    assert len(batches) == 6 and all(len(set(present)) == 2 for present, _ in batches)
    seen = sorted(p for _, points in batches for p in points)
    assert seen == sorted(list(range(24)) * 2)  # every item once
    # the sequence is the workers' in turn: a loader without batches gives it whatever
    # its workers; another epoch, another order of the same items
    sequence = [(int(i["point"]), int(i["realisation"])) for i in stream]
    loaded = DataLoader(stream, batch_size=None, num_workers=2)
    assert [(int(i["point"]), int(i["realisation"])) for i in loaded] == sequence
    stream.set_epoch(1)
    again = [(int(i["point"]), int(i["realisation"])) for i in stream]
    assert again != sequence and sorted(again) == sorted(sequence)
    with pytest.raises(ValueError, match="epoch"):
        stream.set_epoch(-1)
