"""The sweep's zarr store: template, region writes, completion records.

Layout (DESIGN §4): dimensions ``sample, frame, gate, y, x``, one sample per chunk. The
template (metadata and the coordinates that do not depend on rendering) is written once with
``compute=False``; each task then writes whole chunks of its samples with region writes, and
only after that sets their ``completed`` flags, so an interrupted run never marks a sample
complete that is not written.
"""

from __future__ import annotations

import contextlib
import json
import warnings
from importlib.metadata import PackageNotFoundError, version

import dask.array as da
import fsspec
import numpy as np
import xarray as xr
import zarr

from service.sweep import Plan, SweepError, field_units
from workers.render import render, sample_labels
from workers.seeds import SampleSeed

__all__ = [
    "RENDERED_VARIABLES",
    "check_uniform",
    "completed_samples",
    "create_store",
    "lazy_array",
    "one_per_chunk",
    "open_group",
    "open_store",
    "remove_store",
    "sample_dataset",
    "stats_url",
    "store_exists",
    "write_samples",
]

RENDERED_VARIABLES = ("image", "expected", "target_mask", "surface_elevation")
"""Per-sample variables that tasks write; the rest of a sample is written with the template."""

FLAT_CHUNK_KEYS = {"name": "default", "separator": "."}
"""Chunk files named c.4.0.0.0.0 in the array's folder: one file per chunk, no folders to
create (each folder costs as much as a small file on the file systems measured)."""
CONVENTIONS = "CF-1.10"


@contextlib.contextmanager
def consolidated_v3():
    """Write consolidated metadata to a zarr v3 store without zarr's standing warning.

    zarr-python warns that consolidated metadata is not yet part of the v3 specification;
    we keep it because opening a store then costs one read (it matters on object storage),
    and zarr-python, which we pin, reads it.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
        yield


def package_version() -> str:
    """The installed oceanlidar version."""
    try:
        return version("oceanlidar")
    except PackageNotFoundError:
        return "unknown"


def stats_url(url: str) -> str:
    """Where the statistics dataset of the store at `url` lives (beside it)."""
    stem = url.rstrip("/")
    if stem.endswith(".zarr"):
        stem = stem[: -len(".zarr")]
    return stem + ".stats.zarr"


def _fs(url: str, storage_options: dict | None):
    try:
        return fsspec.core.url_to_fs(url, **(storage_options or {}))
    except (TypeError, ValueError, ImportError) as error:
        raise SweepError(f"{url}: cannot open with these storage options ({error})") from None


def lazy_array(shape: tuple, fill, dtype) -> da.Array:
    """A dask array standing for data the template does not write (few, large chunks).

    The zarr chunking comes from `one_per_chunk`: a dask graph with one chunk per sample
    would grow with the sweep (10⁶ samples: gigabytes in the client).
    """
    return da.full(shape, fill, dtype=dtype, chunks=(min(shape[0], 65536), *shape[1:]))


def one_per_chunk(shape: tuple) -> dict:
    """Zarr encoding: one leading index (sample or point) per chunk, flat chunk keys."""
    return {"chunks": (1, *shape), "chunk_key_encoding": FLAT_CHUNK_KEYS}


def store_exists(url: str, storage_options: dict | None = None) -> bool:
    """Whether anything is stored at `url`."""
    fs, path = _fs(url, storage_options)
    return fs.exists(path)


def is_oceanlidar_store(url: str, storage_options: dict | None = None) -> bool:
    """Whether `url` holds a zarr group written by oceanlidar (a sweep or its statistics)."""
    try:
        group = zarr.open_group(store=url, mode="r", storage_options=storage_options)
    except Exception:
        return False
    return "sweep_sha256" in group.attrs


def remove_store(url: str, storage_options: dict | None = None) -> None:
    """Delete the oceanlidar store at `url` (``--overwrite``); refuse anything else."""
    fs, path = _fs(url, storage_options)
    if not fs.exists(path):
        return
    if not is_oceanlidar_store(url, storage_options):
        raise SweepError(f"{url} exists and is not an oceanlidar store; refusing to delete it")
    fs.rm(path, recursive=True)


def check_uniform(plan: Plan) -> None:
    """One store holds one array shape: the shape-defining parameters must not vary."""
    first = plan.scenes[0]
    fields = {
        "receiver.pixels": lambda s: s.receiver.pixels,
        "receiver.gates": lambda s: s.receiver.gate_depths,
        "sequence.frames": lambda s: s.sequence.frames,
        "save_surface": lambda s: s.save_surface,
        "surface.grid_size": lambda s: s.surface.grid_size if s.save_surface else None,
        "surface.spacing": lambda s: s.surface.spacing if s.save_surface else None,
    }
    for path, get in fields.items():
        if any(get(scene) != get(first) for scene in plan.scenes[1:]):
            raise SweepError(
                f"sweep.parameters.{path}: cannot vary within one sweep (it sets the shape of "
                "the stored arrays); run one sweep per value"
            )


def sample_dataset(plan: Plan, sample: int) -> xr.Dataset:
    """Render sample `sample` of the plan, with its per-sample coordinates."""
    point, realisation = divmod(sample, plan.realisations)
    return render(
        plan.scenes[point],
        seed=SampleSeed(root=plan.sweep.seed, point=point, realisation=realisation),
    )


def _coordinate_array(values: list) -> np.ndarray:
    """Numbers as numbers; anything else (names, lists) as strings (zarr's `string`)."""
    if all(isinstance(v, bool | int | float) for v in values):
        return np.asarray(values)
    return np.asarray([v if isinstance(v, str) else json.dumps(v) for v in values], dtype=object)


def create_store(plan: Plan, url: str, *, storage_options: dict | None = None) -> None:
    """Write the template of the store: metadata, coordinates, empty data arrays.

    Parameters
    ----------
    plan : Plan
        The validated sweep.
    url : str
        A path or fsspec URL; nothing may exist there yet.
    storage_options : dict, optional
        fsspec options (credentials, endpoint).
    """
    check_uniform(plan)
    probe = render(plan.scenes[0], seed=0)
    n = plan.samples
    realisations = plan.realisations
    data_vars = {}
    encoding = {}
    for name in RENDERED_VARIABLES:
        if name not in probe:
            continue
        variable = probe[name]
        fill = np.nan if variable.dtype.kind == "f" else 0
        data_vars[name] = (
            ("sample", *variable.dims),
            lazy_array((n, *variable.shape), fill, variable.dtype),
            dict(variable.attrs),
        )
        encoding[name] = one_per_chunk(variable.shape)
    data_vars["completed"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint8),
        {"long_name": "sample rendered and written", "units": "1"},
    )
    encoding["completed"] = one_per_chunk(())
    # labels and the platform track follow from each point's scene: written once, here
    track = ["time", "platform_x", "platform_y", "platform_z"]
    labels = xr.concat(
        [sample_labels(scene).reset_coords(track) for scene in plan.scenes],
        dim="sample",
        data_vars="all",
    )
    for name in ("target_present", "target_visibility", *track):
        variable = labels[name]
        data_vars[name] = (
            variable.dims,
            np.repeat(variable.values, realisations, axis=0),
            dict(variable.attrs),
        )
    coords = {
        "gate_top": probe["gate_top"],
        "gate_bottom": probe["gate_bottom"],
        "point": (
            "sample",
            np.repeat(np.arange(len(plan.points)), realisations),
            {"long_name": "parameter point index", "units": "1"},
        ),
        "realisation": (
            "sample",
            np.tile(np.arange(realisations), len(plan.points)),
            {"long_name": "Monte Carlo realisation index", "units": "1"},
        ),
    }
    for name in ("sx", "sy"):
        if name in probe.coords:
            coords[name] = probe[name]
    for path in plan.swept:
        values = _coordinate_array([point[path] for point in plan.points])
        coords[path] = (
            "sample",
            np.repeat(values, realisations),
            {"long_name": f"swept scene parameter {path}", "units": field_units(path)},
        )
    ds = xr.Dataset(data_vars, coords=coords)
    ds.attrs.update(
        title=f"oceanlidar sweep {plan.sweep.name}",
        Conventions=CONVENTIONS,
        source=f"oceanlidar {package_version()}",
        oceanlidar_version=package_version(),
        sweep=plan.text,
        sweep_sha256=plan.digest,
        seed=plan.sweep.seed,
        realisations=realisations,
        points=len(plan.points),
    )
    with consolidated_v3():
        ds.to_zarr(
            url,
            mode="w-",
            compute=False,
            consolidated=True,
            zarr_format=3,
            encoding=encoding,
            storage_options=storage_options,
        )


def open_store(
    url: str, *, storage_options: dict | None = None, samples_per_chunk: int | None = None
) -> xr.Dataset:
    """Open a store lazily (dask arrays; one sample per dask chunk unless told otherwise)."""
    if samples_per_chunk is None:
        return xr.open_zarr(url, consolidated=True, storage_options=storage_options)
    with warnings.catch_warnings():
        # labels are stored in one chunk per array: splitting them for reading is intended
        warnings.filterwarnings("ignore", message="The specified chunks separate")
        return xr.open_zarr(
            url,
            consolidated=True,
            storage_options=storage_options,
            chunks={"sample": samples_per_chunk},
        )


def completed_samples(url: str, *, storage_options: dict | None = None) -> np.ndarray:
    """Boolean array: which samples are written."""
    ds = open_store(url, storage_options=storage_options)
    return ds["completed"].values.astype(bool)


def open_group(url: str, storage_options: dict | None = None):
    """A store's zarr group, for whole-chunk writes into arrays the template created."""
    return zarr.open_group(
        store=url,
        mode="r+",
        zarr_format=3,
        use_consolidated=False,
        storage_options=storage_options,
    )


def write_samples(group, start: int, samples: list[xr.Dataset]) -> None:
    """Write consecutive rendered samples' whole chunks, then mark them complete.

    Writes go straight to the zarr arrays the template created (one chunk per sample per
    variable), one call per variable for the whole batch: xarray's region writes re-read
    the store's metadata on every call, which costs more than rendering a small sample.
    """
    region = slice(start, start + len(samples))
    for name in RENDERED_VARIABLES:
        if name in samples[0]:
            group[name][region] = np.stack([sample[name].values for sample in samples])
    group["completed"][region] = np.ones(len(samples), dtype=np.uint8)
