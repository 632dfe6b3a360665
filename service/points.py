"""The scenes of a sweep's points, each validated and checked when first asked for.

`Scenes` is `service.sweep.Plan.scenes`: point ``i``'s scene is the sweep's default scene
with the point's values set, validated (`workers.settings.scene.Scene`) and checked beyond its
schema (`check_scene`). `service.sweep.parse_sweep` builds them all, in point order, before
a new run: bad input is refused before anything is written. A resume of a store of the
same sweep, written by the same version (its points were validated when it was made),
builds only the scenes of the samples it addresses (`service.sweep.Plan.sample`), so that
its cost follows what is missing rather than the sweep's points.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from pydantic import ValidationError

from service.errors import BadSweepError, InputError
from service.inputs import shown, strict_numbers
from service.schema import Sweep, scene_field
from workers.dataset.variables import count_dtype
from workers.settings.scene import Scene

__all__ = ["MAX_TRAVEL", "Scenes", "assign", "check_scene", "format_errors", "raw_value"]

MAX_TRAVEL = 100_000.0
"""Farthest the platform may fly during a sequence [m]: beyond 100 km, float32 ray
coordinates resolve less than a centimetre, coarser than the surface grids need."""


class Scenes(Sequence):
    """Every point's scene, built and checked on first use, then kept.

    Parameters
    ----------
    sweep : Sweep
        The parsed sweep (its default scene).
    points : sequence of dict
        Each point's swept values, by dotted path.
    check : callable
        Called with a point's raw scene (a dict) once it is validated (`build_all`, on
        first use) or, by `survey`, unvalidated: the memory limit
        (`service.sweep.memory_estimate`).

    Attributes
    ----------
    images : dict
        The image type of each distinct scene built so far (`check_scene`), in the order
        they were built.
    kinds : dict
        ``(transport.method, save_surface)`` -> the first point of that kind, filled by
        `build_all` or `survey`.

    Notes
    -----
    Points whose scenes have the same values share one `Scene`. A point's errors are
    raised as `parse_sweep` raises them, naming the point and its values.
    """

    def __init__(self, sweep: Sweep, points: Sequence[dict[str, Any]], *, check: Callable):
        self._sweep, self._points, self._check = sweep, points, check
        self._built: dict[int, Scene] = {}
        self._by_values: dict[str, Scene] = {}
        self.images: dict[Scene, np.dtype] = {}
        self.kinds: dict[tuple[str, bool], int] = {}

    def __len__(self) -> int:
        return len(self._points)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return tuple(self[i] for i in range(len(self))[index])
        point = range(len(self))[index]  # IndexError beyond the points
        scene = self._built.get(point)
        if scene is None:
            scene = self._built[point] = self._build(point)
        return scene

    def raw(self, point: int) -> dict:
        """Point `point`'s scene as a dict: the default scene with its values set."""
        data = copy.deepcopy(self._sweep.scene)
        for path, value in self._points[point].items():
            assign(data, path, value)
        return data

    def build_all(self) -> None:
        """Build and check every point's scene, in point order (a new run's admission)."""
        for point, scene in enumerate(self):
            self.kinds.setdefault((scene.transport.method, scene.save_surface), point)

    def survey(self) -> None:
        """Check every point's raw scene (`check`) and find its kind, building none.

        What a resume of a store of the same sweep and version does instead of
        `build_all`: the raw values' checks depend on the limits given now.
        """
        for point in range(len(self)):
            data = self.raw(point)
            self._run_check(point, data)
            method = raw_value(data, "transport.method")
            self.kinds.setdefault((method, bool(raw_value(data, "save_surface"))), point)

    def _run_check(self, point: int, data: dict) -> None:
        try:
            self._check(data)
        except InputError as error:
            raise type(error)(f"{self._where(point)}:\n{error}") from None

    def _where(self, point: int) -> str:
        values = ", ".join(f"{p}={shown(v)}" for p, v in self._points[point].items())
        return f"parameter point {point} ({values})"

    def _build(self, point: int) -> Scene:
        data = self.raw(point)
        key = json.dumps(data, sort_keys=True, default=str)
        if key in self._by_values:
            return self._by_values[key]
        try:
            scene = Scene.model_validate(data)
            image = check_scene(data, scene)
        except ValidationError as error:
            raise BadSweepError(
                f"{self._where(point)}:\n" + format_errors(error, "scene")
            ) from None
        except InputError as error:
            raise type(error)(f"{self._where(point)}:\n{error}") from None
        self._run_check(point, data)  # on values the schema took
        self.images.setdefault(scene, image)
        self._by_values[key] = scene
        return scene


def raw_value(data: dict, path: str) -> Any:
    """The value at dotted `path` of a raw scene dict, or the schema's default."""
    node: Any = data
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            return scene_field(path).default
        node = node[part]
    return node


def check_scene(raw: dict, scene: Scene) -> np.dtype:
    """Checks of a validated scene beyond its schema; its image type.

    Strict numbers, a bounded track, counts that fit the store's unsigned integers
    (`workers.dataset.variables.count_dtype`; float32 images when not counts: what
    `service.sweep.Plan.image_dtypes` holds).
    """
    strict_numbers(raw, scene.model_dump(), "scene")
    try:
        image = count_dtype(scene) or np.dtype(np.float32)
    except ValueError as error:
        raise BadSweepError(f"scene.{error}") from None
    sequence = scene.sequence
    travel = max(map(abs, sequence.velocity)) * ((sequence.frames - 1) * sequence.interval)
    if travel > MAX_TRAVEL:
        raise BadSweepError(
            f"scene.sequence.velocity: the platform would fly {travel:.3g} m during the "
            f"sequence, over the limit of {MAX_TRAVEL:,.0f} m"
        )
    return image


def format_errors(error: ValidationError, prefix: str = "") -> str:
    """A pydantic error as one line per problem, each naming its field's dotted path."""
    lines = []
    for item in error.errors():
        location = ".".join(str(part) for part in item["loc"] if not _is_union_tag(part))
        place = ".".join(filter(None, [prefix, location])) or "(top level)"
        lines.append(f"{place}: {item['msg']}")
    return "\n".join(dict.fromkeys(lines))


def _is_union_tag(part) -> bool:
    return part in {"list", "fixed", "random"} or str(part).startswith("function-after")


def assign(data: dict, path: str, value: Any) -> None:
    """Set dotted `path` of the raw dict `data` to `value`, making the sections on the way."""
    *parents, leaf = path.split(".")
    node = data
    for part in parents:
        child = node.get(part)
        if not isinstance(child, dict):
            child = {}
            node[part] = child
        node = child
    node[leaf] = value
