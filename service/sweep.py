"""The sweep file: schema, safe loading, and expansion into parameter points and samples.

A sweep is a scene (defaults for every sample), a set of parameters addressed by dotted
paths into the scene (``target.depth``), a method that turns them into parameter points
(``grid``, ``zip`` or ``random``), and a number of Monte Carlo realisations per point.
Sample ``s`` is realisation ``s % realisations`` of point ``s // realisations``.
"""

from __future__ import annotations

import copy
import csv
import hashlib
import io
import itertools
import json
import math
import os
import re
import stat
from collections.abc import Hashable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    model_validator,
)

from workers.cascades import MAX_CASCADES
from workers.scene import Scene

__all__ = [
    "Plan",
    "Sweep",
    "SweepError",
    "field_units",
    "human_bytes",
    "load_sweep",
    "memory_estimate",
    "parse_sweep",
    "read_measurements",
    "read_text",
    "scene_field",
    "shown",
]

MAX_FILE_BYTES = 1_000_000
MAX_DEPTH = 20
MAX_NODES = 1_000_000
MAX_POINTS = 10_000_000
DEFAULT_MAX_SAMPLES = 1_000_000
DEFAULT_MAX_BYTES = 50 * 2**30
DEFAULT_MAX_MEMORY = 4 * 2**30
"""Most memory [bytes] one sample may need to render (`memory_estimate`); ``--max-memory``
sets another, ``--no-limits`` lifts it."""
MAX_TRAVEL = 100_000.0
"""Farthest the platform may fly during a sequence [m]: beyond 100 km, float32 ray
coordinates resolve less than a centimetre, coarser than the surface grids need."""


class SweepError(ValueError):
    """A sweep file a user must fix: the message names the place and the reason."""


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Values(_Model):
    """An explicit list of values."""

    values: Annotated[list[Any], Field(min_length=1, max_length=100_000)]


class Value(_Model):
    """One fixed value."""

    value: Any


class Distribution(_Model):
    """A random distribution, for ``method: random``."""

    distribution: Literal["uniform", "log_uniform", "normal", "int_uniform"]
    min: float | None = None
    max: float | None = None
    mu: float | None = None
    sigma: float | None = Field(None, gt=0.0)

    @model_validator(mode="after")
    def _parameters(self) -> Distribution:
        if self.distribution == "normal":
            if self.mu is None or self.sigma is None:
                raise ValueError("a normal distribution needs mu and sigma")
            if self.min is not None or self.max is not None:
                raise ValueError("a normal distribution takes mu and sigma, not min and max")
            if not np.isfinite(self.mu + 10 * self.sigma):
                raise ValueError("mu and sigma must be finite and moderate")
            return self
        if self.mu is not None or self.sigma is not None:
            raise ValueError(f"a {self.distribution} distribution takes min and max")
        if self.min is None or self.max is None:
            raise ValueError(f"a {self.distribution} distribution needs min and max")
        if not np.isfinite(self.max - self.min):
            raise ValueError("min and max must be finite, and their difference too")
        if self.distribution == "int_uniform" and math.ceil(self.min) > math.floor(self.max):
            raise ValueError("an int_uniform distribution needs an integer between min and max")
        if self.min > self.max or (self.min == self.max and self.distribution != "int_uniform"):
            raise ValueError("min must be below max")
        if self.distribution == "log_uniform" and self.min <= 0:
            raise ValueError("a log_uniform distribution needs min > 0")
        return self

    def draw(self, rng: np.random.Generator, count: int) -> list:
        """`count` draws, as plain Python numbers."""
        if self.distribution == "uniform":
            return rng.uniform(self.min, self.max, count).tolist()
        if self.distribution == "log_uniform":
            return np.exp(rng.uniform(np.log(self.min), np.log(self.max), count)).tolist()
        if self.distribution == "normal":
            return rng.normal(self.mu, self.sigma, count).tolist()
        return rng.integers(
            math.ceil(self.min), math.floor(self.max), count, endpoint=True
        ).tolist()


def _parameter_kind(data: Any) -> str | None:
    for model, kind in ((Values, "list"), (Value, "fixed"), (Distribution, "random")):
        if isinstance(data, model):
            return kind
    if isinstance(data, dict):
        for key, kind in (("values", "list"), ("value", "fixed"), ("distribution", "random")):
            if key in data:
                return kind
    return None


Parameter = Annotated[
    Annotated[Values, Tag("list")]
    | Annotated[Value, Tag("fixed")]
    | Annotated[Distribution, Tag("random")],
    Discriminator(
        _parameter_kind,
        custom_error_type="parameter",
        custom_error_message="a parameter needs values: [...], value: x or distribution: ...",
    ),
]


class SweepSpec(_Model):
    """How parameters combine into points."""

    method: Literal["grid", "zip", "random"] = "grid"
    count: int | None = Field(None, ge=1, le=10_000_000)
    parameters: dict[str, Parameter] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _consistent(self) -> SweepSpec:
        if self.method == "random":
            if self.count is None:
                raise ValueError("method random needs a count")
        elif self.count is not None:
            raise ValueError(f"count applies to method random only, not {self.method}")
        if self.method != "random":
            for path, parameter in self.parameters.items():
                if isinstance(parameter, Distribution):
                    raise ValueError(f"{path}: distributions need method random")
        if self.method == "zip":
            lengths = {
                path: len(p.values) for path, p in self.parameters.items() if isinstance(p, Values)
            }
            if len(set(lengths.values())) > 1:
                raise ValueError(f"method zip needs equally long value lists, got {lengths}")
        return self


class Sweep(_Model):
    """A sweep file."""

    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")
    seed: int = Field(ge=0, le=2**63 - 1)
    realisations: int = Field(1, ge=1, le=1_000_000)
    output: str = Field(min_length=1, max_length=4096)
    scene: dict[str, Any] = Field(default_factory=dict)
    sweep: SweepSpec = SweepSpec()


@dataclass(frozen=True)
class Plan:
    """A validated, expanded sweep.

    Attributes
    ----------
    sweep : Sweep
        The parsed file.
    text : str
        The file's text, stored with the data.
    digest : str
        SHA-256 of the canonical form of the sweep (the output location excluded), which
        `--resume` compares.
    points : tuple of dict
        For every parameter point, the dotted-path values that define it.
    scenes : tuple of Scene
        The validated scene of every point.
    """

    sweep: Sweep
    text: str
    digest: str
    points: tuple[dict[str, Any], ...]
    scenes: tuple[Scene, ...]

    @property
    def realisations(self) -> int:
        """Monte Carlo samples per point."""
        return self.sweep.realisations

    @property
    def samples(self) -> int:
        """Total number of samples."""
        return len(self.points) * self.sweep.realisations

    @property
    def swept(self) -> tuple[str, ...]:
        """Dotted paths that vary across the sweep, in file order."""
        return tuple(self.sweep.sweep.parameters)

    def sample_bytes(self) -> int:
        """Estimated stored bytes of the largest sample (uncompressed)."""
        return max(_sample_bytes(scene) for scene in self.scenes)

    def total_bytes(self) -> int:
        """Estimated stored bytes of the whole sweep (uncompressed)."""
        r = self.sweep.realisations
        return sum(_sample_bytes(scene) * r for scene in self.scenes)

    def check_limits(self, *, max_samples=DEFAULT_MAX_SAMPLES, max_bytes=DEFAULT_MAX_BYTES):
        """Refuse sweeps beyond the size limits (the caller may lift them)."""
        if self.samples > max_samples:
            raise SweepError(
                f"the sweep has {self.samples:,} samples, over the limit of {max_samples:,}; "
                "pass --no-limits to run it anyway"
            )
        if self.total_bytes() > max_bytes:
            raise SweepError(
                f"the sweep would store about {human_bytes(self.total_bytes())}, over the "
                f"limit of {human_bytes(max_bytes)}; pass --no-limits to run it anyway"
            )


def _sample_bytes(scene: Scene) -> int:
    pixels = scene.receiver.pixels**2
    frames = scene.sequence.frames
    gates = len(scene.receiver.gate_depths)
    size = frames * (gates * pixels * 8 + pixels)
    if scene.save_surface:
        size += frames * scene.surface.grid_size**2 * 4
    return size


SHOWN_CHARACTERS = 60
"""Longest echo of a user's value in a message; longer ones are cut."""


def shown(value: Any) -> str:
    """`value` for a message: its repr, cut to `SHOWN_CHARACTERS`."""
    text = repr(value)
    if len(text) <= SHOWN_CHARACTERS:
        return text
    return f"{text[: SHOWN_CHARACTERS - 12]}... ({len(text):,} characters)"


def human_bytes(n: float) -> str:
    """A byte count for people (binary units)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def _check_structure(text: str) -> None:
    """Refuse YAML that nests too deep or expands too far, before building any object.

    Aliases are counted at their expanded size, so an "alias bomb" (nested lists of
    aliases that expand exponentially) is refused from the event stream alone.
    """
    sizes: dict[str, int] = {}
    stack: list[list] = [[None, 0]]
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.CollectionStartEvent):
            stack.append([event.anchor, 0])
            if len(stack) - 1 > MAX_DEPTH:
                raise SweepError(f"the file nests deeper than {MAX_DEPTH} levels")
        elif isinstance(event, yaml.CollectionEndEvent):
            anchor, count = stack.pop()
            if anchor is not None:
                sizes[anchor] = count + 1
            stack[-1][1] += count + 1
        elif isinstance(event, yaml.ScalarEvent):
            if event.anchor is not None:
                sizes[event.anchor] = 1
            stack[-1][1] += 1
        elif isinstance(event, yaml.AliasEvent):
            if any(anchor == event.anchor for anchor, _ in stack):
                raise SweepError(
                    f"line {event.start_mark.line + 1}: the alias *{event.anchor} refers to "
                    "a collection that contains it (a self-referential alias)"
                )
            stack[-1][1] += sizes.get(event.anchor, 1)
        if stack[-1][1] > MAX_NODES:
            raise SweepError(
                f"the file expands to more than {MAX_NODES:,} values (through YAML aliases?)"
            )


class _Loader(yaml.SafeLoader):
    """YAML's safe loader, stricter: no duplicate keys, no sets.

    A duplicate key would silently win over the first; a set (``!!set``) has no order, so
    a list of values built from it could differ from one process to the next.
    """

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            if isinstance(key, Hashable) and key in seen:
                raise SweepError(
                    f"line {line}: duplicate key {shown(key)} (first on line {seen[key]})"
                )
            if isinstance(key, Hashable):
                seen[key] = line
        return super().construct_mapping(node, deep=deep)

    def construct_set(self, node):
        raise SweepError(
            f"line {node.start_mark.line + 1}: YAML sets (!!set) are not accepted: they have "
            "no order, so the sweep would not mean one sequence of samples; use a list"
        )


_Loader.add_constructor("tag:yaml.org,2002:set", _Loader.construct_set)
# YAML 1.1 reads 1e-3 (no dot) as a string; YAML 1.2, and people, read a number
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _read_yaml(text: str) -> Any:
    if len(text.encode()) > MAX_FILE_BYTES:
        raise SweepError(f"the file is larger than {MAX_FILE_BYTES:,} bytes")
    if "\x00" in text:
        raise SweepError("the file is not YAML text (it contains NUL bytes)")
    try:
        _check_structure(text)
        loader = _Loader(text)  # a SafeLoader: plain YAML only
        try:
            return loader.get_single_data()
        finally:
            loader.dispose()
    except yaml.constructor.ConstructorError as error:
        raise SweepError(
            f"line {error.problem_mark.line + 1}: {error.problem} (only plain YAML is "
            "accepted: no language-specific tags)"
        ) from None
    except yaml.MarkedYAMLError as error:
        where = f"line {error.problem_mark.line + 1}: " if error.problem_mark else ""
        raise SweepError(f"{where}not valid YAML: {error.problem}") from None
    except yaml.YAMLError as error:
        raise SweepError(f"not valid YAML: {error}") from None


def _strict_numbers(raw: Any, parsed: Any, place: str) -> None:
    """Refuse a boolean or a string that validation turned into a number, and NaN or inf.

    pydantic reads ``true`` as 1 and ``"7"`` as 7 where a number goes; a sweep file must
    write numbers as numbers, and finite ones. `raw` is what the file gave, `parsed` the
    validated model's dump, walked side by side.
    """
    if isinstance(parsed, float) and not math.isfinite(parsed):
        raise SweepError(f"{place}: must be a finite number, got {shown(raw)}")
    if isinstance(raw, bool | str):
        if isinstance(parsed, int | float) and not isinstance(parsed, bool):
            kind = "a boolean" if isinstance(raw, bool) else "a string"
            raise SweepError(
                f"{place or '(top level)'}: expected a number, got {kind}, {shown(raw)}"
            )
        return
    if isinstance(raw, dict) and isinstance(parsed, dict):
        pairs = [(key, raw[key], parsed[key]) for key in raw if key in parsed]
    elif isinstance(raw, list) and isinstance(parsed, list | tuple) and len(raw) == len(parsed):
        pairs = [(str(i), a, b) for i, (a, b) in enumerate(zip(raw, parsed, strict=True))]
    else:
        return
    for key, a, b in pairs:
        _strict_numbers(a, b, f"{place}.{key}" if place else str(key))


def _raw(data: dict, path: str) -> Any:
    """The value at dotted `path` of a raw scene dict, or the schema's default."""
    node: Any = data
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            return scene_field(path).default
        node = node[part]
    return node


def memory_estimate(scene: dict) -> int:
    """Memory [bytes] that rendering one sample of a raw scene needs: an upper estimate.

    Read from the scene's values before anything is built, since validating a scene
    already builds its kriging system. An empirical bound on peak allocations measured on
    the renderer of 2026-11-23 (the shipped configs need 0.8 to 5 times less): per frame,
    256 bytes per pixel and gate (plane grids, MTF filters, images; the frames' geometry
    is cached) and 128 bytes per surface grid point and cascade (``surface.coarse_patches``
    plus one, or at most `workers.cascades.MAX_CASCADES` by default); the kriging system of
    measurements at G distinct times holds about 8 + G(G + 1)/8 complex grids per cascade
    (one covariance grid per time lag, G(G + 1)/2 of them, built in turn).

    Returns
    -------
    int
        The estimate; 0 if the values are not numbers (validation then says why).
    """
    try:
        grid = int(_raw(scene, "surface.grid_size"))
        pixels = int(_raw(scene, "receiver.pixels"))
        frames = int(_raw(scene, "sequence.frames"))
        gates = _raw(scene, "receiver.gates")
        gates = 6 if gates == "mldc" else len(gates)
        points = ((scene.get("surface") or {}).get("conditioning") or {}).get("points") or []
        times = len({point[3] if len(point) > 3 else 0.0 for point in points})
        patches = (scene.get("surface") or {}).get("coarse_patches")
        cascades = MAX_CASCADES if patches is None else len(patches) + 1
    except (TypeError, ValueError, AttributeError, IndexError):
        return 0
    render = frames * (256 * pixels**2 * (gates + 1) + 128 * grid**2 * cascades)
    kriging = 16 * grid**2 * cascades * (8 + times * (times + 1) / 8) if points else 0
    return int(render + kriging)


def _check_memory(scene: dict, max_memory: float | None) -> None:
    estimate = memory_estimate(scene)
    if max_memory is not None and estimate > max_memory:
        raise SweepError(
            f"scene: one sample would need about {human_bytes(estimate)} of memory to render "
            f"(surface.grid_size, receiver.pixels, sequence.frames, measurement times), over "
            f"the limit of {human_bytes(max_memory)}; pass --max-memory GIB or --no-limits "
            "to run it anyway"
        )


def _check_scene(raw: dict, scene: Scene) -> None:
    """Checks of a validated scene beyond its schema: strict numbers, a bounded track."""
    _strict_numbers(raw, scene.model_dump(), "scene")
    sequence = scene.sequence
    travel = max(map(abs, sequence.velocity)) * ((sequence.frames - 1) * sequence.interval)
    if travel > MAX_TRAVEL:
        raise SweepError(
            f"scene.sequence.velocity: the platform would fly {travel:.3g} m during the "
            f"sequence, over the limit of {MAX_TRAVEL:,.0f} m"
        )


def _format_errors(error: ValidationError, prefix: str = "") -> str:
    lines = []
    for item in error.errors():
        location = ".".join(str(part) for part in item["loc"] if not _is_union_tag(part))
        place = ".".join(filter(None, [prefix, location])) or "(top level)"
        lines.append(f"{place}: {item['msg']}")
    return "\n".join(dict.fromkeys(lines))


def _is_union_tag(part) -> bool:
    return part in {"list", "fixed", "random"} or str(part).startswith("function-after")


def load_sweep(path, *, max_memory: float | None = DEFAULT_MAX_MEMORY) -> Plan:
    """Read, validate and expand a sweep file.

    `max_memory` (bytes; None: no limit) is the most one sample may need to render
    (`memory_estimate`), checked before any scene is built.

    Raises
    ------
    SweepError
        With a message that names the place and the reason.
    """
    text = read_text(path, place=str(path))
    return parse_sweep(text, folder=Path(path).parent, max_memory=max_memory)


def read_text(path, *, place: str) -> str:
    """The UTF-8 text of a regular file of at most `MAX_FILE_BYTES` bytes.

    The file is opened without blocking and checked to be a regular file before anything
    is read (a FIFO would block, ``/dev/zero`` never ends), then at most the limit plus
    one byte is read.

    Raises
    ------
    SweepError
        Naming `place`, if the file is missing, not a regular file, too large or not
        UTF-8 text.
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as error:
        raise SweepError(f"{place}: {error.strerror}") from None
    with os.fdopen(descriptor, "rb") as handle:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise SweepError(f"{place}: not a regular file")
        try:
            data = handle.read(MAX_FILE_BYTES + 1)
        except OSError as error:
            raise SweepError(f"{place}: {error.strerror}") from None
    if len(data) > MAX_FILE_BYTES:
        raise SweepError(f"{place}: the file is larger than {MAX_FILE_BYTES:,} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise SweepError(f"{place}: not a UTF-8 text file") from None


def parse_sweep(text: str, *, folder=None, max_memory: float | None = DEFAULT_MAX_MEMORY) -> Plan:
    """Validate and expand sweep YAML text (see `load_sweep`).

    Parameters
    ----------
    text : str
        The sweep file's text.
    folder : path-like or None, optional
        Folder that relative paths in the sweep are relative to (`load_sweep` passes the
        sweep file's); None: the current directory.
    max_memory : float or None, optional
        The most memory [bytes] one sample may need (see `load_sweep`).

    Notes
    -----
    A ``scene.surface.conditioning.file`` is read here (`read_measurements`) and replaced
    by the ``points`` it holds, so the workers see inline points only and the sweep's
    digest covers the measured values, not just the file name.
    """
    data = _read_yaml(text)
    if not isinstance(data, dict):
        raise SweepError("the file must be a YAML mapping with name, seed, output and scene")
    _inline_measurements(data, Path(folder) if folder is not None else Path())
    try:
        sweep = Sweep.model_validate(data)
    except ValidationError as error:
        raise SweepError(_format_errors(error)) from None
    _strict_numbers(data, sweep.model_dump(), "")
    _check_memory(sweep.scene, max_memory)
    try:
        default = Scene.model_validate(sweep.scene)
    except ValidationError as error:
        raise SweepError(_format_errors(error, "scene")) from None
    _check_scene(sweep.scene, default)
    for path in sweep.sweep.parameters:
        scene_field(path)
    points = _expand(sweep)
    if not points:
        raise SweepError("sweep: the sweep expands to no parameter point")
    scenes = []
    cache: dict[str, Scene] = {}
    for index, point in enumerate(points):
        data = copy.deepcopy(sweep.scene)
        for path, value in point.items():
            _assign(data, path, value)
        key = json.dumps(data, sort_keys=True, default=str)
        if key not in cache:
            values = ", ".join(f"{p}={shown(v)}" for p, v in point.items())
            try:
                _check_memory(data, max_memory)
                cache[key] = Scene.model_validate(data)
                _check_scene(data, cache[key])
            except ValidationError as error:
                raise SweepError(
                    f"parameter point {index} ({values}):\n" + _format_errors(error, "scene")
                ) from None
            except SweepError as error:
                raise SweepError(f"parameter point {index} ({values}):\n{error}") from None
        scenes.append(cache[key])
    canonical = sweep.model_dump(mode="json", exclude={"output"})
    # parameters in file order: grid expansion and random draws follow it
    canonical["sweep"]["parameters"] = list(canonical["sweep"]["parameters"].items())
    digest = hashlib.sha256(json.dumps(canonical, sort_keys=True).encode()).hexdigest()
    return Plan(sweep=sweep, text=text, digest=digest, points=tuple(points), scenes=tuple(scenes))


def _inline_measurements(data: dict, folder: Path) -> None:
    """Replace ``scene.surface.conditioning.file`` in `data` by the points it holds."""
    scene = data.get("scene")
    surface = scene.get("surface") if isinstance(scene, dict) else None
    conditioning = surface.get("conditioning") if isinstance(surface, dict) else None
    if not isinstance(conditioning, dict) or "file" not in conditioning:
        return
    place = "scene.surface.conditioning"
    name = conditioning.pop("file")
    if name is None:
        return
    if not isinstance(name, str) or not name:
        raise SweepError(f"{place}.file: must be the path of a CSV file, got {shown(name)}")
    relative = os.path.normpath(name)
    if os.path.isabs(relative) or relative.split(os.sep)[0] == os.pardir:
        raise SweepError(
            f"{place}.file: must name a file in the sweep file's folder or below it, "
            f"got {shown(name)}"
        )
    if conditioning.get("points") is not None:
        raise SweepError(f"{place}: give points or file, not both")
    conditioning["points"] = read_measurements(folder / relative, place=f"{place}.file")


def read_measurements(path, *, place: str = "measurements") -> list[list[float]]:
    """Measured elevations from a CSV file.

    The first line names the columns, ``x,y,elevation`` or ``x,y,elevation,time``
    (m, m, m, s); then one point a line. Blank lines and lines starting with ``#`` are
    skipped.

    Parameters
    ----------
    path : path-like
        The CSV file.
    place : str, optional
        Where the file was named, for error messages.

    Returns
    -------
    list of list of float
        One [x, y, elevation(, time)] per point, as ``surface.conditioning.points``
        takes them.

    Raises
    ------
    SweepError
        If the file cannot be read, is larger than the sweep-file limit, or a line is
        not the header's number of finite numbers.
    """
    place = f"{place}: {shown(str(path))}"
    try:
        lines = [
            (number, row)
            for number, row in enumerate(
                csv.reader(io.StringIO(read_text(path, place=place), newline="")), start=1
            )
            if row and "".join(row).strip() and not row[0].lstrip().startswith("#")
        ]
    except csv.Error as error:
        raise SweepError(f"{place}: not CSV ({error})") from None
    columns = ["x", "y", "elevation", "time"]
    header = [name.strip().lower() for name in lines[0][1]] if lines else []
    if header not in (columns[:3], columns):
        # the file's contents are never echoed: it may be any file the user can read
        raise SweepError(
            f"{place}: must start with the header line x,y,elevation or x,y,elevation,time"
        )
    points = []
    for number, row in lines[1:]:
        try:
            values = [float(value) for value in row]
        except ValueError:
            values = []
        if len(values) != len(header) or not all(math.isfinite(v) for v in values):
            raise SweepError(
                f"{place} line {number}: expected {len(header)} finite numbers "
                f"({','.join(header)})"
            )
        points.append(values)
    if not points:
        raise SweepError(f"{place}: holds no points")
    return points


def scene_field(path: str):
    """The pydantic field a dotted path names in the scene (a leaf value).

    Raises
    ------
    SweepError
        If the path names no field, or a section rather than a value.
    """
    model: Any = Scene
    parts = path.split(".")
    field = None
    for depth, part in enumerate(parts):
        fields = getattr(model, "model_fields", None)
        if fields is None or part not in fields:
            known = ", ".join(sorted(fields)) if fields else "nothing (a leaf value)"
            where = ".".join(parts[:depth]) or "the scene"
            raise SweepError(f"sweep.parameters.{path}: unknown path; {where} has {known}")
        field = fields[part]
        annotation = field.annotation
        is_model = isinstance(annotation, type) and issubclass(annotation, BaseModel)
        model = annotation if is_model else None
    if model is not None:
        raise SweepError(f"sweep.parameters.{path}: names a section, not a value")
    return field


def field_units(path: str) -> str:
    """The unit a scene field's description gives in brackets at its end ('1' if none)."""
    found = re.search(r"\[([^\]]+)\]\.?\s*$", scene_field(path).description or "")
    return found.group(1) if found else "1"


def _assign(data: dict, path: str, value: Any) -> None:
    *parents, leaf = path.split(".")
    node = data
    for part in parents:
        child = node.get(part)
        if not isinstance(child, dict):
            child = {}
            node[part] = child
        node = child
    node[leaf] = value


def _expand(sweep: Sweep) -> list[dict[str, Any]]:
    spec = sweep.sweep
    params = spec.parameters
    if not params:
        return [{}]
    if spec.method == "random":
        rng = np.random.Generator(
            np.random.PCG64(np.random.SeedSequence(sweep.seed, spawn_key=(2,)))
        )
        columns = {}
        for path, p in params.items():
            if isinstance(p, Distribution):
                columns[path] = p.draw(rng, spec.count)
            elif isinstance(p, Values):
                picks = rng.integers(0, len(p.values), spec.count)
                columns[path] = [p.values[i] for i in picks]
            else:
                columns[path] = [p.value] * spec.count
        return [{path: columns[path][i] for path in params} for i in range(spec.count)]
    lists = {
        path: (p.values if isinstance(p, Values) else [p.value]) for path, p in params.items()
    }
    if spec.method == "zip":
        length = max(len(v) for v in lists.values())
        return [
            {path: (v * length if len(v) == 1 else v)[i] for path, v in lists.items()}
            for i in range(length)
        ]
    size = math.prod(len(v) for v in lists.values())
    if size > MAX_POINTS:
        raise SweepError(
            f"sweep: the grid has {size:,} parameter points, over the limit of {MAX_POINTS:,}"
        )
    combos = itertools.product(*lists.values())
    return [dict(zip(lists, combo, strict=True)) for combo in combos]
