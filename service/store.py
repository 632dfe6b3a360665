"""The sweep's zarr store: its layout and template.

Layout (README, "The dataset"): dimensions ``sample, frame, gate, y, x``. Samples are grouped
in shards of consecutive samples (zarr v3 sharding), one file per shard and array; inside a
shard, one sample per chunk, so that reading one sample stays one small read. The small
per-sample arrays (``completed``, ``checksum``, the signal means, the target's effect and
visibility) have one chunk per shard. A shard belongs to one task (`service.run`), which
writes all of it. The template (metadata and the coordinates that do not depend on
rendering) is written once with ``compute=False``; tasks then write whole shards, and only
after that set their samples' ``completed`` flags, so an interrupted run never marks a
sample complete that is not written (`service.integrity`). Where stores live and what may
be deleted: `service.storage`; the writer's lock: `service.lock`.
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
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec

from service.inputs import SweepError
from service.schema import field_units
from service.storage import KIND, LOCK_NAME
from service.sweep import Plan
from workers.labels import rendered_variables, sample_labels, surface_axis

__all__ = [
    "CODECS",
    "COUNT_CODECS",
    "FLOAT_CODECS",
    "MAX_SHARD_SAMPLES",
    "MIN_SHARDS",
    "RENDERED_VARIABLES",
    "SHARD_BYTES",
    "check_uniform",
    "create_store",
    "lazy_array",
    "one_per_chunk",
    "open_group",
    "open_store",
    "parameter_name",
    "shard_samples",
    "shard_size",
    "swept_parameters",
    "variable_table",
    "widest_image",
]

RENDERED_VARIABLES = (
    "image",
    "expected",
    "expected_stderr",
    "target_mask",
    "surface_elevation",
    "target_signal",
    "background_signal",
    "target_effect",
    "target_effect_relative",
    "target_visibility",
)
"""Per-sample variables that tasks write; the rest of a sample is written with the template."""
SHARDED = frozenset({"image", "expected", "expected_stderr", "target_mask", "surface_elevation"})
"""Rendered variables stored one sample per chunk inside shards; the others (small) and the
completion records take one chunk per shard."""
STDERR_COMMENT = (
    "standard deviation of the images of the Monte Carlo renderer's independent photon "
    "batches (transport.batches) over the square root of their number; 0 for samples "
    "rendered by the small-angle renderer (transport.method small_angle: deterministic, "
    "no Monte Carlo error)"
)
"""The ``comment`` of a store's ``expected_stderr`` (`variable_table`)."""
SHARD_BYTES = 16 * 2**20
"""Uncompressed bytes a shard (and a task) aims at, unless ``--batch`` says otherwise
(`shard_size`; a sample larger than this is a shard of its own): large enough that a task's
fixed costs (opening the store, zarr's calls, dask's handling, some 20 ms) are a small share
of its rendering, small enough that a task's samples sit in a worker's memory at once."""
MIN_SHARDS = 8
"""Shards a sweep of at least that many samples is split into, at least (`shard_size`), so
that small sweeps still spread over the workers."""
MAX_SHARD_SAMPLES = 256
"""Most samples a shard holds by default (`shard_size`): tiny samples would otherwise make
a few huge tasks, few in flight at once, and a failed one reruns its samples one by one."""

FLAT_CHUNK_KEYS = {"name": "default", "separator": "."}
"""Chunk files named c.4.0.0.0.0 in the array's folder: one file per chunk, no folders to
create (each folder costs as much as a small file on the file systems measured)."""
CONVENTIONS = "CF-1.10"
CODECS = (ZstdCodec(), Crc32cCodec())
"""Compression, then a CRC32C checksum of every chunk: a damaged chunk fails to decode
instead of reading as other numbers."""
COUNT_CODECS = (BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle"), Crc32cCodec())
"""The same for the sharded unsigned arrays (counts, masks): LZ4 after a bit shuffle (Blosc,
a codec of the zarr v3 core specification). On 128-pixel six-gate uint32 counts it writes
ten times faster than zstd, reads three times faster, and takes a quarter fewer bytes:
the high bits of small counts, shuffled together, are long runs of zeros."""
FLOAT_CODECS = (BloscCodec(cname="zstd", clevel=3, shuffle="shuffle"), Crc32cCodec())
"""The same for the sharded float arrays (`expected`, the saved surface): zstd after a byte
shuffle, 15 % fewer bytes than zstd alone on a 257² surface and on 128-pixel images (the
float mantissas' low bytes are noise either way), decoded twice as fast."""


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


def lazy_array(shape: tuple, fill, dtype, *, multiple: int = 1) -> da.Array:
    """A dask array standing for data the template does not write (few, large chunks).

    The zarr chunking comes from the encoding: a dask graph with one chunk per sample
    would grow with the sweep (10⁶ samples: gigabytes in the client). Dask chunks hold a
    whole number of `multiple` leading indices (a shard).
    """
    rows = min(shape[0], max(multiple, 65536 // multiple * multiple))
    return da.full(shape, fill, dtype=dtype, chunks=(rows, *shape[1:]))


def one_per_chunk(shape: tuple, compressors: tuple = CODECS) -> dict:
    """Zarr encoding: one leading index (sample or point) per chunk, flat keys, checksums."""
    return {
        "chunks": (1, *shape),
        "chunk_key_encoding": FLAT_CHUNK_KEYS,
        "compressors": compressors,
    }


def sharded(shape: tuple, samples: int, dtype: np.dtype) -> dict:
    """Zarr encoding: shards of `samples` leading indices, one index per chunk inside.

    Unsigned arrays (counts, masks) are compressed by `COUNT_CODECS`, floats by
    `FLOAT_CODECS`.
    """
    compressors = COUNT_CODECS if np.dtype(dtype).kind == "u" else FLOAT_CODECS
    return {**one_per_chunk(shape, compressors), "shards": (samples, *shape)}


def per_shard(shape: tuple, samples: int) -> dict:
    """Zarr encoding: one chunk per shard of `samples` leading indices (small arrays)."""
    return {**one_per_chunk(shape), "chunks": (samples, *shape)}


def shard_size(plan: Plan, batch: int | None = None) -> int:
    """Samples per shard (and per task) of a new store of `plan`.

    `batch` if given (``--batch``); otherwise as many samples as fit in `SHARD_BYTES`
    uncompressed, at most `MAX_SHARD_SAMPLES`, but few enough to leave `MIN_SHARDS` shards,
    and at least one. The choice depends on the sweep alone, never on the cluster: the
    store's layout is the same on any number of workers. 128-pixel six-gate samples: 40 a
    shard; 512-pixel: 2.
    """
    if batch is not None:
        return batch
    by_bytes = min(SHARD_BYTES // plan.sample_bytes(), MAX_SHARD_SAMPLES)
    return max(1, min(by_bytes, plan.samples // MIN_SHARDS))


def shard_samples(group) -> int:
    """Samples per shard of a store's zarr group."""
    return int(group["completed"].chunks[0])


def parameter_name(path: str) -> str:
    """The variable name of a swept dotted path: a Python identifier (``target_depth``)."""
    return path.replace(".", "_")


def swept_parameters(ds: xr.Dataset) -> dict[str, str]:
    """The swept parameters of a store (or its statistics): variable name -> dotted path."""
    return {
        str(name): variable.attrs["parameter"]
        for name, variable in ds.variables.items()
        if "parameter" in variable.attrs
    }


def check_uniform(plan: Plan) -> None:
    """One store holds one array shape: the shape-defining parameters must not vary.

    Swept parameters' variable names (`parameter_name`) must be distinct too.
    """
    names = {}
    for path in plan.swept:
        other = names.setdefault(parameter_name(path), path)
        if other != path:
            raise SweepError(
                f"sweep.parameters.{path}: its variable name {parameter_name(path)!r} is "
                f"also that of {other}; sweep one of them"
            )
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
        if all(get(scene) == get(first) for scene in plan.scenes[1:]):
            continue
        if path == "surface.spacing" and path not in plan.swept:
            raise SweepError(
                "scene.surface.spacing: with save_surface the stored surface grid must be the "
                "same for every point, but the default surface.spacing follows the receiver's "
                "footprint (platform.altitude, platform.nadir_deg, platform.azimuth_deg, "
                "receiver.field_of_view_deg), which this sweep varies; set surface.spacing "
                "(and surface.coarse_patches) explicitly"
            )
        raise SweepError(
            f"sweep.parameters.{path}: cannot vary within one sweep (it sets the shape of "
            "the stored arrays); run one sweep per value"
        )


def widest_image(plan: Plan, tables: list[dict] | None = None) -> tuple:
    """The ``image`` entry of `rendered_variables` whose type holds every point's counts.

    Counts take the narrowest unsigned type their scene needs (`workers.labels.count_dtype`),
    which differs between points (a brighter target, a lower platform); the store holds
    the widest, and the values of every point unchanged. Points whose images are floats
    (an ICCD gain, no noise) beside points of counts make the store's image a float type
    that holds every count exactly (float32 up to 16-bit counts, else float64); its
    ``long_name`` then names what each kind of point holds. `tables`: every point's
    `rendered_variables`, if already made.
    """
    entries = {}
    for table in map(rendered_variables, plan.scenes) if tables is None else tables:
        entry = table["image"]
        entries.setdefault(entry[1], entry)
    widest = plan.image_dtype()
    if len({dtype.kind for dtype in entries}) == 1:
        return entries[widest]
    dims, _, attrs = next(entry for dtype, entry in entries.items() if dtype.kind == "f")
    names = sorted({entry[2]["long_name"] for entry in entries.values()})
    return dims, widest, {**attrs, "long_name": f"by point: {'; or '.join(names)}"}


def variable_table(plan: Plan) -> dict:
    """The store's rendered variables: the union of every point's `rendered_variables`.

    Each name's dimensions, type and attributes are those of the first point that renders
    it; the image's type is the widest (`widest_image`). A variable only some points render
    is stored for every sample: ``expected_stderr``, of the points that ``transport.method``
    renders by Monte Carlo, is 0 for the small-angle points (deterministic, no Monte Carlo
    error: `service.integrity.write_shard` writes the zeros), as its ``comment`` says.
    """
    tables = [rendered_variables(scene) for scene in plan.scenes]
    union: dict = {}
    for table in tables:
        for name, entry in table.items():
            union.setdefault(name, entry)
    union["image"] = widest_image(plan, tables)
    if "expected_stderr" in union:
        dims, dtype, attrs = union["expected_stderr"]
        union["expected_stderr"] = (dims, dtype, {**attrs, "comment": STDERR_COMMENT})
    return union


def _coordinate_array(values: list) -> np.ndarray:
    """Numbers as numbers; anything else (names, lists) as strings (zarr's `string`)."""
    if all(isinstance(v, bool | int | float) for v in values):
        return np.asarray(values)
    return np.asarray([v if isinstance(v, str) else json.dumps(v) for v in values], dtype=object)


def create_store(
    plan: Plan,
    url: str,
    *,
    storage_options: dict | None = None,
    samples_per_shard: int | None = None,
) -> None:
    """Write the template of the store: metadata, coordinates, empty data arrays.

    Parameters
    ----------
    plan : Plan
        The validated sweep.
    url : str
        A path or fsspec URL; nothing but the writer's lock may be there yet.
    storage_options : dict, optional
        fsspec options (credentials, endpoint).
    samples_per_shard : int, optional
        Consecutive samples per shard, the unit a task renders and writes; by default
        `shard_size`'s choice.
    """
    ds, encoding = template(plan, samples_per_shard)
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


def template(plan: Plan, samples_per_shard: int | None = None) -> tuple[xr.Dataset, dict]:
    """The store's template (`create_store`): the dataset, rendered arrays lazy, and encoding.

    Everything but the rendered arrays and the completion flags and checksums (the labels,
    the platform track, the coordinates) follows from the plan alone: the values
    `service.integrity.wrong_labels` compares a store's with.
    """
    check_uniform(plan)
    first = plan.scenes[0]
    # names, dimensions, dtypes and attributes from the renderer's tables; nothing rendered
    table = variable_table(plan)
    sizes = {
        "frame": first.sequence.frames,
        "gate": len(first.receiver.gate_depths),
        "y": first.receiver.pixels,
        "x": first.receiver.pixels,
    }
    axis = surface_axis(first) if first.save_surface else None
    if axis is not None:
        sizes.update(sy=axis.size, sx=axis.size)
    n = plan.samples
    shard = min(shard_size(plan, samples_per_shard), n)
    realisations = plan.realisations
    data_vars = {}
    encoding = {}
    for name in RENDERED_VARIABLES:
        if name not in table or (name == "expected" and not plan.sweep.store.expected):
            continue
        dims, dtype, attrs = table[name]
        shape = tuple(sizes[dim] for dim in dims)
        fill = np.nan if dtype.kind == "f" else 0
        array = lazy_array((n, *shape), fill, dtype, multiple=shard)
        data_vars[name] = (("sample", *dims), array, dict(attrs))
        if name in SHARDED:
            encoding[name] = sharded(shape, shard, dtype)
        else:
            encoding[name] = per_shard(shape, shard)
    data_vars["completed"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint8, multiple=shard),
        {
            "long_name": "sample rendered and written",
            "units": "1",
            "flag_values": np.arange(2, dtype=np.uint8),
            "flag_meanings": "missing written",
        },
    )
    data_vars["checksum"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint32, multiple=shard),
        {"long_name": "CRC-32 of the sample's rendered arrays", "units": "1"},
    )
    for name in ("completed", "checksum"):
        encoding[name] = per_shard((), shard)
    # labels and the platform track follow from each point's scene: written once, here
    track = ["time", "platform_x", "platform_y", "platform_z"]
    labels = xr.concat(
        [sample_labels(scene).reset_coords(track) for scene in plan.scenes],
        dim="sample",
        data_vars="all",
    )
    for name in ("target_present", *track):
        variable = labels[name]
        data_vars[name] = (
            variable.dims,
            np.repeat(variable.values, realisations, axis=0),
            dict(variable.attrs),
        )
    coords = {
        "gate": labels["gate"],
        "frame": labels["frame"],
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
    if axis is not None:
        for name in ("sx", "sy"):
            coords[name] = (name, axis, dict(table[name][2]))
    for path in plan.swept:
        values = _coordinate_array([point[path] for point in plan.points])
        coords[parameter_name(path)] = (
            "sample",
            np.repeat(values, realisations),
            {
                "long_name": f"swept scene parameter {path}",
                "units": field_units(path),
                "parameter": path,
            },
        )
    ds = xr.Dataset(data_vars, coords=coords)
    for name in ds.variables:
        encoding.setdefault(name, {"compressors": CODECS})
    ds.attrs.update(
        title=f"oceanlidar sweep {plan.sweep.name}",
        Conventions=CONVENTIONS,
        source=f"oceanlidar {package_version()}",
        history=f"oceanlidar {package_version()} run of sweep {plan.sweep.name}",
        oceanlidar_version=package_version(),
        sweep=plan.text,
        sweep_sha256=plan.digest,
        seed=plan.sweep.seed,
        **{KIND: "samples"},
        realisations=realisations,
        points=len(plan.points),
    )
    return ds, encoding


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
