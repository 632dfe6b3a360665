"""The store's template: its variables, metadata and coordinates, written before any sample.

Dimensions ``sample, frame, gate, y, x`` (README, "The dataset"; ``y`` and ``x`` the
pixels' places on the sea, `workers.dataset.labels.image_axes`, unless the sweep varies the
footprint). The template (metadata and everything that does not depend on rendering:
labels, platform track, coordinates, swept parameters under identifier names) is written
once with ``compute=False``, laid out as `service.store.layout` says; tasks then write
whole shards, and only after that set their samples' ``completed`` flags, so an
interrupted run never marks a sample complete that is not written
(`service.store.shards.write_shard`). The variables are the union of
every point's table (`store_variables`, from `workers.dataset.variables`).
"""

from __future__ import annotations

import dataclasses
import json

import google_crc32c
import numpy as np
import xarray as xr

from service import package_version
from service.devices import NUMPY, recorded
from service.errors import BadSweepError
from service.schema import field_units
from service.store.layout import (
    CODECS,
    CONVENTIONS,
    lazy_array,
    per_shard,
    shard_size,
    sharded,
)
from service.store.location import KIND, Store
from service.sweep import Plan
from workers.backends.backend import Backend
from workers.dataset.labels import sample_labels, surface_axis
from workers.dataset.variables import Role, Variable, rendered_order, variables
from workers.settings.scene import Scene

__all__ = [
    "LABELS_CHECKSUM",
    "OWNER",
    "check_uniform",
    "create_store",
    "label_names",
    "labels_checksum",
    "parameter_name",
    "rendered_shapes",
    "store_variables",
    "swept_parameters",
    "template",
    "widest_image",
]

STDERR_COMMENT = (
    "standard deviation of the images of the Monte Carlo renderer's independent photon "
    "batches (transport.batches) over the square root of their number; 0 for samples "
    "rendered by the small-angle renderer (transport.method small_angle: deterministic, "
    "no Monte Carlo error)"
)
"""The ``comment`` of a store's ``expected_stderr`` (`store_variables`)."""
OWNER = "oceanlidar_owner"
"""Root attribute naming who wrote a store: the job service's submitter (`create_store`)."""
LABELS_CHECKSUM = "labels_crc32c"
"""Root attribute: the `labels_checksum` of the labels and coordinates the template wrote
(stores written since issue #37), which a reader compares the stored ones with in one
read (`service.store.integrity.check_labels`)."""


def label_names(names) -> list[str]:
    """The labels and coordinates among a store's variable `names`, sorted.

    What the template writes once (`template`): neither a rendered variable nor the
    completion flags nor a checksum, which the tasks write.
    """
    samples = {*rendered_order(), "completed"}
    return sorted(str(n) for n in names if n not in samples and not str(n).startswith("checksum"))


def labels_checksum(values: dict) -> int:
    """CRC32C of a store's labels and coordinates: `values` by name (`label_names`).

    Each variable's name, then its values: numbers as their little-endian bytes, anything
    else (names, lists as JSON) as text, so that the values read back from the store give
    the checksum the template's gave.
    """
    crc = 0
    for name in label_names(values):
        array = np.asarray(values[name])
        if array.dtype.kind in "OUST":
            data = "\x1f".join(str(value) for value in array.ravel()).encode()
        else:
            data = np.ascontiguousarray(array, array.dtype.newbyteorder("<")).tobytes()
        crc = google_crc32c.extend(google_crc32c.extend(crc, name.encode() + b"\0"), data)
    return crc


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
            raise BadSweepError(
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
            raise BadSweepError(
                "scene.surface.spacing: with save_surface the stored surface grid must be the "
                "same for every point, but the default surface.spacing follows the receiver's "
                "footprint (platform.altitude, platform.nadir_deg, platform.azimuth_deg, "
                "receiver.field_of_view_deg), which this sweep varies; set surface.spacing "
                "(and surface.coarse_patches) explicitly"
            )
        raise BadSweepError(
            f"sweep.parameters.{path}: cannot vary within one sweep (it sets the shape of "
            "the stored arrays); run one sweep per value"
        )


def widest_image(plan: Plan, tables: list[dict[str, Variable]]) -> Variable:
    """The ``image`` variable whose type holds every point's counts.

    Counts take the narrowest unsigned type their scene needs
    (`workers.dataset.variables.count_dtype`), which differs between points (a brighter target, a
    lower platform); the store holds the widest, and the values of every point unchanged.
    Points whose images are floats (an ICCD gain, no noise) beside points of counts make
    the store's image a float type that holds every count exactly (float32 up to 16-bit
    counts, else float64); its ``long_name`` then names what each kind of point holds.
    `tables`: every point's `workers.dataset.variables.variables`.
    """
    images: dict = {}
    for table in tables:
        images.setdefault(table["image"].dtype, table["image"])
    widest = plan.image_dtype()
    if len({dtype.kind for dtype in images}) == 1:
        return images[widest]
    floats = next(image for dtype, image in images.items() if dtype.kind == "f")
    names = sorted({image.attrs["long_name"] for image in images.values()})
    attrs = {**floats.attrs, "long_name": f"by point: {'; or '.join(names)}"}
    return dataclasses.replace(floats, dtype=widest, attrs=attrs)


def store_variables(plan: Plan) -> dict[str, Variable]:
    """The store's variables: the union of every point's `workers.dataset.variables.variables`.

    Each name's variable is that of the first point that has it; the image's type is the
    widest (`widest_image`). A variable only some points render is stored for every
    sample: ``expected_stderr``, of the points that ``transport.method`` renders by Monte
    Carlo, is 0 for the small-angle points (deterministic, no Monte Carlo error:
    `service.store.shards.write_shard` writes the zeros), as its ``comment`` says.
    """
    tables = [variables(scene) for scene in _representatives(plan)]
    union: dict = {}
    for table in tables:
        for name, variable in table.items():
            union.setdefault(name, variable)
    union["image"] = widest_image(plan, tables)
    if "expected_stderr" in union:
        stderr = union["expected_stderr"]
        attrs = {**stderr.attrs, "comment": STDERR_COMMENT}
        union["expected_stderr"] = dataclasses.replace(stderr, attrs=attrs)
    return union


def _representatives(plan: Plan) -> list[Scene]:
    """The first scene of each kind of table among the plan's points, in point order.

    A scene's variable names follow from its ``transport.method`` and ``save_surface``
    alone, and their types from its image type (`service.sweep.Plan.image_dtypes`): a
    later scene of the same kind adds nothing to `store_variables`' union, and tables are
    worked out for these scenes alone (each sets its scene up: a few milliseconds).
    """
    kinds: dict = {}
    for scene, image in plan.image_dtypes.items():
        kinds.setdefault((scene.transport.method, scene.save_surface, image), scene)
    return list(kinds.values())


def _coordinate_array(values: list) -> np.ndarray:
    """Numbers as numbers; anything else (names, lists) as strings (zarr's `string`)."""
    if all(isinstance(v, bool | int | float) for v in values):
        return np.asarray(values)
    return np.asarray([v if isinstance(v, str) else json.dumps(v) for v in values], dtype=object)


def create_store(
    plan: Plan,
    store: Store,
    *,
    samples_per_shard: int | None = None,
    owner: str | None = None,
    backend: Backend = NUMPY,
) -> None:
    """Write the template of the store: metadata, coordinates, empty data arrays.

    Parameters
    ----------
    plan : Plan
        The validated sweep.
    store : Store
        Where; nothing but the writer's lock may be there yet.
    samples_per_shard : int, optional
        Consecutive samples per shard, the unit a task renders and writes; by default
        `service.store.layout.shard_size`'s choice.
    owner : str, optional
        Who writes it, recorded in its `OWNER` attribute: the job service's submitter,
        whom the store's record names even if the job table is lost.
    backend : Backend, optional
        Where its samples render, recorded in its root attributes
        (`service.devices.recorded`): a resume must render on the same.
    """
    ds, encoding = template(plan, samples_per_shard)
    ds.attrs.update(recorded(backend))
    if owner is not None:
        ds.attrs[OWNER] = owner
    # mode "a": the folder holds the writer's lock
    store.write(ds, mode="a", compute=False, encoding=encoding)


def rendered_shapes(plan: Plan, table: dict[str, Variable] | None = None) -> dict:
    """The rendered variables the store of `plan` holds, and a sample's shape of each.

    In `workers.dataset.variables.rendered_order`; what `template` lays out and what
    `service.store.integrity.stale_layout` compares a store with, without the labels.
    `table`: the plan's `store_variables`, if already worked out; else the names and dims
    of each kind's first scene (`service.sweep.Plan.representatives`), which are those of
    `store_variables` without working out every point's image type.
    """
    if table is None:
        table = {}
        for scene in plan.representatives():
            for name, variable in variables(scene).items():
                table.setdefault(name, variable)
    first = plan.scenes[0]
    sizes = {
        "frame": first.sequence.frames,
        "gate": len(first.receiver.gate_depths),
        "y": first.receiver.pixels,
        "x": first.receiver.pixels,
    }
    if first.save_surface:
        sizes.update(dict.fromkeys(("sy", "sx"), surface_axis(first).size))
    return {
        name: tuple(sizes[dim] for dim in table[name].dims)
        for name in rendered_order()
        if name in table and (name != "expected" or plan.sweep.store.expected)
    }


def template(plan: Plan, samples_per_shard: int | None = None) -> tuple[xr.Dataset, dict]:
    """The store's template (`create_store`): the dataset, rendered arrays lazy, and encoding.

    Everything but the rendered arrays and the completion flags and checksums (the labels,
    the platform track, the coordinates) follows from the plan alone: the values
    `service.store.integrity.wrong_labels` compares a store's with.
    """
    check_uniform(plan)
    first = plan.scenes[0]
    # names, dimensions, dtypes and attributes from the renderer's tables; nothing rendered
    table = store_variables(plan)
    axis = surface_axis(first) if first.save_surface else None
    n = plan.samples
    shard = min(shard_size(plan, samples_per_shard), n)
    realisations = plan.realisations
    data_vars = {}
    encoding = {}
    for name, shape in rendered_shapes(plan, table).items():
        variable = table[name]
        fill = np.nan if variable.dtype.kind == "f" else 0
        array = lazy_array((n, *shape), fill, variable.dtype, multiple=shard)
        data_vars[name] = (("sample", *variable.dims), array, dict(variable.attrs))
        if variable.sharded:
            encoding[name] = sharded(shape, shard, variable.dtype)
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
    data_vars["checksum_bound"] = (
        ("sample",),
        lazy_array((n,), 0, np.uint32, multiple=shard),
        {
            "long_name": "CRC32C of the sample's identity and rendered arrays",
            "comment": "the identity: sample index, point, realisation, sweep_sha256 and seed "
            "(service.store.shards.sample_identity), then the arrays in the store's order",
            "units": "1",
        },
    )
    for name in ("completed", "checksum", "checksum_bound"):
        encoding[name] = per_shard((), shard)
    # labels and the platform track follow from each point's scene: written once, here
    track = [name for name, v in table.items() if v.role is Role.TRACK]
    per_point = [sample_labels(scene).reset_coords(track) for scene in plan.scenes]
    first_labels = per_point[0]
    if not all(labels.y.equals(first_labels.y) for labels in per_point):
        # the footprint varies (altitude, field of view, nadir): the pixels have no common
        # place on the sea, and the store no y and x coordinates
        per_point = [labels.drop_vars(["y", "x"]) for labels in per_point]
    labels = xr.concat(per_point, dim="sample", data_vars="all")
    for name in (name for name, v in table.items() if v.role in (Role.LABEL, Role.TRACK)):
        variable = labels[name]
        data_vars[name] = (
            variable.dims,
            np.repeat(variable.values, realisations, axis=0),
            dict(variable.attrs),
        )
    coords = {
        **{name: labels[name] for name in labels.coords},
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
            coords[name] = (name, axis, dict(table[name].attrs))
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
    labels = {name: ds[name].values for name in label_names(ds.variables)}
    ds.attrs[LABELS_CHECKSUM] = labels_checksum(labels)
    return ds, encoding
