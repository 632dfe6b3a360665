"""A sweep expanded into parameter points and samples: the `Plan`, with its size limits.

`load_sweep` reads a sweep file safely (`service.inputs`), inlines its measurement files
(`service.measurements`), validates it against the schema (`service.schema`) and every
point's scene, and expands the parameters into points (``grid``, ``zip``, ``random``, or
the space-filling ``latin_hypercube`` and ``sobol`` of `scipy.stats.qmc`).
`Plan.sample` addresses the samples, in one place: sample ``s`` is realisation
``s % realisations`` of point ``s // realisations``, with the random streams of
`workers.settings.seeds.SampleSeed` keyed by (root seed, point, realisation).
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from dask.utils import format_bytes
from pydantic import ValidationError
from scipy.stats import qmc

from service.errors import BadSweepError, TooBigError
from service.inputs import DEFAULT_MAX_MEMORY, read_text, read_yaml, shown, strict_numbers
from service.measurements import inline_measurements
from service.points import Scenes, check_scene, format_errors, raw_value
from service.schema import Distribution, Sweep, Value, Values, scene_field
from workers.dataset.variables import count_dtype
from workers.fast.spread import MAX_COARSE
from workers.montecarlo.renderer import LAUNCH_CHUNK, LOOKUP_ENTRIES
from workers.sea.cascades import MAX_CASCADES
from workers.settings.scene import Scene, laser_rays
from workers.settings.seeds import SampleSeed

__all__ = ["Plan", "Sample", "load_sweep", "memory_estimate", "parse_sweep", "read_header"]

MAX_POINTS = 10_000_000
DEFAULT_MAX_SAMPLES = 1_000_000
DEFAULT_MAX_BYTES = 50 * 2**30
NO_LIMITS = "pass --no-limits to run it anyway"
"""What the command line's messages about the limits advise."""
MEMORY_REMEDY = "pass --max-memory GIB or --no-limits to run it anyway"
"""What the command line's messages about the memory limit advise."""


@dataclass(frozen=True)
class Sample:
    """One sample of a plan: where it sits, what it renders, and how to name it.

    Attributes
    ----------
    index : int
        Position in the store's ``sample`` dimension.
    point, realisation : int
        Its parameter point and Monte Carlo realisation.
    scene : Scene
        The point's scene.
    seed : SampleSeed
        Its random streams (surface by realisation, noise by point and realisation).
    values : dict
        The point's swept values, by dotted path.
    """

    index: int
    point: int
    realisation: int
    scene: Scene
    seed: SampleSeed
    values: dict[str, Any]

    def describe(self) -> str:
        """The sample by its point, swept values and realisation, for messages."""
        values = ", ".join(f"{path}={shown(value)}" for path, value in self.values.items())
        where = f"point {self.point}" + (f": {values}" if values else "")
        return f"sample {self.index} ({where}; realisation {self.realisation})"


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
    scenes : sequence of Scene
        The validated scene of every point (`service.points.Scenes`: built on first use).
    stored_image : numpy.dtype or None
        For the plan of a resume of a store of this sweep written by this version
        (`parse_sweep`'s `resumed`), the store's image type: its points were checked when
        it was made, their scenes are built only as samples are addressed, and the sizes
        are those of the first scene of each kind (a store's points share their shapes:
        `service.store.template.check_uniform`). None: every scene was built and checked.
    """

    sweep: Sweep
    text: str
    digest: str
    points: tuple[dict[str, Any], ...]
    scenes: Sequence[Scene]
    stored_image: np.dtype | None = None

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

    def sample(self, index: int) -> Sample:
        """Sample `index` (0 to `samples` - 1) of the sweep.

        Raises
        ------
        BadSweepError
            If the sweep has no such sample.
        """
        if not 0 <= index < self.samples:
            raise BadSweepError(f"sample {index}: the sweep has samples 0..{self.samples - 1}")
        point, realisation = divmod(int(index), self.realisations)
        return Sample(
            index=int(index),
            point=point,
            realisation=realisation,
            scene=self.scenes[point],
            seed=SampleSeed(root=self.sweep.seed, point=point, realisation=realisation),
            values=self.points[point],
        )

    @functools.cached_property
    def image_dtypes(self) -> dict[Scene, np.dtype]:
        """The image type of each distinct scene, in point order, worked out once a plan.

        A scene's photoelectron counts take `count_dtype` (which sets its scene up: a few
        milliseconds), other images float32. Every stored image type (`image_dtype`), the
        sizes (`sample_bytes`) and the store's variables
        (`service.store.template.store_variables`) read them from here.
        """
        kinds: dict[Scene, np.dtype] = {}
        for scene in self.scenes:
            if scene not in kinds:
                kinds[scene] = count_dtype(scene) or np.dtype(np.float32)
        return kinds

    def image_dtype(self) -> np.dtype:
        """The store's image type: the widest any point needs.

        Each point's counts take `count_dtype`, other images float32; counts beside floats
        make a float type that holds every count exactly
        (`service.store.template.widest_image`).
        """
        if self.stored_image is not None:
            return self.stored_image
        return np.result_type(*set(self.image_dtypes.values()))

    def representatives(self) -> list[Scene]:
        """The first scene of each kind (``transport.method``, ``save_surface``), in order.

        A scene's stored variables follow from its kind alone
        (`service.store.template.rendered_shapes`).
        """
        kinds = getattr(self.scenes, "kinds", None)
        if not kinds:  # scenes built (a plan's part, `benchmarks/storage.py`)
            kinds = {}
            for point, scene in enumerate(self.scenes):
                kinds.setdefault((scene.transport.method, scene.save_surface), point)
        return [self.scenes[point] for point in sorted(kinds.values())]

    def _sized(self) -> Sequence[Scene]:
        """The scenes whose sizes are taken: every one, or each kind's first if resumed."""
        return self.scenes if self.stored_image is None else self.representatives()

    def float_images(self) -> int:
        """Float32 arrays of an image's shape every sample stores beside ``image``.

        ``expected`` with ``store: {expected: true}``; ``expected_stderr`` when any point is
        rendered by Monte Carlo (``transport.method``;
        `service.store.template.store_variables`).
        """
        monte_carlo = any(s.transport.method == "monte_carlo" for s in self.representatives())
        return int(self.sweep.store.expected) + int(monte_carlo)

    def sample_bytes(self) -> int:
        """Estimated stored bytes of the largest sample (uncompressed)."""
        image, floats = self.image_dtype().itemsize, self.float_images()
        return max(_sample_bytes(s, image=image, floats=floats) for s in self._sized())

    def total_bytes(self) -> int:
        """Estimated stored bytes of the whole sweep (uncompressed)."""
        if self.stored_image is not None:
            return self.samples * self.sample_bytes()
        r = self.sweep.realisations
        image, floats = self.image_dtype().itemsize, self.float_images()
        return sum(_sample_bytes(s, image=image, floats=floats) * r for s in self.scenes)

    def check_limits(
        self,
        *,
        max_samples=DEFAULT_MAX_SAMPLES,
        max_bytes=DEFAULT_MAX_BYTES,
        remedy=NO_LIMITS,
    ):
        """Refuse sweeps beyond the size limits; `remedy` ends the message."""
        if self.samples > max_samples:
            raise TooBigError(
                f"the sweep has {self.samples:,} samples, over the limit of {max_samples:,}; "
                f"{remedy}"
            )
        if self.total_bytes() > max_bytes:
            raise TooBigError(
                f"the sweep would store about {format_bytes(self.total_bytes())}, over the "
                f"limit of {format_bytes(max_bytes)}; {remedy}"
            )


def _sample_bytes(scene: Scene, *, image: int, floats: int) -> int:
    """A sample's stored bytes: its image `image` bytes a value, `floats` float32 images.

    Per frame also the mask (a byte a pixel) and per gate four float32 means (the signal
    means and the target's effect) and the visibility flag.
    """
    pixels = scene.receiver.pixels**2
    frames = scene.sequence.frames
    gates = len(scene.receiver.gate_depths)
    size = frames * (gates * pixels * (image + 4 * floats) + pixels + 17 * gates)
    if scene.save_surface:
        size += frames * scene.surface.grid_size**2 * 4
    return size


def memory_estimate(scene: dict) -> int:
    """Memory [bytes] that rendering one sample of a raw scene needs: an upper estimate.

    Read from the scene's raw values before anything is rendered. An empirical bound on
    peak allocations (traced by ``tracemalloc``, every cache of `workers` empty) of the
    multi-scale, compiled renderer of 2026-11-23: the shipped configs need 1.25 to 7 times
    less (`tests/test_sweep.py` holds it to small scenes of every kind). Once a sample: a
    floor of 384 bytes per cell of a `workers.fast.spread.MAX_COARSE`-sided coarse plane (the
    planes' least size) and 128 bytes per surface grid point and cascade
    (``surface.coarse_patches`` plus one, or at most `workers.sea.cascades.MAX_CASCADES` by
    default), and the Monte Carlo renderer's arrays (`_transport_memory`); then per frame
    512 bytes per pixel (or laser ray, if the laser's lattice is
    the larger) and gate (the frame's geometry, which stays cached, its plane grids and MTF
    filters, the images) and 32 per grid point and cascade (the evolved sea). The kriging
    system of measurements at G distinct times holds about 8 + G(G + 1)/8 complex grids
    per cascade (one covariance grid per time lag, G(G + 1)/2 of them, built in turn).

    Returns
    -------
    int
        The estimate; 0 if the values are not numbers or leave their range (a field of
        view of 0, no batches: validation says why).
    """
    try:
        grid = int(raw_value(scene, "surface.grid_size"))
        pixels = int(raw_value(scene, "receiver.pixels"))
        rays = raw_value(scene, "laser.rays")
        laser = raw_value(scene, "laser.field_of_view_deg")
        rays = laser_rays(
            rays=None if rays is None else int(rays),
            pixels=pixels,
            field_of_view_deg=float(raw_value(scene, "receiver.field_of_view_deg")),
            laser_field_of_view_deg=None if laser is None else float(laser),
        )
        side = max(pixels, rays)
        frames = int(raw_value(scene, "sequence.frames"))
        gates = raw_value(scene, "receiver.gates")
        gates = 6 if gates == "mldc" else len(gates)
        points = ((scene.get("surface") or {}).get("conditioning") or {}).get("points") or []
        times = len({point[3] if len(point) > 3 else 0.0 for point in points})
        patches = (scene.get("surface") or {}).get("coarse_patches")
        cascades = MAX_CASCADES if patches is None else len(patches) + 1
    except (TypeError, ValueError, AttributeError, IndexError, ArithmeticError):
        return 0
    once = 384 * MAX_COARSE**2 + 128 * grid**2 * cascades
    render = once + frames * (512 * side**2 * (gates + 1) + 32 * grid**2 * cascades)
    kriging = 16 * grid**2 * cascades * (8 + times * (times + 1) / 8) if points else 0
    return int(render + kriging + _transport_memory(scene, pixels=pixels, gates=gates))


def _transport_memory(scene: dict, *, pixels: int, gates: int) -> int:
    """Memory [bytes] the Monte Carlo renderer adds to a sample (0 for the small-angle one).

    Its batches' images (float64, three copies at most while their mean and spread are
    taken), a chunk of launched photons (`workers.montecarlo.renderer.LAUNCH_CHUNK`, 64 bytes
    each),
    the lines of sight (taken as S = 4 a pixel side, 64 bytes each) and their lookup (about
    12 bytes per slab and cell, 100 slabs, at most `LOOKUP_ENTRIES` slab-cells).
    """
    try:
        if raw_value(scene, "transport.method") != "monte_carlo":
            return 0
        batches = int(raw_value(scene, "transport.batches"))
        launch = 64 * min(LAUNCH_CHUNK, -(-int(raw_value(scene, "transport.photons")) // batches))
    except (TypeError, ValueError, ArithmeticError):
        return 0
    images = 3 * 8 * batches * gates * pixels**2
    cells = (4 * pixels) ** 2
    return images + launch + 64 * cells + 12 * min(LOOKUP_ENTRIES, 100 * cells)


def _check_memory(scene: dict, *, max_memory: float | None, remedy: str) -> None:
    estimate = memory_estimate(scene)
    if max_memory is not None and estimate > max_memory:
        raise TooBigError(
            f"scene: one sample would need about {format_bytes(estimate)} of memory to render "
            f"(surface.grid_size, receiver.pixels, sequence.frames, measurement times), over "
            f"the limit of {format_bytes(max_memory)}; {remedy}"
        )


def load_sweep(path, *, max_memory: float | None = DEFAULT_MAX_MEMORY) -> Plan:
    """Read, validate and expand a sweep file.

    `max_memory` (bytes; None: no limit) is the most one sample may need to render
    (`memory_estimate`), checked once each scene is validated, before any is rendered (a
    value out of its range is refused by the schema, naming its field, before the estimate
    reads it).

    Raises
    ------
    InputError
        A `BadSweepError`, `BadFileError` or `TooBigError`, with a message that names the
        place and the reason.
    """
    text = read_text(path, place=str(path))
    return parse_sweep(text, folder=Path(path).parent, max_memory=max_memory)


def read_header(
    text: str,
    *,
    folder=None,
    max_memory: float | None = DEFAULT_MAX_MEMORY,
    memory_remedy: str = MEMORY_REMEDY,
) -> Sweep:
    """The sweep's file checked without expanding its points: the quick part of `parse_sweep`.

    The YAML, the measurement files, the schema, the default scene (its memory estimate
    too) and the swept fields' paths; parameters as `parse_sweep`'s. What it leaves to
    `parse_sweep` grows with the sweep: the points' expansion and each point's scene.

    Raises
    ------
    InputError
        As `parse_sweep`.
    """
    data = read_yaml(text)
    if not isinstance(data, dict):
        raise BadSweepError("the file must be a YAML mapping with name, seed, output and scene")
    inline_measurements(data, folder if folder is not None else Path())
    try:
        sweep = Sweep.model_validate(data)
    except ValidationError as error:
        raise BadSweepError(format_errors(error)) from None
    strict_numbers(data, sweep.model_dump(), "")
    try:
        default = Scene.model_validate(sweep.scene)
    except ValidationError as error:
        raise BadSweepError(format_errors(error, "scene")) from None
    check_scene(sweep.scene, default)
    _check_memory(sweep.scene, max_memory=max_memory, remedy=memory_remedy)
    for path in sweep.sweep.parameters:
        scene_field(path)
    return sweep


def parse_sweep(
    text: str,
    *,
    folder=None,
    max_memory: float | None = DEFAULT_MAX_MEMORY,
    memory_remedy: str = MEMORY_REMEDY,
    resumed: Callable[[Sweep, str], np.dtype | None] | None = None,
) -> Plan:
    """Validate and expand sweep YAML text (see `load_sweep`).

    Parameters
    ----------
    text : str
        The sweep file's text.
    folder : path-like or None, optional
        Folder that relative paths in the sweep are relative to (`load_sweep` passes the
        sweep file's); None: the current directory. A URL (an object-storage data root)
        reads no measurement file.
    max_memory : float or None, optional
        The most memory [bytes] one sample may need (see `load_sweep`).
    memory_remedy : str, optional
        What the message of a sample over `max_memory` advises (the front end's remedy;
        default the command line's flags).
    resumed : callable, optional
        Called with the parsed sweep and its digest: the image type of the store a resume
        completes if that store holds this sweep written by this version, else None
        (`service.admission.resumable`). Given one, the points' scenes are built only as
        samples are addressed (`Plan.stored_image`); their raw values' memory estimates
        are still checked. Otherwise every point's scene is built and checked here.

    Notes
    -----
    A ``scene.surface.conditioning.file`` is read here
    (`service.measurements.read_measurements`) and replaced by the ``points`` it holds, so
    the workers see inline points only and the sweep's digest covers the measured values,
    not just the file name.
    """
    sweep = read_header(text, folder=folder, max_memory=max_memory, memory_remedy=memory_remedy)
    points = _expand(sweep)
    if not points:
        raise BadSweepError("sweep: the sweep expands to no parameter point")
    canonical = sweep.model_dump(mode="json", exclude={"output"})
    # parameters in file order: grid expansion and random draws follow it
    canonical["sweep"]["parameters"] = list(canonical["sweep"]["parameters"].items())
    digest = hashlib.sha256(json.dumps(canonical, sort_keys=True).encode()).hexdigest()
    check = functools.partial(_check_memory, max_memory=max_memory, remedy=memory_remedy)
    scenes = Scenes(sweep, points, check=check)
    stored = None if resumed is None else resumed(sweep, digest)
    if stored is None:
        scenes.build_all()
    else:
        scenes.survey()
    plan = Plan(sweep, text, digest, tuple(points), scenes, stored_image=stored)
    if stored is None:
        plan.__dict__["image_dtypes"] = scenes.images  # `Plan.image_dtypes`' cache
    return plan


def _expand(sweep: Sweep) -> list[dict[str, Any]]:
    spec = sweep.sweep
    params = spec.parameters
    if not params:
        return [{}]
    if spec.method in ("latin_hypercube", "sobol"):
        return _design(sweep)
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
    for path, values in lists.items():
        seen: set[str] = set()
        for value in values:  # 3 and 3.0 are one value
            key = json.dumps(json.loads(json.dumps(value, default=str), parse_int=float))
            if key in seen:
                raise BadSweepError(
                    f"sweep.parameters.{path}.values: {shown(value)} is listed twice, so the "
                    "grid would repeat its points (raise realisations for more samples of one)"
                )
            seen.add(key)
    size = math.prod(len(v) for v in lists.values())
    if size > MAX_POINTS:
        raise TooBigError(
            f"sweep: the grid has {size:,} parameter points, over the limit of {MAX_POINTS:,}"
        )
    combos = itertools.product(*lists.values())
    return [dict(zip(lists, combo, strict=True)) for combo in combos]


def _design(sweep: Sweep) -> list[dict[str, Any]]:
    """Points of a Latin hypercube or a scrambled Sobol sequence, in file order.

    One dimension per parameter that varies (a fixed ``value`` takes none): a distribution
    maps the design's coordinate u in [0, 1) through its inverse CDF
    (`service.schema.Distribution.quantile`), a list of values picks ``values[⌊u n⌋]``.
    The design's generator is seeded by the sweep's seed (its own stream, apart from
    ``random``'s), so the points depend on the file alone.
    """
    spec = sweep.sweep
    varying = [path for path, p in spec.parameters.items() if not isinstance(p, Value)]
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(sweep.seed, spawn_key=(3,))))
    if not varying:
        unit = np.empty((spec.count, 0))
    elif spec.method == "latin_hypercube":
        unit = qmc.LatinHypercube(d=len(varying), rng=rng).random(spec.count)
    else:
        unit = qmc.Sobol(d=len(varying), rng=rng).random_base2(int(spec.count).bit_length() - 1)
    columns = {}
    for path, p in spec.parameters.items():
        if isinstance(p, Value):
            columns[path] = [p.value] * spec.count
            continue
        u = unit[:, varying.index(path)]
        if isinstance(p, Distribution):
            columns[path] = p.quantile(u)
        else:
            picks = np.minimum((u * len(p.values)).astype(int), len(p.values) - 1)
            columns[path] = [p.values[i] for i in picks]
    return [{path: columns[path][i] for path in spec.parameters} for i in range(spec.count)]
