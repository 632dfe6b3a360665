"""Plots of a sweep's results: statistics, detection and the fidelity check.

Each against the swept parameters: a column per parameter that varies among the points
plotted, a line and marker per combination of the others, named. Drawn like the previews
(`service.plots`: a `Figure` on its own Agg canvas from `service.plots.new_figure`, no
pyplot, safe from several threads).
"""

from __future__ import annotations

import textwrap

import numpy as np
import xarray as xr

from service import plots
from service.errors import BadSweepError
from service.plots import DPI, colour_scales, rounded
from service.stats import statistics_completeness
from service.store.template import swept_parameters

__all__ = ["MARKERS", "plot_check", "plot_detection", "plot_statistics", "statistics_title"]


def statistics_title(stats: xr.Dataset) -> str:
    """The statistics plot's title: the samples store and how complete its statistics are."""
    store = stats.attrs.get("samples_store") or stats.attrs.get("title", "")
    return f"{store}: statistics of {statistics_completeness(stats)}"


def plot_statistics(stats: xr.Dataset, path: str) -> None:
    """Target contrast and contrast-to-noise ratio against each swept parameter, per gate.

    One colour per gate; points that share every other parameter are joined by a line,
    one marker per such combination, named in the column's legend. The CNR of a point with
    a target is drawn filled, its ``cnr_without_target`` hollow beside it. A parameter that
    takes one value among the points with a target (``target.shape`` beside its twins)
    gets no column, unless no parameter takes two; a category's axis has no unit. Titled
    by `statistics_title`: the store and how many of its samples the statistics hold.
    """
    swept = list(swept_parameters(stats))
    if not swept:
        raise BadSweepError("the store sweeps no parameter: nothing to plot against")
    measured = np.isfinite(stats["target_contrast"].values).any(axis=1)
    rows = np.flatnonzero(measured) if measured.any() else np.arange(stats.sizes["point"])
    varied = [name for name in swept if _categories_among(stats[name].values[rows]) > 1]
    columns = varied or swept[:1]
    figure = plots.new_figure(figsize=(3.4 * len(columns), 5.4))
    axes = figure.subplots(2, len(columns), squeeze=False)
    twin = stats["cnr_without_target"].values if "cnr_without_target" in stats else None
    if twin is not None and not np.isfinite(twin).any():
        twin = None  # no point has a target-free twin: nothing drawn hollow
    for column, name in enumerate(columns):
        position, categories = _parameter_position(stats[name].values)
        series = _series(stats, [n for n in varied if n != name], rows)
        for row, quantity in enumerate(("target_contrast", "cnr")):
            ax = axes[row, column]
            data = stats[quantity].values
            for g in range(stats.sizes["gate"]):
                top, bottom = float(stats.gate_top[g]), float(stats.gate_bottom[g])
                gate = f"{int(stats['gate'][g])}: {top:.1f}–{bottom:.1f} m"
                for s, members in enumerate(series.values()):
                    at = members[np.argsort(position[members], kind="stable")]
                    style = {"marker": MARKERS[s % len(MARKERS)], "ms": 4, "color": f"C{g}"}
                    ax.plot(position[at], data[at, g], "-", lw=0.5, **style)
                    if row == 1 and twin is not None:  # the same reading without the target
                        ax.plot(position[at], twin[at, g], linestyle="none", mfc="none", **style)
                if row == column == 0:  # the gates' legend
                    ax.plot([], [], "o", ms=4, color=f"C{g}", label=gate)
            ax.set_xlabel(_axis_label(stats[name], categories), fontsize=8)
            ax.set_ylabel("target contrast" if row == 0 else "CNR", fontsize=8)
            ax.axhline(0.0, color="0.7", linewidth=0.5)
            ax.tick_params(labelsize=7)
            if categories:
                ax.set_xticks(range(len(categories)), categories)
        for s, combination in enumerate(series):
            if combination:
                marker = MARKERS[s % len(MARKERS)]
                axes[1, column].plot([], [], marker, ms=4, color="0.3", label=combination)
        if twin is not None:
            axes[1, column].plot(
                [], [], "o", ms=4, mfc="none", c="0.3", label="without the target"
            )
        if axes[1, column].get_legend_handles_labels()[0]:
            axes[1, column].legend(fontsize=5)
    axes[0, 0].legend(fontsize=6, title="gate", title_fontsize=6)
    figure.suptitle(textwrap.fill(statistics_title(stats), 48 * len(columns)), fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=DPI)


MARKERS = "osD^vP*Xh<>p"
"""One marker per combination of the other parameters (`_series`), in turn."""


def _categories_among(values) -> int:
    """How many distinct values `values` holds (as its axis would show them)."""
    return len(np.unique(np.asarray([str(v) for v in values])))


def _axis_label(variable: xr.DataArray, categories) -> str:
    """A parameter axis' label: its name, and its unit unless its values are categories."""
    name = variable.attrs.get("parameter", str(variable.name))
    return name if categories else f"{name} ({variable.attrs.get('units', '1')})"


def _series(ds: xr.Dataset, others, rows) -> dict[str, np.ndarray]:
    """The points of `rows` grouped by their values of the parameters `others`.

    Returns ``{"name=value, ...": points}`` in the order the combinations first occur
    (``{"": rows}`` when `others` is empty), each name its dotted path's last part.
    """
    groups: dict[str, list[int]] = {}
    for i in rows:
        label = ", ".join(
            f"{ds[n].attrs.get('parameter', n).split('.')[-1]}={rounded(ds[n].values[i])}"
            for n in others
        )
        groups.setdefault(label, []).append(int(i))
    return {label: np.asarray(points) for label, points in groups.items()}


def _parameter_position(values) -> tuple[np.ndarray, list[str] | None]:
    """Where each point lies on a parameter's axis, and the category names if not numeric."""
    if values.dtype.kind in "biuf":
        return values.astype(float), None
    names, index = np.unique(np.asarray([str(v) for v in values]), return_inverse=True)
    return index.astype(float), names.tolist()


def plot_detection(detection: xr.Dataset, path: str) -> None:
    """ROC curves per parameter point, then AUC and Pd at Pfa = 10⁻² against each parameter.

    Parameters
    ----------
    detection : xarray.Dataset
        A detection dataset (`service.detect.write_detection`).
    path : str
        PNG to write. Top: one ROC panel per point with a target (every detector, false
        alarms on a log axis, ties drawn as the diagonal they stand for). Below, per swept
        parameter (other than the target's shape) that takes two values or more: the AUC
        with its 95 % interval, and Pd at Pfa = 10⁻² where the negatives measure it
        (points where it is unavailable are left out), one colour per detector; points
        that share every other parameter are joined by a line, one marker per such
        combination, named in the Pd panel's legend.
    """
    swept = [
        name
        for name, path in swept_parameters(detection).items()
        if path != "target.shape" and _categories_among(detection[name].values) > 1
    ]
    points = detection.sizes["point"]
    columns = max(4, len(swept))
    roc_rows = -(-points // columns)
    figure = plots.new_figure(figsize=(2.6 * columns, 2.5 * (roc_rows + 2)))
    axes = figure.subplots(roc_rows + 2, columns, squeeze=False)
    detectors = [str(d) for d in detection["detector"].values]
    colours = [f"C{i}" for i in range(len(detectors))]
    floor = 1.0 / (2 * detection.sizes["realisation"])
    for i in range(roc_rows * columns):
        ax = axes[i // columns, i % columns]
        if i >= points:
            ax.axis("off")
            continue
        for d, name in enumerate(detectors):
            pfa = detection["roc_pfa"].values[i, d]
            pd = detection["roc_pd"].values[i, d]
            auc = float(detection["auc"].values[i, d])
            ax.plot(np.maximum(pfa, floor), pd, color=colours[d], linewidth=1)
            ax.plot([], [], color=colours[d], label=f"{name} ({auc:.2f})")
        ax.set_xscale("log")
        ax.set_xlim(floor, 1.0)
        ax.set_ylim(0.0, 1.02)
        ax.set_xlabel("false-alarm probability", fontsize=6)
        ax.set_ylabel("detection probability", fontsize=6)
        values = [
            f"{detection[n].attrs['parameter'].split('.')[-1]}={detection[n].values[i]}"
            for n in swept
        ]
        half = -(-len(values) // 2)
        ax.set_title(", ".join(values[:half]) + "\n" + ", ".join(values[half:]), fontsize=6)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=5, loc="lower right")
    for column in range(len(swept), columns):
        axes[roc_rows, column].axis("off")
        axes[roc_rows + 1, column].axis("off")
    for column, name in enumerate(swept):
        position, categories = _parameter_position(detection[name].values)
        series = _series(detection, [n for n in swept if n != name], range(points))
        step = 0.015 * (np.ptp(position) or 1.0)
        for d, detector in enumerate(detectors):
            shift = position + (d - (len(detectors) - 1) / 2) * step
            auc = detection["auc"].values[:, d]
            pd = detection["pd"].sel(pfa=1e-2).values[:, d]
            for group, rows in enumerate(series.values()):
                rows = rows[np.argsort(position[rows], kind="stable")]
                marker = MARKERS[group % len(MARKERS)]
                axes[roc_rows, column].errorbar(
                    shift[rows],
                    auc[rows],
                    yerr=[
                        auc[rows] - detection["auc_low"].values[rows, d],
                        detection["auc_high"].values[rows, d] - auc[rows],
                    ],
                    fmt=f"{marker}-",
                    color=colours[d],
                    linewidth=0.5,
                    elinewidth=0.8,
                    markersize=3,
                    label=detector if group == 0 else None,
                )
                shown = rows[~np.isnan(pd[rows])]
                axes[roc_rows + 1, column].plot(
                    shift[shown], pd[shown], f"{marker}-", color=colours[d], lw=0.5, ms=3
                )
        for group, combination in enumerate(series):
            if combination:
                marker = MARKERS[group % len(MARKERS)]
                axes[roc_rows + 1, column].plot([], [], marker, ms=3, c="0.3", label=combination)
        if axes[roc_rows + 1, column].get_legend_handles_labels()[0]:
            axes[roc_rows + 1, column].legend(fontsize=5)
        for row, label in ((roc_rows, "AUC"), (roc_rows + 1, "Pd at Pfa = 1e-2")):
            ax = axes[row, column]
            ax.set_ylabel(label, fontsize=7)
            units = detection[name].attrs.get("units", "1")
            ax.set_xlabel(name if categories else f"{name} ({units})", fontsize=7)
            ax.set_ylim(-0.02, 1.02)
            ax.tick_params(labelsize=6)
            if categories:
                ax.set_xticks(range(len(categories)), categories)
    if swept:
        axes[roc_rows, 0].legend(fontsize=5)
    figure.tight_layout()
    figure.savefig(path, dpi=DPI)


def plot_check(checks, path: str) -> None:
    """``oceanlidar check``'s comparison: each point's images side by side, ratios by gate.

    Parameters
    ----------
    checks : sequence of service.check.PointCheck
        The points checked.
    path : str
        Picture to write (`PLOT_FORMATS`). Two rows a point: transport's noise-free
        images, gate by gate, over the fast renderer's, each gate on one colour scale
        (`colour_scales` over both, the target's mask outlined); beside them, by gate, the
        background's ratio (fast/transport) and the target's (the contrast's ratio inside
        or at an edge; 1 + the difference of the contrasts in a shadow or above it), with
        the reference's errors, the bars shaded, measures outside their bar in red.
    """
    gates = max(len(check.gates) for check in checks)
    figure = plots.new_figure(figsize=(1.6 * gates + 3.6, 3.2 * len(checks)))
    grid = figure.add_gridspec(2 * len(checks), gates + 2)
    for row, check in enumerate(checks):
        pair = np.stack([check.reference.image, check.fast.image])
        scales = colour_scales(pair)
        for g in range(len(check.gates)):
            for r, (name, image) in enumerate((("transport", pair[0]), ("fast", pair[1]))):
                ax = figure.add_subplot(grid[2 * row + r, g])
                ax.imshow(image[g], cmap="gray", vmin=scales[g, 0], vmax=scales[g, 1])
                if check.reference.mask.any():
                    ax.contour(check.reference.mask, levels=[0.5], colors="C1", linewidths=0.5)
                ax.set_xticks([])
                ax.set_yticks([])
                if g == 0:
                    ax.set_ylabel(f"point {check.point}\n{name}", fontsize=7)
                if r == 0:
                    ax.set_title(f"gate {g + 1} ({check.gates[g].kind})", fontsize=7)
        ax = figure.add_subplot(grid[2 * row : 2 * row + 2, gates:])
        _draw_ratios(ax, check)
    figure.tight_layout()
    figure.savefig(path, dpi=DPI)


def _draw_ratios(ax, check) -> None:
    """One point's measures by gate against 1, each with its bar (`plot_check`)."""
    number = np.array([gate.gate for gate in check.gates], dtype=np.float64)
    series = [
        ("background", -0.12, [gate.background for gate in check.gates]),
        ("target", 0.12, [gate.contrast for gate in check.gates]),
    ]
    for label, shift, measures in series:
        for x, measure in zip(number + shift, measures, strict=True):
            if measure is None or not np.isfinite(measure.value):
                continue
            value = measure.value if measure.ratio else 1.0 + measure.value
            colour = "C3" if measure.holds is False else "C0" if label == "target" else "C2"
            ax.errorbar(
                x,
                value,
                yerr=measure.error,
                fmt="o" if label == "target" else "s",
                color=colour,
                markersize=3,
                elinewidth=0.8,
                markerfacecolor="none" if measure.holds is None else colour,
            )
            ax.fill_between(
                [x - 0.1, x + 0.1], 1 - measure.bar, 1 + measure.bar, color=colour, alpha=0.15
            )
        ax.plot(
            [],
            [],
            "s" if label == "background" else "o",
            color="C2" if label == "background" else "C0",
            markersize=3,
            label=label,
        )
    ax.axhline(1.0, color="0.5", linewidth=0.5)
    ax.set_xticks(number)
    ax.set_xlabel("gate", fontsize=7)
    ax.set_ylabel("fast / transport", fontsize=7)
    verdict = "holds" if check.holds else "fails (red)"
    ax.set_title(f"point {check.point}: {verdict}", fontsize=7)
    ax.tick_params(labelsize=6)
    ax.legend(fontsize=5)
