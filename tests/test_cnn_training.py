"""`detect --cnn`'s training: its options, fresh samples, the pairs it trains on, its progress."""

import contextlib
import shutil

import numpy as np
import pytest
import xarray as xr
import zarr
from conftest import on_cluster
from test_cnn import SWEEP as CNN_SWEEP

from service.cli import main
from service.cnn import point_conditions
from service.detect import pair_points, write_detection
from service.errors import BadOptionError
from service.store.location import Store
from service.stream import SweepStream
from workers.detectors.cnn import CnnSettings

SWEEP = CNN_SWEEP.replace("name: cnn", "name: cnn-training").replace("seed: 7", "seed: 11")
SWEEP = SWEEP.replace("realisations: 120", "realisations: 24")
"""Tiny samples of a bright sphere at two depths in two waters, each with its twin: 4 pairs,
12 training and 12 held-out realisations a point."""

REALISATIONS = 24
QUICK = CnnSettings(epochs=2, batch_size=16)
"""Two epochs: seconds; what is tested is what the network is fed, not how well it learns."""
FRESH = 5
"""Fresh realisations a training point."""


@pytest.fixture(scope="module")
def store(tmp_path_factory, session_cluster):
    folder = tmp_path_factory.mktemp("cnn-training")
    sweep = folder / "sweep.yaml"
    sweep.write_text(SWEEP.format(output=folder / "cnn.zarr"))
    with on_cluster(session_cluster):
        assert main(["run", str(sweep), "--workers", "1"]) == 0
    return Store.at(str(folder / "cnn.zarr"))


def detect(store, folder, name, **options):
    output = Store.at(str(folder / f"{name}.detect.zarr"))
    write_detection(store, output=output, cnn=QUICK, **options)
    return xr.open_zarr(output.url).load()


@pytest.fixture(scope="module")
def baseline(store, tmp_path_factory):
    return detect(store, tmp_path_factory.mktemp("base"), "base")


@pytest.fixture(scope="module")
def rendered():
    """The (point, realisation) of every sample `SweepStream` renders while it is on."""
    return []


@contextlib.contextmanager
def spying(rendered):
    """`SweepStream.item` recording each (point, realisation) it renders into `rendered`."""
    original = SweepStream.item

    def spied(self, *, point, realisation):
        rendered.append((point, realisation))
        return original(self, point=point, realisation=realisation)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(SweepStream, "item", spied)
        yield


@pytest.fixture(scope="module")
def fresh(store, tmp_path_factory, rendered):
    with spying(rendered):
        return detect(store, tmp_path_factory.mktemp("fresh"), "fresh", samples=FRESH)


def cnn_scores(detection):
    return np.stack(
        [detection[n].sel(detector="cnn").values for n in ("score_positive", "score_negative")]
    )


def test_fresh_samples_are_none_of_the_stores_and_change_the_model(fresh, baseline, rendered):
    # FRESH realisations of every point (all 8 train), from the sweep's count on: seas and
    # noise the store does not hold
    assert sorted(rendered) == [
        (point, realisation)
        for point in range(8)
        for realisation in range(REALISATIONS, REALISATIONS + FRESH)
    ]
    assert fresh.attrs["cnn_fresh_samples"] == FRESH
    # each point's 12 training realisations, and its 5 fresh ones
    assert baseline.attrs["cnn_training_samples"] == 8 * 12
    assert fresh.attrs["cnn_training_samples"] == 8 * (12 + FRESH)
    a, b = cnn_scores(baseline), cnn_scores(fresh)
    held = ~np.isnan(a)
    assert np.array_equal(held, ~np.isnan(b))
    assert np.abs(a[held] - b[held]).max() > 1e-3  # another model


def test_fresh_samples_repeat_bytes_for_bytes(store, fresh, tmp_path):
    again = detect(store, tmp_path, "again", samples=FRESH)
    assert cnn_scores(again).tobytes() == cnn_scores(fresh).tobytes()
    assert again["auc"].values.tobytes() == fresh["auc"].values.tobytes()


def test_fresh_samples_rendered_in_processes_are_the_same_bytes(store, fresh, tmp_path):
    spread = detect(store, tmp_path, "spread", samples=FRESH, render_workers=2)
    assert cnn_scores(spread).tobytes() == cnn_scores(fresh).tobytes()


def test_train_on_trains_on_the_matching_pairs_only(store, baseline, tmp_path, rendered):
    rendered.clear()
    with spying(rendered):
        clear = detect(store, tmp_path, "clear", samples=1, train_on=["water.preset=clear_ocean"])
    water = [str(value) for value in clear["water_preset"].values.tolist()]
    assert clear["cnn_trained"].values.tolist() == [int(w == "clear_ocean") for w in water]
    assert baseline["cnn_trained"].values.tolist() == [1] * 4
    assert clear.attrs["cnn_trained_on"] == ["water.preset=clear_ocean"]
    assert baseline.attrs["cnn_trained_on"] == "every pair"
    # half the pairs: half the training samples, fresh ones of their points only
    assert clear.attrs["cnn_training_samples"] == 4 * (12 + 1)
    ds = store.dataset()
    clear_points = {
        p for p in range(8) if str(ds["water_preset"].values[p * REALISATIONS]) == "clear_ocean"
    }
    assert {point for point, _ in rendered} == clear_points
    # every pair scored, by another model than the one trained on every pair
    held = ~np.isnan(cnn_scores(baseline))
    assert np.array_equal(held, ~np.isnan(cnn_scores(clear)))
    assert np.abs(cnn_scores(clear)[held] - cnn_scores(baseline)[held]).max() > 1e-3


def test_a_network_trained_in_one_water_is_not_told_of_another(store):
    # the water it trained in is the only one it knows: its columns are dropped, so a pair
    # in coastal water is described exactly as the clear-water pair at its depth
    ds = store.dataset()
    pairs, _ = pair_points(ds)
    every = point_conditions(ds, pairs)
    assert every.names == ("target.depth", "water.preset=clear_ocean", "water.preset=coastal")
    depth = every.values[:, 0]
    assert sorted(depth.tolist()) == [-1.0, -1.0, 1.0, 1.0]  # standardised over the pairs
    clear = point_conditions(ds, pairs, train_on=["water.preset=clear_ocean"])
    assert clear.names == ("target.depth",)
    np.testing.assert_array_equal(clear.values[:, 0], depth)
    first = np.array([p for p, _ in pairs]) * REALISATIONS
    water = [str(value) for value in ds["water_preset"].values[first].tolist()]
    assert clear.training.tolist() == [w == "clear_ocean" for w in water]
    both = point_conditions(ds, pairs, train_on=["target.depth=1.5", "water.preset=coastal"])
    assert both.training.sum() == 1 and both.names == ()


@pytest.mark.parametrize(
    ("selection", "reason"),
    [
        ("surface.wind_speed=3", "not a swept parameter"),
        ("target.shape=sphere", "target.shape is the label"),
        ("target.depth=9", "no paired point has that value"),
        ("target.depth=deep", "takes numbers"),
        ("water.preset=muddy", "no paired point has that value"),
    ],
)
def test_train_on_refuses_what_the_store_does_not_sweep(store, selection, reason):
    ds = store.dataset()
    pairs, _ = pair_points(ds)
    with pytest.raises(BadOptionError, match=reason) as refused:
        point_conditions(ds, pairs, train_on=[selection])
    assert f"--train-on {selection}" in str(refused.value)


def exit_code(argv) -> int:
    try:
        return main(argv)
    except SystemExit as stop:  # argparse's refusal
        return stop.code


@pytest.mark.parametrize(
    ("options", "reason"),
    [
        (["--epochs", "0"], "--epochs: must be at least 1"),
        (["--epochs", "2.5"], "--epochs: not a whole number"),
        (["--samples", "-1"], "--samples: must be at least 0"),
        (["--batch-size", "0"], "--batch-size: must be at least 1"),
        (["--seed", "x"], "--seed: not a whole number"),
        (["--device", "tpu"], "--device: 'tpu' is neither"),
        (["--device", "cuda:99"], "--device: 'cuda:99' asked, but this machine has"),
        (["--train-on", "windy"], "--train-on: give PATH=VALUE"),
        (["--train-on", "surface.wind_speed=3"], "--train-on surface.wind_speed=3: "),
        (["--train-on", "target.depth=9"], "--train-on target.depth=9: no paired point"),
    ],
)
def test_bad_training_options_exit_2_naming_them(store, tmp_path, capsys, options, reason):
    output = tmp_path / "bad.detect.zarr"
    assert exit_code(["detect", store.url, "--cnn", "--output", str(output), *options]) == 2
    err = capsys.readouterr().err
    assert reason in err and "Traceback" not in err
    assert not output.exists()


@pytest.mark.parametrize(
    "options",
    [
        ["--epochs", "3"],
        ["--samples", "10"],
        ["--batch-size", "8"],
        ["--device", "cpu"],
        ["--seed", "1"],
        ["--train-on", "target.depth=1.5"],
    ],
)
def test_training_options_need_cnn(store, tmp_path, capsys, options):
    output = tmp_path / "no-cnn.detect.zarr"
    assert exit_code(["detect", store.url, "--output", str(output), *options]) == 2
    err = capsys.readouterr().err
    assert f"{options[0]} sets the trained network's training: it needs --cnn" in err
    assert "Traceback" not in err
    assert not output.exists()


def test_detect_says_how_long_training_takes_then_shows_it(store, tmp_path, capsys):
    output = tmp_path / "shown.detect.zarr"
    argv = ["detect", store.url, "--cnn", "--epochs", "2", "--samples", "2", "--device", "cpu"]
    assert main([*argv, "--batch-size", "16", "--seed", "3", "--output", str(output)]) == 0
    err = capsys.readouterr().err
    lines = err.splitlines()
    # 16 fresh samples rendered, counted; then the estimate before the first epoch
    assert any("16/16" in line and "fresh samples/s" in line for line in lines)
    estimate = next(i for i, line in enumerate(lines) if line.startswith("training: about "))
    assert lines[estimate].endswith("(2 epochs of 112 samples on cpu)")
    first = next(i for i, line in enumerate(lines) if line.startswith("epoch 1/2: loss "))
    assert estimate < first
    assert lines[first + 1].startswith("epoch 2/2: loss ")
    assert "elapsed" in lines[first + 1]
    summary = next(line for line in lines if "against the sea-marginal observer" in line)
    assert "AUC gap mean" in summary and "worst" in summary
    detection = xr.open_zarr(str(output))
    assert detection.attrs["cnn_epochs"] == 2 and detection.attrs["cnn_seed"] == 3
    assert detection.attrs["cnn_batch_size"] == 16
    # -q: none of it
    assert main([*argv, "--output", str(tmp_path / "quiet.detect.zarr"), "-q"]) == 0
    assert capsys.readouterr().err == ""


def test_fresh_samples_of_a_sweep_that_reads_otherwise_are_refused(store, tmp_path, capsys):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(store.url, copy)
    zarr.open_group(str(copy), mode="r+").attrs["sweep_sha256"] = "0" * 64
    output = tmp_path / "copy.detect.zarr"
    argv = ["detect", str(copy), "--cnn", "--samples", "2", "--output", str(output)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--samples 2 asks for fresh samples, and its sweep reads differently now" in err
    assert "Traceback" not in err and not output.exists()
