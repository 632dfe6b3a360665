"""Analysis through xarray (issue #27 item 5): `open_dataset` reads whole shards, indexes the
points, and the images carry the pixels' places on the sea."""

import json

import numpy as np
import pytest
import xarray as xr
import zarr
from numpy.testing import assert_allclose
from test_store import fill, tiny_plan

from service.dataset import open_dataset
from service.store import integrity
from service.store.location import Store
from service.store.template import template
from workers.dataset.labels import image_axes, sample_labels
from workers.settings.scene import Scene
from workers.setup.geometry import PinholeCamera

SHARD = 4
"""Samples per shard of the store below: 12 samples, 3 shards."""


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    plan = tiny_plan()
    url = str(tmp_path_factory.mktemp("analysis") / "t.zarr")
    fill(plan, url, samples_per_shard=SHARD)
    return plan, url


def test_open_dataset_reads_one_dask_chunk_per_shard(store):
    plan, url = store
    ds = open_dataset(url)
    plain = xr.open_zarr(url)
    shards = -(-plan.samples // SHARD)
    for name in ("image", "target_mask"):
        assert ds[name].chunks[0] == (SHARD,) * shards
        np.testing.assert_array_equal(ds[name].values, plain[name].values)
        assert ds[name].attrs.keys() == plain[name].attrs.keys()
    mean = ds["image"].isel(gate=0).mean(("sample", "frame"))
    assert len(mean.data.__dask_graph__()) <= 4 * shards
    np.testing.assert_allclose(mean.values, plain["image"].isel(gate=0).mean(("sample", "frame")))
    assert isinstance(ds["target_present"].data, np.ndarray)  # the labels loaded


def test_a_shard_never_written_reads_as_fill_values(tmp_path):
    plan = tiny_plan()
    url = str(tmp_path / "t.zarr")
    fill(plan, url, samples_per_shard=SHARD)
    (tmp_path / "t.zarr" / "image" / "c.1.0.0.0.0").unlink()  # as before its task ran
    ds, plain = open_dataset(url), xr.open_zarr(url)
    np.testing.assert_array_equal(ds["image"].values, plain["image"].values)
    assert (ds["image"][SHARD : 2 * SHARD] == 0).all() and ds["image"][:SHARD].any()


def test_the_sample_index_selects_a_point_and_realisation_and_groups_by_point(store):
    plan, url = store
    ds = open_dataset(url)
    plain = xr.open_zarr(url)["image"].values  # sample = point * realisations + realisation
    realisations = plan.realisations
    by_point = plain.reshape(len(plan.points), realisations, *plain.shape[1:])
    point = ds.sel(point=2)
    assert point["realisation"].values.tolist() == list(range(realisations))
    np.testing.assert_array_equal(point["image"].values, by_point[2])
    np.testing.assert_array_equal(ds.sel(point=2, realisation=1)["image"].values, by_point[2, 1])
    means = ds["image"].groupby("point").mean()
    assert means["point"].values.tolist() == list(range(len(plan.points)))
    np.testing.assert_allclose(means.values, by_point.mean(axis=1))
    grid = ds["image"].unstack("sample")
    np.testing.assert_array_equal(grid.transpose("point", "realisation", ...).values, by_point)
    assert ds.isel(sample=ds["completed"] == 1).sizes["sample"] == plan.samples


def test_pixels_y_x_are_where_their_lines_of_sight_meet_the_sea():
    scene = Scene.model_validate(
        {"platform": {"altitude": 50.0, "azimuth_deg": 0.0}, "receiver": {"pixels": 8}}
    )
    y, x = image_axes(scene)
    camera = PinholeCamera(
        position=(0.0, 0.0, 50.0),
        nadir=0.0,
        azimuth=0.0,
        field_of_view=np.radians(scene.receiver.field_of_view_deg),
        pixels=8,
    )
    points = np.stack(np.broadcast_arrays(x[None, :], y[:, None], 0.0), axis=-1)
    row, column = camera.pixel_of(*camera.project(points))
    np.testing.assert_allclose(row, np.arange(8)[:, None] + 0 * column, atol=1e-9)
    np.testing.assert_allclose(column, np.arange(8)[None, :] + 0 * row, atol=1e-9)
    # row 0 (the far edge, the top of preview's images) has the largest y
    assert y[0] > 0 > y[-1] and x[0] < 0 < x[-1]


@pytest.mark.parametrize(
    ("nadir", "azimuth", "pixels"),
    [(20.0, 0.0, 8), (35.0, 30.0, 9)],
    ids=["nadir20", "nadir35-azimuth30"],
)
def test_oblique_pixels_y_x_are_their_sea_points_seen_on_the_plane_across_the_boresight(
    nadir, azimuth, pixels
):
    # Issue #38 item 5 (a): the stored axes against geometry written here from first
    # principles. The optical axis b leaves the lens at `nadir` from the downward vertical,
    # towards compass `azimuth` (clockwise from north, +y); the image's right is
    # horizontal, its up completes the frame (docs/model.md §2, the paper's pan/tilt
    # pinhole). A pixel centre's line of sight is b + u right + w up, u and w its
    # offsets on the image plane at unit focal length. Each line meets the mean sea
    # (z = 0); the stored (y, x) are that sea point seen from the lens on the plane across
    # the boresight at its sea point (`image_axes`: exact on the sea at nadir, a
    # trapezium's image off it).
    altitude = 34.0
    scene = Scene.model_validate(
        {
            "surface": {"spectrum": "flat"},
            "platform": {"altitude": altitude, "nadir_deg": nadir, "azimuth_deg": azimuth},
            "receiver": {"pixels": pixels},
        }
    )
    theta, phi = np.radians(nadir), np.radians(azimuth)
    axis = np.array([np.sin(theta) * np.sin(phi), np.sin(theta) * np.cos(phi), -np.cos(theta)])
    right = np.array([np.cos(phi), -np.sin(phi), 0.0])
    up = np.cross(right, axis)  # towards the far edge, and above the optical axis
    assert up[2] > 0 and up[:2] @ axis[:2] > 0
    half = np.tan(0.5 * np.radians(scene.receiver.field_of_view_deg))
    offsets = (2 * np.arange(pixels) + 1 - pixels) / pixels * half  # pixel centres
    u, w = offsets[None, :], -offsets[:, None]  # row 0 is the far edge
    lines = axis + u[..., None] * right + w[..., None] * up  # (row, column, xyz)
    lens = np.array([0.0, 0.0, altitude])
    sea = lens + (altitude / -lines[..., 2])[..., None] * lines  # where each line meets z = 0
    centre = lens + altitude / np.cos(theta) * axis  # the boresight's sea point
    # each sea point seen from the lens, on the plane through `centre` across `axis`
    seen = lens + (((centre - lens) @ axis) / ((sea - lens) @ axis))[..., None] * (sea - lens)
    assert_allclose((seen - centre) @ axis, 0.0, atol=1e-12)
    labels = sample_labels(scene)
    y, x = labels["y"].values, labels["x"].values
    grid = np.broadcast_to(x, (pixels, pixels)), np.broadcast_to(y[:, None], (pixels, pixels))
    assert_allclose((seen - centre) @ right, grid[0], rtol=1e-12, atol=1e-12)
    assert_allclose((seen - centre) @ up, grid[1], rtol=1e-12, atol=1e-12)
    # these lines are the renderer's (its camera: the paper's rotation matrix)
    camera = PinholeCamera(
        position=tuple(lens),
        nadir=theta,
        azimuth=phi,
        field_of_view=np.radians(scene.receiver.field_of_view_deg),
        pixels=pixels,
    )
    unit = lines / np.linalg.norm(lines, axis=-1, keepdims=True)
    assert_allclose(camera.pixel_directions(), unit, atol=1e-12)
    # on the sea itself: the middle row (odd N) lies along x, the middle column at
    # g cos θ / (1 + g sin θ cos θ / H) of its ground distance g from the centre
    if pixels % 2:
        middle = pixels // 2
        assert_allclose(sea[middle] - centre, x[:, None] * right, atol=1e-12)
        g = (sea[:, middle] - centre) @ np.array([np.sin(phi), np.cos(phi), 0.0])
        stretch = 1 + g * np.sin(theta) * np.cos(theta) / altitude
        assert_allclose(y, g * np.cos(theta) / stretch, rtol=1e-12, atol=1e-12)


def test_stores_and_samples_have_y_x_in_metres(store):
    plan, url = store
    expected = image_axes(plan.scenes[0])
    for ds in (open_dataset(url), xr.open_zarr(url)):
        for name, values in zip(("y", "x"), expected, strict=True):
            assert ds[name].attrs["units"] == "m"
            np.testing.assert_array_equal(ds[name].values, values)
        assert set(ds["image"].isel(sample=0, frame=0, gate=0).coords) >= {"y", "x"}


def test_a_sweep_varying_the_footprint_stores_no_pixel_places():
    plan = tiny_plan(
        **{"target.depth: {values: [3.0, 6.0]}": "platform.altitude: {values: [30.0, 40.0]}"}
    )
    ds, _ = template(plan, 2)
    assert "y" not in ds.coords and "x" not in ds.coords and ds.sizes["y"] == 8


def test_a_store_written_before_the_pixel_places_lacks_nothing(tmp_path):
    plan = tiny_plan(realisations=1)
    url = str(tmp_path / "old.zarr")
    fill(plan, url, samples_per_shard=2)
    group = zarr.open_group(url, mode="r+", zarr_format=3, use_consolidated=False)
    for name in ("y", "x"):
        del group[name]
    metadata = json.loads((tmp_path / "old.zarr" / "zarr.json").read_text())
    nested = metadata["consolidated_metadata"]["metadata"]
    for name in ("y", "x"):
        del nested[name]
    (tmp_path / "old.zarr" / "zarr.json").write_text(json.dumps(metadata))
    assert integrity.wrong_labels(Store(url), plan) == {}
    assert integrity.repair_labels(Store(url), plan) == []
    ds = open_dataset(url)
    assert "y" not in ds.coords and ds["image"].chunks[0] == (2, 2)
