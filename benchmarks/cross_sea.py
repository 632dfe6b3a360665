"""Across seas and waters: the figures of docs/detection.md's "Across seas and waters" (#41).

Does a network trained at one wind (or in one water) carry to another? Reads the detection
datasets of one store, each from ``oceanlidar detect --cnn`` trained on another selection
of its pairs (``--train-on PATH=VALUE``; one of them, optionally, trained on every pair),
and prints, per scored pair, the AUC (with its 95 % bootstrap interval) of the network
trained on each selection, beside the sea-marginal observer's (the ceiling of a detector
that sees the image only) and the matched filter's. With ``--png`` it draws the table:
one panel a scored pair, the networks' AUCs with their intervals, the observer's band.

Usage, from the repository root, after ``oceanlidar run configs/cross-sea.yaml`` and one
``oceanlidar detect cross-sea.zarr --cnn --train-on ... --output NAME.detect.zarr`` a
selection (the config's header gives the commands)::

    python -m benchmarks.cross_sea cross-3.detect.zarr cross-10.detect.zarr ...
        [--png docs/gallery/cross-sea.png]
"""

import argparse

import numpy as np
import xarray as xr

OBSERVER = "sea_marginal_observer"
"""The ceiling: the detection dataset's name of the sea-marginal observer."""

FILTER = "matched_filter"
"""The matched filter's name in the detection dataset."""


def swept_names(detection: xr.Dataset) -> list[str]:
    """The swept coordinates along ``point`` other than the target's shape."""
    return [
        name
        for name, coord in detection.coords.items()
        if coord.dims == ("point",) and name not in ("point", "target_shape")
    ]


def pair_label(detection: xr.Dataset, position: int) -> str:
    """A scored pair's swept values, e.g. ``surface_wind_speed 3, water_preset coastal``."""
    values = []
    for name in swept_names(detection):
        value = detection[name].values[position]
        value = f"{value:g}" if isinstance(value, float | np.floating) else str(value)
        values.append(f"{name} {value}")
    return ", ".join(values)


def trained_on(detection: xr.Dataset) -> str:
    """What the network of `detection` trained on, as ``detect`` recorded it."""
    selection = detection.attrs.get("cnn_trained_on")
    if selection is None:
        raise SystemExit("a detection dataset without the network: run detect with --cnn")
    return selection if isinstance(selection, str) else " ".join(selection)


def short(selection: str) -> str:
    """A training selection for a tick label: its values alone (``every pair`` stays)."""
    if "=" not in selection:
        return selection
    return " ".join(part.split("=", 1)[1] for part in selection.split())


def interval(row: xr.Dataset) -> str:
    """``AUC [low, high]`` of one detector at one pair."""
    return f"{float(row['auc']):.3f} [{float(row['auc_low']):.3f}, {float(row['auc_high']):.3f}]"


def table(detections: list[xr.Dataset]) -> tuple[list[str], list[dict]]:
    """Markdown rows, and for the plot each pair's AUCs: one column a training selection."""
    first = detections[0]
    names = [trained_on(d) for d in detections]
    header = "| scored at | sea-marginal | matched filter | " + " | ".join(
        f"network trained on {n}" for n in names
    )
    rows = [header + " |", "|---" * (3 + len(names)) + "|"]
    pairs = []
    for position in range(first.sizes["point"]):
        label = pair_label(first, position)
        ceiling = first.sel(detector=OBSERVER).isel(point=position)
        matched = first.sel(detector=FILTER).isel(point=position)
        cells = [label, interval(ceiling), interval(matched)]
        networks = []
        for detection in detections:
            network = detection.sel(detector="cnn").isel(point=position)
            gap = float(network["auc"]) - float(ceiling["auc"])
            cells.append(f"{interval(network)} ({gap:+.3f})")
            networks.append(network)
        rows.append("| " + " | ".join(cells) + " |")
        pairs.append({"label": label, "ceiling": ceiling, "networks": networks})
    return rows, pairs


def plot(pairs: list[dict], names: list[str], path: str) -> None:
    """One panel a scored pair: the networks' AUCs with intervals, the observer's band."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    figure, axes = pyplot.subplots(
        1, len(pairs), figsize=(3.2 * len(pairs), 3.6), sharey=True, squeeze=False
    )
    for axis, pair in zip(axes[0], pairs, strict=True):
        ceiling = pair["ceiling"]
        axis.axhspan(float(ceiling["auc_low"]), float(ceiling["auc_high"]), color="0.85")
        axis.axhline(float(ceiling["auc"]), color="0.4", label="sea-marginal observer")
        for i, network in enumerate(pair["networks"]):
            auc = float(network["auc"])
            low, high = auc - float(network["auc_low"]), float(network["auc_high"]) - auc
            axis.errorbar(i, auc, yerr=[[low], [high]], fmt="o", capsize=3)
        axis.set_xticks(range(len(names)), [n.replace(" ", "\n") for n in names], fontsize=7)
        axis.set_xlabel("the network trained on", fontsize=8)
        axis.set_title(pair["label"].replace(", ", "\n"), fontsize=8)
    axes[0][0].set_ylabel("AUC (95 % interval)")
    axes[0][0].legend(fontsize=7, loc="lower left")
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main() -> None:
    """Print the table (and draw it with ``--png``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("detections", nargs="+", help="detection datasets of one store")
    parser.add_argument("--png", help="draw the table into this file")
    args = parser.parse_args()
    detections = [xr.open_zarr(path).load() for path in args.detections]
    sweeps = {d.attrs["sweep_sha256"] for d in detections}
    if len(sweeps) > 1:
        raise SystemExit("the detection datasets are of different sweeps")
    rows, pairs = table(detections)
    print("\n".join(rows))
    for detection in detections:
        print(
            f"trained on {trained_on(detection)}: {detection.attrs['cnn_epochs']} epochs, "
            f"{detection.attrs['cnn_fresh_samples']} fresh samples a point"
        )
    if args.png:
        plot(pairs, [short(trained_on(d)) for d in detections], args.png)
        print(f"plot: {args.png}")


if __name__ == "__main__":
    main()
