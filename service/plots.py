"""Pictures of samples and of statistics.

The gated strip of one sample (PNG, or an animated GIF of a sequence); the plots of
statistics, detection and `check` are in `service.charts`.

Matplotlib's object-oriented API draws every picture on its own `Figure` with an Agg
canvas: no pyplot, no global backend switched, so pictures are drawn safely from several
threads at once (the job server's requests). Nothing here is needed to simulate, only to
look.
"""

from __future__ import annotations

import functools
import math
import textwrap

import numpy as np
import xarray as xr
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from service.devices import NUMPY
from service.errors import BadOptionError
from service.sweep import Plan
from workers.backends.backend import Backend
from workers.dataset.variables import Visibility
from workers.render import render

__all__ = [
    "CLIP_PERCENTILE",
    "PLOT_FORMATS",
    "PREVIEW_FORMATS",
    "colour_scales",
    "figure_pixels",
    "image_label",
    "new_figure",
    "preview_figure",
    "render_preview",
    "rounded",
    "save_preview",
]

PREVIEW_FORMATS = (".png", ".gif")
"""The files `save_preview` writes: one frame, or all of them."""
PLOT_FORMATS = tuple(sorted(f".{name}" for name in FigureCanvasAgg.get_supported_filetypes()))
"""The files the statistics and detection plots are saved as (matplotlib's Agg canvas)."""
PANEL_INCHES = 2.2
DPI = 100
TITLE_CHARACTERS = 28
"""Characters of a title a panel's width holds at 9 points (longer titles wrap)."""
PIXEL_SIDE = 2
"""Fewest screen pixels across an image pixel in a preview at its default DPI (at one, a
128-pixel gate in a 150-pixel panel shows an outline as fragments)."""
MAX_DPI = 1200
"""Most dots per inch a preview is drawn at (a 7-panel strip: about 18 000 pixels wide)."""
CLIP_PERCENTILE = 99.5
"""Percentile of a gate's pixels its colour scale tops at (`colour_scales`)."""


def render_preview(plan: Plan, sample: int, backend: Backend = NUMPY) -> xr.Dataset:
    """Render sample `sample` of a sweep exactly as the service would, with its surface.

    On `backend` (``preview --backend --device``, `service.devices.choose`): a run on that
    backend and device writes the same sample.
    """
    address = plan.sample(sample)
    scene = address.scene
    if not scene.save_surface:
        scene = scene.model_copy(update={"save_surface": True})
    return render(scene, seed=address.seed, backend=backend.name, device=backend.device)


def new_figure(*, figsize: tuple[float, float]) -> Figure:
    """A figure of `figsize` (inches) at `DPI` on its own Agg canvas (no pyplot)."""
    figure = Figure(figsize=figsize, dpi=DPI)
    FigureCanvasAgg(figure)
    return figure


def colour_scales(images, *, clip: float | None = CLIP_PERCENTILE, shared: bool = False):
    """Each gate's colour scale over `images`, robust to a few hot pixels.

    Parameters
    ----------
    images : array_like, shape (frames, gates, y, x)
        The images the scale covers: one frame for a PNG, every frame for a GIF (one scale
        per gate across frames, so that brightness compares from frame to frame).
    clip : float or None
        Percentile of a gate's pixels the scale tops at (a few bright caustic pixels then
        saturate instead of turning the rest black); None: the greatest value.
    shared : bool
        One scale for every gate (the least and the clipped top over them all).

    Returns
    -------
    ndarray, shape (gates, 2)
        (low, high) of each gate, in the image's units; high > low.
    """
    images = np.asarray(images, dtype=np.float64)
    axes = (0, 1, 2, 3) if shared else (0, 2, 3)
    low = images.min(axis=axes)
    high = images.max(axis=axes) if clip is None else np.percentile(images, clip, axis=axes)
    high = np.where(high > low, high, low + 1.0)  # a uniform gate: any span will do
    gates = images.shape[1]
    return np.broadcast_to(np.stack([low, high], axis=-1), (gates, 2)).copy()


def image_label(image: xr.DataArray) -> str:
    """The colour bar's label of a sample's ``image``: what its values count."""
    kind = image.attrs.get("long_name", "")
    if kind.startswith("photoelectron"):
        return "photoelectrons"
    return "ICCD counts" if kind.startswith("ICCD") else "white-plane units"


def rounded(value) -> str:
    """`value` for a title: numbers to 4 significant digits, anything else as it is."""
    if isinstance(value, float | np.floating):
        return f"{value:.4g}"
    return str(value)


def preview_figure(
    ds: xr.Dataset,
    *,
    frame: int = 0,
    title: str = "",
    measurements=None,
    scales=None,
    sea_scale=None,
):
    """The gated images of one frame side by side, deeper to the right, and the sea.

    Parameters
    ----------
    ds : xarray.Dataset
        One sample, rendered (`workers.render.render`) or read from a store; the sea is
        drawn when it holds ``surface_elevation``.
    frame : int
        Frame to draw.
    title : str
        Figure title.
    measurements : array_like or None
        Points the surface was conditioned on, one [x, y, ...] row each (m); drawn as
        red dots on the sea.
    scales : array_like, shape (gates, 2), or None
        (low, high) of each gate's colour scale, in the image's units (`colour_scales`);
        None: each gate's over this frame, clipped at `CLIP_PERCENTILE`.
    sea_scale : tuple of float, or None
        (low, high) of the sea's colour scale [m]; None: this frame's elevations.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per gate, titled by its ``gate`` coordinate and depths (m), its colour bar
        in photoelectrons (or the image's other units; an arrow where pixels are brighter
        than the scale), the target's mask outlined where ``target_visibility`` says it is
        seen in the gate; and one for the surface elevation (m) on x and y (m), with the
        platform's position and the measured points.
    """
    gates = ds.sizes["gate"]
    panels = gates + ("surface_elevation" in ds)
    figure = new_figure(figsize=(PANEL_INCHES * panels, PANEL_INCHES + 0.6))
    axes = figure.subplots(1, panels, squeeze=False)
    axes = axes[0]
    images = ds["image"].isel(frame=frame).values
    if scales is None:
        scales = colour_scales(images[np.newaxis])
    label = image_label(ds["image"])
    mask = ds["target_mask"].isel(frame=frame).values
    seen = ds["target_visibility"].isel(frame=frame).values == Visibility.in_gate
    for g in range(gates):
        top, bottom = float(ds.gate_top[g]), float(ds.gate_bottom[g])
        low, high = scales[g]
        shown = axes[g].imshow(
            images[g], cmap="gray", interpolation="nearest", vmin=low, vmax=high
        )
        if mask.any() and seen[g]:
            axes[g].contour(mask, levels=[0.5], colors="tab:red", linewidths=0.5, alpha=0.5)
        name = rounded(ds["gate"].values[g].item())
        axes[g].set_title(f"gate {name}: {top:.1f}–{bottom:.1f} m", fontsize=8)
        axes[g].set_xticks([])
        axes[g].set_yticks([])
        extend = "max" if images[g].max() > high else "neither"
        bar = figure.colorbar(shown, ax=axes[g], fraction=0.046, pad=0.02, extend=extend)
        bar.ax.tick_params(labelsize=6)
        bar.set_label(label, fontsize=6)
    if panels > gates:
        _draw_sea(figure, axes[gates], ds, frame, measurements, sea_scale)
    if title:
        figure.suptitle(textwrap.fill(title, TITLE_CHARACTERS * panels), fontsize=9)
    figure.tight_layout()
    return figure


def _draw_sea(figure, sea, ds: xr.Dataset, frame: int, measurements, scale) -> None:
    """The surface elevation of `frame` with the platform's ground point and the data.

    `scale` is the colour scale's (low, high) [m], or None for this frame's range.
    """
    elevation = ds["surface_elevation"].isel(frame=frame)
    extent = [float(ds.sx[0]), float(ds.sx[-1]), float(ds.sy[0]), float(ds.sy[-1])]
    low, high = (None, None) if scale is None else scale
    shown = sea.imshow(
        elevation.values, origin="lower", extent=extent, cmap="ocean", vmin=low, vmax=high
    )
    # the grid covers the first frame's footprint; the platform's ground point, if on it
    sea.plot(float(ds.platform_x[frame]), float(ds.platform_y[frame]), "r+", markersize=10)
    sea.set_xlim(extent[:2])
    sea.set_ylim(extent[2:])
    if measurements is not None and len(measurements):
        measured = np.asarray([point[:2] for point in measurements], dtype=float)
        sea.plot(
            measured[:, 0],
            measured[:, 1],
            linestyle="none",
            marker=".",
            markersize=3,
            color="tab:red",
        )
    sea.set_title(
        f"sea, t = {float(ds.time[frame]):.1f} s, platform {float(ds.platform_z[frame]):.0f} m",
        fontsize=8,
    )
    sea.set_xlabel("x (m)", fontsize=6)
    sea.set_ylabel("y (m)", fontsize=6)
    sea.tick_params(labelsize=6)
    bar = figure.colorbar(shown, ax=sea, fraction=0.046, pad=0.02)
    bar.ax.tick_params(labelsize=6)
    bar.set_label("elevation (m)", fontsize=6)


def figure_pixels(figure) -> Image.Image:
    """The RGB pixels of `figure` (drawn on its Agg canvas, as `new_figure` makes it)."""
    figure.canvas.draw()
    return Image.fromarray(np.asarray(figure.canvas.buffer_rgba())).convert("RGB")


def save_preview(
    ds: xr.Dataset,
    path: str,
    *,
    frame: int | None = None,
    shared_scale: bool = False,
    full_range: bool = False,
    title: str = "",
    measurements=None,
    dpi: float | None = None,
) -> int:
    """Write a PNG of one frame (`frame`, default 0), or an animated GIF of every frame.

    Each gate has its colour scale (`colour_scales`): over the frame drawn in a PNG, over
    every frame in a GIF, from the least value to the `CLIP_PERCENTILE` th percentile (the
    greatest with `full_range`). With `shared_scale`, one scale for every gate (and every
    frame of a GIF), so brightness compares across gates too. The sea's scale spans the
    elevations of every frame drawn (all of a GIF's). ``title`` and ``measurements`` are
    passed to `preview_figure`. `dpi`: the picture's dots per inch (its panels are
    `PANEL_INCHES` wide); None: `DPI`, or more where a gate's image would be drawn with
    fewer than `PIXEL_SIDE` screen pixels across each of its pixels.

    Returns
    -------
    int
        Frames written.

    Raises
    ------
    BadOptionError
        For a frame the sample lacks, a frame given for a GIF, or another file type.
    """
    lower = path.lower()
    count = ds.sizes["frame"]
    if frame is not None and not 0 <= frame < count:
        raise BadOptionError(f"--frame {frame}: the sample has frames 0..{count - 1}")
    if not lower.endswith(PREVIEW_FORMATS):
        raise BadOptionError(f"--output {path}: write a .png (one frame) or a .gif (all frames)")
    gif = lower.endswith(".gif")
    if gif and frame is not None:
        raise BadOptionError(f"--frame {frame}: a GIF holds every frame; write a .png for one")
    drawn = range(count) if gif or shared_scale else [frame or 0]
    clip = None if full_range else CLIP_PERCENTILE
    if dpi is not None and not 0 < dpi <= MAX_DPI:
        raise BadOptionError(f"--dpi {dpi}: give dots per inch, above 0 and at most {MAX_DPI}")
    scales = colour_scales(ds["image"].values[list(drawn)], clip=clip, shared=shared_scale)
    indices = list(drawn) if gif else [frame or 0]
    sea = None
    if "surface_elevation" in ds:
        elevation = ds["surface_elevation"].values[indices]
        sea = (float(elevation.min()), float(elevation.max()))
    draw = functools.partial(
        preview_figure, ds, title=title, measurements=measurements, scales=scales, sea_scale=sea
    )
    first = draw(frame=indices[0])
    dpi = _legible_dpi(first, pixels=ds.sizes["x"]) if dpi is None else dpi
    frames = []
    for index in indices:  # one figure at a time
        figure = first if index == indices[0] else draw(frame=index)
        figure.set_dpi(dpi)
        frames.append(figure_pixels(figure))
    frames[0].save(path, save_all=gif, append_images=frames[1:], duration=200, loop=0)
    return len(frames)


def _legible_dpi(figure, *, pixels: int) -> float:
    """`DPI`, or the least DPI that draws each image pixel `PIXEL_SIDE` screen pixels wide.

    `pixels` is the first gate's image width; its panel's width is measured on `figure`.
    """
    figure.canvas.draw()  # the panels' places, their images' aspect applied
    width = figure.axes[0].get_window_extent().width
    return max(DPI, math.ceil(figure.dpi * PIXEL_SIDE * pixels / width))
