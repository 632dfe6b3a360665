"""Pictures (preview, plot) and the paper's examples."""

import os
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from PIL import Image

import service.charts
import service.plots
from service.cli import main
from service.plots import DPI, PANEL_INCHES, preview_figure, render_preview
from service.run import execute
from service.store.location import Store
from service.sweep import load_sweep, parse_sweep

PAPER = Path(__file__).resolve().parent.parent / "configs" / "paper"


def image_axes(figure):
    return [ax for ax in figure.axes if ax.get_images()]


def test_preview_png_has_one_panel_per_gate_and_the_sea(tmp_path, capsys):
    target = tmp_path / "strip.png"
    assert main(["preview", str(PAPER / "mldc-strip.yaml"), "--output", str(target)]) == 0
    with Image.open(target) as picture:
        picture.verify()
    ds = render_preview(load_sweep(PAPER / "mldc-strip.yaml"), 0)
    figure = preview_figure(ds)
    with Image.open(target) as picture:  # 7 panels at the DPI that gives 128 pixels 256
        dpi = service.plots._legible_dpi(figure, pixels=128)
        assert dpi > DPI
        assert picture.size == (int(PANEL_INCHES * 7 * dpi), int((PANEL_INCHES + 0.6) * dpi))
    assert len(image_axes(figure)) == 7
    titles = [ax.get_title() for ax in image_axes(figure)]
    assert titles[0] == "gate 1: 3.7–9.8 m" and titles[-1].startswith("sea")
    # a gate's label is its coordinate, the ML(DC) camera number (issue #27), not its place
    assert ds["gate"].values.tolist() == [1, 2, 3, 4, 5, 6]
    titles = [ax.get_title() for ax in image_axes(preview_figure(ds.isel(gate=[2, 4])))]
    assert titles[:2] == ["gate 3: 6.1–12.2 m", "gate 5: 10.7–13.7 m"]
    # the colour bars say what the images count; the sea's axes carry their units
    bars = [ax for ax in figure.axes if ax not in image_axes(figure)]
    assert [bar.get_ylabel() for bar in bars[:6]] == ["photoelectrons"] * 6
    sea = image_axes(figure)[-1]
    assert (sea.get_xlabel(), sea.get_ylabel()) == ("x (m)", "y (m)")


def synthetic_sample(*, frames=1, gates=3, pixels=40, seed=0):
    """A sample with Poisson images (mean 100), a target mask, in gate 1 only."""
    rng = np.random.default_rng(seed)
    image = rng.poisson(100.0, size=(frames, gates, pixels, pixels)).astype(np.uint16)
    mask = np.zeros((frames, pixels, pixels), dtype=np.uint8)
    mask[:, 15:25, 15:25] = 1
    visibility = np.tile(np.resize(np.array([1, 3, 0], dtype=np.uint8), gates), (frames, 1))
    return xr.Dataset(
        {
            "image": (
                ("frame", "gate", "y", "x"),
                image,
                {"long_name": "photoelectron count with shot noise", "units": "1"},
            ),
            "target_mask": (("frame", "y", "x"), mask),
            "target_visibility": (("frame", "gate"), visibility),
        },
        coords={
            "gate": np.arange(1, gates + 1),
            "gate_top": ("gate", np.arange(gates) * 2.0),
            "gate_bottom": ("gate", np.arange(gates) * 2.0 + 3.0),
        },
    )


def test_a_few_hot_pixels_do_not_set_the_colour_scale():
    # issue #27 item 8: a caustic's few bright pixels set the top of the scale and drew
    # the rest of the gate black
    ds = synthetic_sample()
    ds["image"][0, 0, 3, 3:6] = 60000
    figure = preview_figure(ds)
    low, high = image_axes(figure)[0].get_images()[0].get_clim()
    assert 100 < high < 200  # Poisson(100)'s 99.5th percentile, not the hot pixels
    assert low == ds["image"][0, 0].values.min()
    # the full range is an option
    full = service.plots.colour_scales(ds["image"].values, clip=None)
    assert full[0, 1] == 60000


def test_the_mask_is_outlined_only_where_the_target_is_seen():
    # issue #27 item 8: the outline was drawn on every gate, also those the target is not in
    figure = preview_figure(synthetic_sample())
    outlined = [bool(ax.collections) for ax in image_axes(figure)]
    assert outlined == [True, False, False]  # visibility in_gate, unseen, none


def test_a_gif_has_one_scale_per_gate_shared_by_its_frames(tmp_path, monkeypatch):
    # issue #27 item 8: each frame of a GIF had each panel's own scale, so a climb's
    # frames did not compare (and the example 1 GIF showed a black disc)
    ds = synthetic_sample(frames=3)
    ds["image"][2] *= 4  # the last frame four times brighter
    drawn = []
    original = service.plots.preview_figure

    def spy(ds, *, frame, scales, **kwargs):
        drawn.append(np.array(scales))
        return original(ds, frame=frame, scales=scales, **kwargs)

    monkeypatch.setattr(service.plots, "preview_figure", spy)
    assert service.plots.save_preview(ds, str(tmp_path / "a.gif")) == 3
    assert len(drawn) == 3 and all(np.array_equal(s, drawn[0]) for s in drawn)
    images = ds["image"].values.astype(float)
    for g in range(3):
        assert drawn[0][g, 1] == pytest.approx(np.percentile(images[:, g], 99.5))
    assert drawn[0][0, 1] > 300  # the brighter frame's values are on the scale
    drawn.clear()
    service.plots.save_preview(ds, str(tmp_path / "b.gif"), shared_scale=True)
    assert all((s == s[0]).all() for s in drawn)  # one scale for every gate too


def test_preview_titles_round_the_swept_values():
    from service.cli.store_commands import _sample_title

    title = _sample_title("s", 3, 1, {"target.depth": 3.1415926535, "target.shape": "sphere"}, 0)
    assert title == "s, sample 3 (point 1: target.depth=3.142, target.shape=sphere; realisation 0)"


def test_preview_gif_animates_every_frame(tmp_path):
    target = tmp_path / "example1.gif"
    assert main(["preview", str(PAPER / "example1.yaml"), "--output", str(target)]) == 0
    with Image.open(target) as picture:
        assert picture.format == "GIF" and picture.n_frames == 26
        first = np.asarray(picture.convert("RGB"))
        picture.seek(25)
        last = np.asarray(picture.convert("RGB"))
    assert not np.array_equal(first, last)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--sample", "99"], "samples 0..7"),
        (["--output", "x.jpg"], ".png"),
    ],
    ids=["sample-out-of-range", "unknown-format"],
)
def test_preview_bad_arguments_exit_2(tmp_path, capsys, args, message):
    argv = ["preview", str(PAPER / "example3.yaml"), "--output", str(tmp_path / "x.png"), *args]
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_a_preview_that_cannot_be_written_is_refused_before_rendering(
    tmp_path, capsys, monkeypatch
):
    # a missing folder raised FileNotFoundError after rendering (issue #26 item 11)
    import service.plots

    monkeypatch.setattr(service.plots, "render_preview", lambda *a: pytest.fail("rendered"))
    monkeypatch.chdir(tmp_path)
    sweep = str(PAPER / "example3.yaml")
    for output, reason in [
        ("missing/p.png", "no folder"),
        (".", "a folder"),
        ("p.txt", "cannot write a .txt picture (write .png, .gif)"),
    ]:
        assert main(["preview", sweep, "--output", output]) == 2
        assert f"--output '{output}': {reason}" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_plot_draws_contrast_and_cnr_against_each_swept_parameter(
    tmp_path, shared_cluster, capsys, monkeypatch
):
    text = (PAPER / "example3.yaml").read_text()
    text = text.replace("grid_size: 256, spacing: 0.016", "grid_size: 64, spacing: 0.064")
    text = text.replace("pixels: 128", "pixels: 32").replace("realisations: 4", "realisations: 2")
    text = text.replace(
        "    target.shape: {values: [sphere, none]}",
        "    target.shape: {values: [sphere, none]}\n    target.depth: {values: [3.0, 5.0]}",
    )
    plan = parse_sweep(text)
    url = str(tmp_path / "s.zarr")
    execute(plan, Store.at(url), workers=1, progress_stream=open(os.devnull, "w"))
    target = tmp_path / "stats.png"
    figures, figure = [], service.plots.new_figure

    def kept(**size):
        figures.append(figure(**size))
        return figures[-1]

    monkeypatch.setattr(service.plots, "new_figure", kept)
    assert main(["plot", url, "--output", str(target)]) == 0
    # each gate named by its coordinate, numbered from 1 as in the store (issue #27)
    stats = Store(url).stats.dataset()
    assert stats["gate"].values.tolist() == list(range(1, stats.sizes["gate"] + 1))
    legend = figures[0].axes[0].get_legend()
    assert legend.get_title().get_text() == "gate"
    assert [text.get_text() for text in legend.get_texts()] == [
        f"{g}: {top:.1f}–{bottom:.1f} m"
        for g, top, bottom in zip(
            stats["gate"].values, stats.gate_top.values, stats.gate_bottom.values, strict=True
        )
    ]
    with Image.open(target) as picture:
        picture.verify()
    with Image.open(target) as picture:
        # one column: target.shape takes one value among the points with a target
        assert picture.size == (round(3.4 * 1 * DPI), round(5.4 * DPI))
    # a folder that is not there: bad input, no traceback (issue #26 item 11)
    monkeypatch.chdir(tmp_path)
    assert main(["plot", url, "--output", "missing/stats.png"]) == 2
    assert "--output 'missing/stats.png': no folder" in capsys.readouterr().err
    # an extension matplotlib cannot write: refused before drawing, naming those it can
    monkeypatch.setattr(service.charts, "plot_statistics", lambda *a: pytest.fail("drawn"))
    assert main(["plot", url, "--output", "stats.txt"]) == 2
    err = capsys.readouterr().err
    assert "--output 'stats.txt': cannot write a .txt picture (write " in err
    assert ".pdf" in err and ".png" in err and "Traceback" not in err
    assert not (tmp_path / "stats.txt").exists()


def expected_pair(config):
    plan = load_sweep(PAPER / config)
    with_mine = render_preview(plan, 0)  # point 0: sphere
    without = render_preview(plan, plan.realisations)  # point 1: none, same sea
    assert (
        with_mine.surface_elevation.values.tobytes() == without.surface_elevation.values.tobytes()
    )
    mask = with_mine.target_mask.values[0].astype(bool)
    assert mask.sum() > 20
    return with_mine.expected.values[0, 0], without.expected.values[0, 0], mask


def test_example3_the_mine_raises_the_signal_inside_its_mask():
    a, b, mask = expected_pair("example3.yaml")
    assert a[mask].mean() > 1.5 * b[mask].mean()
    assert np.allclose(a[~mask].mean(), b[~mask].mean(), rtol=0.1)


def test_example4_the_target_darkens_the_deeper_gate_inside_its_mask():
    a, b, mask = expected_pair("example4.yaml")
    assert a[mask].mean() < 0.7 * b[mask].mean()


@pytest.mark.parametrize("config", ["example1.yaml", "example2.yaml"])
def test_sequence_frames_evolve_with_the_sea_and_the_platform(config):
    ds = render_preview(load_sweep(PAPER / config), 0)
    z = ds.platform_z.values
    assert z[0] == 16.0 and np.all(np.diff(z) > 0)
    if config == "example1.yaml":
        assert z[-1] == pytest.approx(66.0)
        assert np.all(ds.platform_x.values == 0.0)
    else:
        assert np.all(np.diff(ds.platform_x.values) > 0)
    eta = ds.surface_elevation.values
    assert not np.array_equal(eta[0], eta[5])
    assert np.abs(eta).max() == pytest.approx(0.1, rel=1e-5)  # the paper's maximum elevation
    images = ds.expected.values[:, 0]
    assert not np.array_equal(images[0], images[1])


def test_statistics_of_an_incomplete_store_are_refused_unless_partial(
    tmp_path, shared_cluster, capsys, monkeypatch
):
    # issue #27 item 7: `stats` on a 4 %-complete store exited 0 without a word, and the
    # plot looked complete
    text = (PAPER / "example3.yaml").read_text()
    text = text.replace("grid_size: 256, spacing: 0.016", "grid_size: 64, spacing: 0.064")
    text = text.replace("pixels: 128", "pixels: 32").replace("realisations: 4", "realisations: 3")
    plan = parse_sweep(text)  # point 0: a sphere, point 1: none (its twin)
    url = str(tmp_path / "s.zarr")
    store = Store.at(url)
    execute(plan, store, workers=1, progress_stream=open(os.devnull, "w"))
    store.mark_incomplete([2, 5])
    capsys.readouterr()
    assert main(["stats", url]) == 2
    err = capsys.readouterr().err
    assert "4 of 6 samples (67 %) are complete" in err and "--partial" in err
    assert "Traceback" not in err
    assert main(["stats", url, "--partial"]) == 0
    out = capsys.readouterr().out
    assert "partial: the statistics of 4 of 6 samples (67 %)" in out
    stats = store.stats.dataset().load()
    assert (stats.attrs["samples_complete"], stats.attrs["samples_total"]) == (4, 6)
    assert stats["samples"].values.tolist() == [2, 2]
    # the plot's title names the store and how complete its statistics are
    drawn = []
    original = service.plots.new_figure
    monkeypatch.setattr(
        service.plots, "new_figure", lambda **k: drawn.append(original(**k)) or drawn[-1]
    )
    service.charts.plot_statistics(stats, str(tmp_path / "p.png"))
    title = " ".join(drawn[0]._suptitle.get_text().split())  # as wrapped to the width
    assert title == "s.zarr: statistics of 4 of 6 samples (67 %)"
    # the README's comparison: the target point's CNR without its target, read on its
    # twin's noisy images over the same masks, realisation by realisation (NaN before)
    from service.dataset import open_dataset
    from service.stats import contrast_to_noise

    ds = open_dataset(url)
    images, masks = ds["image"].values, ds["target_mask"].values.astype(bool)
    expected = np.nanmean(contrast_to_noise(images[[3, 4]], masks[[0, 1]]), axis=(0, 1))
    np.testing.assert_allclose(stats["cnr_without_target"][0], expected, rtol=1e-5)
    assert np.isfinite(expected).all()
    assert np.isnan(stats["cnr_without_target"][1]).all()  # no target: nothing to read
    assert (np.abs(stats["cnr"][0] - expected) > 0).any()
    # ... and the plot draws it beside the CNR, hollow
    hollow = [line for line in drawn[0].axes[1].lines if line.get_markerfacecolor() == "none"]
    assert np.nanmax(hollow[0].get_ydata()) == pytest.approx(float(expected[0]), rel=1e-5)
    # a resumed run completes the statistics in place, and their record with them
    execute(plan, store, workers=1, resume=True, progress_stream=open(os.devnull, "w"))
    stats = store.stats.dataset().load()
    assert (stats.attrs["samples_complete"], stats.attrs["samples_total"]) == (6, 6)
    assert stats["samples"].values.tolist() == [3, 3]
    assert service.charts.statistics_title(stats) == "s.zarr: statistics of 6 of 6 samples (100 %)"


def sample_with_sea(*, frames=3, pixels=128, gates=6):
    """`synthetic_sample` with a sea whose swell grows fourfold by the last frame."""
    ds = synthetic_sample(frames=frames, gates=gates, pixels=pixels)
    x = np.linspace(-2.0, 2.0, 32)
    swell = np.sin(x)[np.newaxis, :] * np.cos(x)[:, np.newaxis]
    growth = np.linspace(1.0, 4.0, frames)[:, np.newaxis, np.newaxis]
    return ds.assign(
        surface_elevation=(("frame", "sy", "sx"), 0.1 * growth * swell),
        platform_x=("frame", np.zeros(frames)),
        platform_y=("frame", np.zeros(frames)),
        platform_z=("frame", np.full(frames, 34.0)),
    ).assign_coords(sx=x, sy=x, time=("frame", 0.1 * np.arange(frames)))


def previews_drawn(monkeypatch) -> list:
    """The figures `service.plots.preview_figure` draws from now on, in order."""
    figures = []
    original = service.plots.preview_figure
    monkeypatch.setattr(
        service.plots,
        "preview_figure",
        lambda *a, **k: figures.append(original(*a, **k)) or figures[-1],
    )
    return figures


def test_a_preview_shows_every_image_pixel_or_the_dpi_asked(tmp_path, monkeypatch):
    # issue #37 item 19: six 128-pixel gates came out 1320 x 280 px, a gate's image about
    # 150 screen pixels for 128 (the target's outline in fragments), with no option; now
    # each image pixel takes 2 screen pixels across at least (`PIXEL_SIDE`)
    figures = previews_drawn(monkeypatch)
    ds = synthetic_sample(pixels=128, gates=6)
    service.plots.save_preview(ds, str(tmp_path / "a.png"))
    gates = image_axes(figures[0])
    assert len(gates) == 6 and all(ax.get_window_extent().width >= 2 * 128 for ax in gates)
    with Image.open(tmp_path / "a.png") as picture:
        assert picture.size[0] > PANEL_INCHES * 6 * DPI
    service.plots.save_preview(ds, str(tmp_path / "b.png"), dpi=50)
    with Image.open(tmp_path / "b.png") as picture:
        assert picture.size == (round(PANEL_INCHES * 6 * 50), round((PANEL_INCHES + 0.6) * 50))
    with pytest.raises(service.plots.BadOptionError, match="--dpi"):
        service.plots.save_preview(ds, str(tmp_path / "c.png"), dpi=0)


def test_a_gifs_sea_keeps_one_colour_scale(tmp_path, monkeypatch):
    # issue #37 item 19: the sea's scale was each frame's own, so a growing swell looked
    # the same from frame to frame; the gates' scales were shared already
    figures = previews_drawn(monkeypatch)
    ds = sample_with_sea(pixels=16, gates=2)
    assert service.plots.save_preview(ds, str(tmp_path / "a.gif"), dpi=40) == 3
    elevation = ds["surface_elevation"].values
    scales = [image_axes(figure)[-1].get_images()[0].get_clim() for figure in figures]
    assert scales == [(elevation.min(), elevation.max())] * 3
    figures.clear()  # a PNG's, its frame's
    service.plots.save_preview(ds, str(tmp_path / "a.png"), frame=0, dpi=40)
    assert image_axes(figures[0])[-1].get_images()[0].get_clim() == (
        elevation[0].min(),
        elevation[0].max(),
    )


def synthetic_statistics():
    """Statistics of 8 points, 2 gates: depth x water x shape, and a radius never swept."""
    depth, water, shape = (
        a.ravel()
        for a in np.meshgrid([3.0, 6.0], ["clear", "coastal"], ["sphere", "none"], indexing="ij")
    )
    rng = np.random.default_rng(1)
    present = (shape == "sphere")[:, np.newaxis]
    contrast = np.where(present, rng.uniform(1.0, 5.0, (8, 2)), np.nan)
    parameter = {
        "target_depth": (depth, "target.depth", "m"),
        "water_preset": (water, "water.preset", "1"),
        "target_shape": (shape, "target.shape", "1"),
        "target_radius": (np.full(8, 0.3), "target.radius", "m"),
    }
    return xr.Dataset(
        {
            **{
                name: ("point", v, {"parameter": p, "units": u})
                for name, (v, p, u) in parameter.items()
            },
            "target_contrast": (("point", "gate"), contrast),
            "cnr": (("point", "gate"), rng.uniform(0.0, 3.0, (8, 2))),
            "cnr_without_target": (
                ("point", "gate"),
                np.where(present, np.full((8, 2), 0.1), np.nan),
            ),
            "samples": ("point", np.full(8, 4)),
        },
        coords={
            "gate": [1, 2],
            "gate_top": ("gate", [1.0, 4.0]),
            "gate_bottom": ("gate", [5.0, 8.0]),
        },
        attrs={"samples_total": 32, "samples_store": "s.zarr"},
    )


def test_the_statistics_plot_names_each_combination_and_no_category_alone(tmp_path, monkeypatch):
    # issue #37 item 19: target.shape had a panel of one category (the twins measure no
    # contrast), "(1)" after a category's name, and points of other parameters' values
    # drawn alike with nothing to tell them apart
    drawn = []
    original = service.plots.new_figure
    monkeypatch.setattr(
        service.plots, "new_figure", lambda **k: drawn.append(original(**k)) or drawn[-1]
    )
    stats = synthetic_statistics()
    service.charts.plot_statistics(stats, str(tmp_path / "s.png"))
    axes = drawn[0].axes
    assert [ax.get_xlabel() for ax in axes] == ["target.depth (m)", "water.preset"] * 2
    assert [t.get_text() for t in axes[1].get_xticklabels()] == ["clear", "coastal"]
    # against depth, one line per water and gate, named in the CNR panel's legend
    legend = [t.get_text() for t in axes[2].get_legend().get_texts()]
    assert legend == ["preset=clear", "preset=coastal", "without the target"]
    lines = [
        line
        for line in axes[0].lines
        if len(line.get_xdata()) == 2 and line.get_marker() != "None"
    ]
    assert len(lines) == 4  # 2 gates x 2 waters
    for line in lines:
        gate = int(line.get_color()[1])
        water = "clear" if line.get_marker() == service.charts.MARKERS[0] else "coastal"
        rows = np.flatnonzero(
            (stats.water_preset.values == water) & (stats.target_shape.values == "sphere")
        )
        np.testing.assert_array_equal(line.get_xdata(), stats.target_depth.values[rows])
        np.testing.assert_array_equal(line.get_ydata(), stats.target_contrast.values[rows, gate])
