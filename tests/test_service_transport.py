"""The service with the Monte Carlo renderer: `expected_stderr` stored, checked and read back."""

import os
import shutil

import numpy as np
import pytest
import xarray as xr
from conftest import assert_same_samples, on_cluster

from service.cli import main
from service.dataset import SampleDataset
from service.errors import InputError
from service.run import execute
from service.store import integrity
from service.store.location import Store
from service.sweep import parse_sweep
from workers.dataset.variables import rendered_order
from workers.render import render, render_arrays
from workers.settings.seeds import SampleSeed

SCENE = """\
name: {name}
seed: 5
realisations: {realisations}
output: {name}.zarr
scene:
  surface: {{spectrum: flat}}
  receiver: {{pixels: 16, gates: [[2.0, 6.0], [5.0, 9.0]]}}
  radiometry: {{mode: normalised, white_plane_photons: 100}}
  transport: {{method: monte_carlo, photons: 5000}}
store: {{expected: true}}
sweep:
  parameters:
"""
MONTE_CARLO = SCENE + "    target.shape: {{values: [sphere, none]}}\n"
"""Two points rendered by Monte Carlo, a sphere and no target."""
MIXED = MONTE_CARLO + "    transport.method: {{values: [small_angle, monte_carlo]}}\n"
"""Four points: the sphere and no target, each by both renderers (small-angle first)."""

QUIET = {"progress_stream": open(os.devnull, "w")}


def plan_of(text, name="t", realisations=2):
    return parse_sweep(text.format(name=name, realisations=realisations))


def methods(ds):
    """The renderer of every sample (or point), as str (zarr's strings read as StringDType)."""
    return np.array([str(value) for value in ds["transport_method"].values.tolist()])


@pytest.fixture(scope="module")
def mixed(tmp_path_factory, session_cluster):
    """The mixed sweep run on two workers (shards of two samples)."""
    plan = plan_of(MIXED, "mixed")
    url = str(tmp_path_factory.mktemp("mixed") / "mixed.zarr")
    assert len(session_cluster.nthreads()) == 2
    with on_cluster(session_cluster):
        result = execute(plan, Store.at(url), workers=2, batch_size=2, **QUIET)
    assert result.written == plan.samples == 8 and not result.failed and not result.rejected
    return plan, url


def test_sweeps_take_the_renderer_and_its_photons_as_parameters():
    plan = plan_of(MIXED)
    assert plan.swept == ("target.shape", "transport.method")
    assert [s.transport.method for s in plan.scenes] == ["small_angle", "monte_carlo"] * 2
    photons = plan_of(SCENE + "    transport.photons: {{values: [5000, 20000]}}\n")
    assert [s.transport.photons for s in photons.scenes] == [5000, 20000]
    for bad, field in (
        ("[small_angle, exact]", "transport.method"),
        ("[10]", "transport.photons"),
    ):
        text = SCENE + "    " + field + ": {{values: " + bad + "}}\n"
        with pytest.raises(InputError, match=f"scene.{field}"):
            plan_of(text)
    with pytest.raises(InputError, match="transport has"):
        plan_of(SCENE + "    transport.photon: {{values: [5000]}}\n")


def test_a_monte_carlo_sweep_stores_its_standard_error(tmp_path, capsys, shared_cluster):
    # without the noise-free images: `detect` renders them again, by Monte Carlo too
    text = MONTE_CARLO.replace("store: {{expected: true}}\n", "")
    sweep = tmp_path / "mc.yaml"
    sweep.write_text(text.format(name="mc", realisations=8))
    url = str(tmp_path / "mc.zarr")
    assert main(["run", str(sweep), "--output", url, "--workers", "1"]) == 0
    ds = xr.open_zarr(url)
    assert "expected" not in ds
    error = ds["expected_stderr"].values
    assert ds["expected_stderr"].dims == ds["image"].dims
    assert error.dtype == np.float32 and error.shape == ds["image"].shape
    assert np.isfinite(error).all() and (error >= 0).all()
    assert (error.max(axis=(1, 2, 3, 4)) > 0).all()  # every sample has a Monte Carlo error
    assert ds["expected_stderr"].attrs["long_name"].startswith("Monte Carlo standard error")
    assert ds["expected_stderr"].encoding["shards"] == ds["image"].encoding["shards"]
    # the stored error is the renderer's, bit for bit
    plan = plan_of(text, "mc", 8)
    for sample in (0, 7, 8, 15):
        address = plan.sample(sample)
        alone = render_arrays(address.scene, seed=address.seed)
        assert error[sample].tobytes() == alone["expected_stderr"].tobytes()
    # counted in the plan's bytes (limits, shard size)
    stored = sum(ds[name].nbytes for name in rendered_order() if name in ds)
    assert plan.total_bytes() == stored
    # the store's commands all take it
    capsys.readouterr()
    assert main(["info", url, "--verify"]) == 0
    assert "verified: 16 of 16 complete samples read back intact" in capsys.readouterr().out
    assert main(["stats", url]) == 0
    assert xr.open_zarr(Store(url).stats.url)["samples"].values.tolist() == [8, 8]
    assert main(["preview", url, "--sample", "1", "--output", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").stat().st_size > 0
    assert main(["detect", url]) == 0
    detection = xr.open_zarr(str(tmp_path / "mc.detect.zarr"))
    assert detection.attrs["expected_images"] == "rendered again"
    assert np.isfinite(detection["auc"].values).all()


def test_a_mixed_sweep_stores_zero_error_at_its_small_angle_points(mixed):
    plan, url = mixed
    ds = xr.open_zarr(url)
    kind = methods(ds)
    assert kind.tolist() == (["small_angle"] * 2 + ["monte_carlo"] * 2) * 2
    error = ds["expected_stderr"].values
    small = kind == "small_angle"
    assert error[small].tobytes() == np.zeros_like(error[small]).tobytes()
    assert np.isfinite(error).all() and (error >= 0).all()
    assert (error[~small].max(axis=(1, 2, 3, 4)) > 0).all()
    assert (
        "0 for samples rendered by the small-angle renderer"
        in (ds["expected_stderr"].attrs["comment"])
    )
    stored = sum(ds[name].nbytes for name in rendered_order() if name in ds)
    assert plan.total_bytes() == stored
    # every sample otherwise as rendered alone; the small-angle renderer has no such output
    for sample in (1, 3, 4):
        address = plan.sample(sample)
        alone = render(address.scene, seed=address.seed)
        for name in ("expected", "target_mask", "target_signal"):
            assert ds[name].values[sample].tobytes() == alone[name].values.tobytes(), name
        # the store's counts are of the widest type its points need (uint32: Monte Carlo)
        assert ds["image"].dtype == np.uint32
        np.testing.assert_array_equal(ds["image"].values[sample], alone["image"].values)
        assert ("expected_stderr" in alone) == (not small[sample])
        if not small[sample]:
            assert error[sample].tobytes() == alone["expected_stderr"].values.tobytes()
    # the checksums cover the error; the training reader decodes it
    assert integrity.verify(Store(url)) == []
    item = SampleDataset(url, arrays=("expected_stderr", "image"))[3]
    assert item["expected_stderr"].tobytes() == error[3].tobytes()
    stats = xr.open_zarr(Store(url).stats.url)
    assert stats["samples"].values.tolist() == [2, 2, 2, 2]
    assert methods(stats).tolist() == ["small_angle", "monte_carlo"] * 2


def test_an_error_chunk_changed_after_its_sample_was_written_is_found(mixed, tmp_path):
    _, url = mixed
    copy = str(tmp_path / "mixed.zarr")
    shutil.copytree(url, copy)  # the module's store stays intact
    group = Store(copy).group("r+")
    values = group["expected_stderr"][3]
    values[0, 0, 0, 0] += 1.0
    group["expected_stderr"][3] = values  # a valid chunk, but not the checksum's
    assert integrity.verify(Store(copy)) == [(3, "its chunks do not match its checksum")]


def test_one_and_two_workers_write_the_same_bytes(mixed, tmp_path):
    plan, url = mixed
    other = str(tmp_path / "mixed.zarr")  # same name: statistics record their store's name
    execute(plan, Store.at(other), workers=1, batch_size=3, **QUIET)
    assert_same_samples(url, other, names=None)
    assert_same_samples(Store(url).stats.url, Store(other).stats.url, names=None)


def test_invalid_errors_are_never_stored():
    plan = plan_of(MONTE_CARLO)
    scene = plan.scenes[0]
    arrays = render_arrays(scene, seed=SampleSeed(root=5, point=0, realisation=0))
    assert integrity.invalid_values(arrays, scene) is None
    for bad, reason in ((np.nan, "non-finite"), (-1.0, "negative")):
        spoiled = {**arrays, "expected_stderr": arrays["expected_stderr"].copy()}
        spoiled["expected_stderr"][0, 0, 0, 0] = bad
        assert f"expected_stderr holds 1 {reason} value" in integrity.invalid_values(
            spoiled, scene
        )


def test_the_plan_counts_the_error_of_every_sample_once_any_point_needs_it():
    fast = plan_of(MONTE_CARLO.replace("method: monte_carlo", "method: small_angle"))
    pixels = 2 * 16 * 16  # two gates of 16 x 16 pixels
    error = 4 * pixels  # float32
    for text in (MONTE_CARLO, MIXED):
        plan = plan_of(text)
        # Monte Carlo counts are uint32 (`count_dtype`), the store's image the widest
        assert plan.image_dtype() == np.uint32
        wider = (4 - fast.image_dtype().itemsize) * pixels
        assert plan.sample_bytes() == fast.sample_bytes() + error + wider
