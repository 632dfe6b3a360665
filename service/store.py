"""The sweep's zarr store: its layout and template.

Layout (README, "The dataset"): dimensions ``sample, frame, gate, y, x``, one sample per chunk. The
template (metadata and the coordinates that do not depend on rendering) is written once with
``compute=False``; each task then writes whole chunks of its samples with region writes, and
only after that sets their ``completed`` flags, so an interrupted run never marks a sample
complete that is not written (`service.integrity`). Where stores live and what may be
deleted: `service.storage`; the writer's lock: `service.lock`.
"""

from __future__ import annotations

import contextlib
import json
import warnings
from importlib.metadata import PackageNotFoundError, version

import dask.array as da
import numpy as np
import xarray as xr
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from service.inputs import SweepError
from service.schema import field_units
from service.storage import KIND, LOCK_NAME
from service.sweep import Plan
from workers.labels import rendered_variables
from workers.render import render, sample_labels

__all__ = [
    "CODECS",
    "RENDERED_VARIABLES",
    "check_uniform",
    "create_store",
    "lazy_array",
    "one_per_chunk",
    "open_group",
    "open_store",
    "sample_dataset",
]

RENDERED_VARIABLES = ("image", "expected", "target_mask", "surface_elevation")
"""Per-sample variables that tasks write; the rest of a sample is written with the template."""

FLAT_CHUNK_KEYS = {"name": "default", "separator": "."}
"""Chunk files named c.4.0.0.0.0 in the array's folder: one file per chunk, no folders to
create (each folder costs as much as a small file on the file systems measured)."""
CONVENTIONS = "CF-1.10"
CODECS = (ZstdCodec(), Crc32cCodec())
"""Compression, then a CRC32C checksum of every chunk: a damaged chunk fails to decode
instead of reading as other numbers."""


@contextlib.contextmanager
def consolidated_v3():
    """Write consolidated metadata to a zarr v3 store without zarr's standing warning.

    zarr-python warns that consolidated metadata is not yet part of the v3 specification;
    we keep it because opening a store then costs one read (it matters on object storage),
    and zarr-python, which we pin, reads it. Consolidating lists the store, where zarr
    notices the writer's lock (`service.lock.writer_lock`), which is not part of the
    hierarchy by design.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
        warnings.filterwarnings("ignore", message=f"Object at {LOCK_NAME} is not recognized")
        yield


def package_version() -> str:
    """The installed oceanlidar version."""
    try:
        return version("oceanlidar")
    except PackageNotFoundError:
        return "unknown"


def lazy_array(shape: tuple, fill, dtype) -> da.Array:
    """A dask array standing for data the template does not write (few, large chunks).

    The zarr chunking comes from `one_per_chunk`: a dask graph with one chunk per sample
    would grow with the sweep (10⁶ samples: gigabytes in the client).
    """
    return da.full(shape, fill, dtype=dtype, chunks=(min(shape[0], 65536), *shape[1:]))


def one_per_chunk(shape: tuple) -> dict:
    """Zarr encoding: one leading index (sample or point) per chunk, flat keys, checksums."""
    return {"chunks": (1, *shape), "chunk_key_encoding": FLAT_CHUNK_KEYS, "compressors": CODECS}


def check_uniform(plan: Plan) -> None:
    """One store holds one array shape: the shape-defining parameters must not vary."""
    first = plan.scenes[0]
    fields = {
        "receiver.pixels": lambda s: s.receiver.pixels,
        "receiver.gates": lambda s: s.receiver.gate_depths,
        "sequence.frames": lambda s: s.sequence.frames,
        "save_surface": lambda s: s.save_surface,
        "surface.grid_size": lambda s: s.surface.grid_size if s.save_surface else None,
        "surface.spacing": lambda s: s.surface_spacing() if s.save_surface else None,
    }
    for path, get in fields.items():
        if any(get(scene) != get(first) for scene in plan.scenes[1:]):
            raise SweepError(
                f"sweep.parameters.{path}: cannot vary within one sweep (it sets the shape of "
                "the stored arrays); run one sweep per value"
            )


def sample_dataset(plan: Plan, sample: int) -> xr.Dataset:
    """Render sample `sample` of the plan, with its per-sample coordinates."""
    address = plan.sample(sample)
    return render(address.scene, seed=address.seed)


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
        A path or fsspec URL; nothing but the writer's lock may be there yet.
    storage_options : dict, optional
        fsspec options (credentials, endpoint).
    """
    check_uniform(plan)
    first = plan.scenes[0]
    # names, dimensions, dtypes and attributes from the renderer's table; nothing rendered
    table = rendered_variables(first)
    sizes = {
        "frame": first.sequence.frames,
        "gate": len(first.receiver.gate_depths),
        "y": first.receiver.pixels,
        "x": first.receiver.pixels,
        "sy": first.surface.grid_size,
        "sx": first.surface.grid_size,
    }
    n = plan.samples
    realisations = plan.realisations
    data_vars = {}
    encoding = {}
    for name in RENDERED_VARIABLES:
        if name not in table:
            continue
        dims, dtype, attrs = table[name]
        shape = tuple(sizes[dim] for dim in dims)
        fill = np.nan if dtype.kind == "f" else 0
        data_vars[name] = (("sample", *dims), lazy_array((n, *shape), fill, dtype), dict(attrs))
        encoding[name] = one_per_chunk(shape)
    data_vars["completed"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint8),
        {"long_name": "sample rendered and written", "units": "1"},
    )
    encoding["completed"] = one_per_chunk(())
    data_vars["checksum"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint32),
        {"long_name": "CRC-32 of the sample's rendered arrays", "units": "1"},
    )
    encoding["checksum"] = one_per_chunk(())
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
        "gate_top": labels["gate_top"],
        "gate_bottom": labels["gate_bottom"],
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
    axis = np.arange(first.surface.grid_size) * first.surface_spacing()
    for name in ("sx", "sy"):
        if name in table:
            coords[name] = (name, axis, dict(table[name][2]))
    for path in plan.swept:
        values = _coordinate_array([point[path] for point in plan.points])
        coords[path] = (
            "sample",
            np.repeat(values, realisations),
            {"long_name": f"swept scene parameter {path}", "units": field_units(path)},
        )
    ds = xr.Dataset(data_vars, coords=coords)
    for name in ds.variables:
        encoding.setdefault(name, {"compressors": CODECS})
    ds.attrs.update(
        title=f"oceanlidar sweep {plan.sweep.name}",
        Conventions=CONVENTIONS,
        source=f"oceanlidar {package_version()}",
        oceanlidar_version=package_version(),
        sweep=plan.text,
        sweep_sha256=plan.digest,
        seed=plan.sweep.seed,
        **{KIND: "samples"},
        realisations=realisations,
        points=len(plan.points),
    )
    with consolidated_v3():
        ds.to_zarr(
            url,
            mode="a",  # the folder holds the writer's lock
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


def open_group(url: str, storage_options: dict | None = None):
    """A store's zarr group, for whole-chunk writes into arrays the template created."""
    return zarr.open_group(
        store=url,
        mode="r+",
        zarr_format=3,
        use_consolidated=False,
        storage_options=storage_options,
    )
