"""The sweep file's schema: frozen pydantic models, and the scene fields dotted paths name.

A sweep is a scene (defaults for every sample), a set of parameters addressed by dotted
paths into the scene (``target.depth``; `scene_field`), a method that turns them into
parameter points (``grid``, ``zip``, or `SAMPLED` ones: ``random`` and the space-filling
designs of `scipy.stats.qmc`, ``latin_hypercube`` and ``sobol``), and a number of Monte
Carlo realisations per point. `sweep_json_schema` is the file's JSON Schema, for editors.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
import scipy.stats
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    StrictBool,
    Tag,
    field_validator,
    model_validator,
)

from service.errors import BadSweepError
from service.inputs import shown
from workers.settings.scene import Scene

__all__ = [
    "SAMPLED",
    "Distribution",
    "StoreSpec",
    "Sweep",
    "SweepSpec",
    "Value",
    "Values",
    "field_units",
    "scene_field",
    "sweep_json_schema",
]

SAMPLED = ("random", "latin_hypercube", "sobol")
"""Methods that draw `count` points from distributions (and from lists, uniformly)."""


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Values(_Model):
    """An explicit list of values."""

    values: Annotated[list[Any], Field(min_length=1, max_length=100_000)]


class Value(_Model):
    """One fixed value."""

    value: Any


class Distribution(_Model):
    """A distribution, for the `SAMPLED` methods (``random``, ``latin_hypercube``, ``sobol``)."""

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

    def quantile(self, u: np.ndarray) -> list:
        """The values at probabilities `u` in [0, 1) (inverse CDF), as plain Python numbers.

        A design stratified in `u` (a Latin hypercube, a Sobol net) stays stratified in
        probability. `u` is kept inside the open interval by 2⁻⁵³ so that a normal
        distribution stays finite.
        """
        u = np.clip(u, 2.0**-53, 1.0 - 2.0**-53)
        if self.distribution == "uniform":
            return (self.min + u * (self.max - self.min)).tolist()
        if self.distribution == "log_uniform":
            low, high = np.log(self.min), np.log(self.max)
            return np.exp(low + u * (high - low)).tolist()
        if self.distribution == "normal":
            return scipy.stats.norm.ppf(u, loc=self.mu, scale=self.sigma).tolist()
        low, high = math.ceil(self.min), math.floor(self.max)
        return np.minimum(low + np.floor(u * (high - low + 1)), high).astype(int).tolist()


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

    method: Literal["grid", "zip", "random", "latin_hypercube", "sobol"] = "grid"
    count: int | None = Field(None, ge=1, le=10_000_000)
    parameters: dict[str, Parameter] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _consistent(self) -> SweepSpec:
        if self.method in SAMPLED:
            if self.count is None:
                raise ValueError(f"method {self.method} needs a count")
        elif self.count is not None:
            raise ValueError(f"count applies to methods {', '.join(SAMPLED)}, not {self.method}")
        if self.method == "sobol" and self.count & (self.count - 1):
            raise ValueError(
                f"method sobol needs a count that is a power of two, not {self.count}: its "
                "balance (one point in every elementary interval) holds for 2^m points"
            )
        if self.method not in SAMPLED:
            for path, parameter in self.parameters.items():
                if isinstance(parameter, Distribution):
                    raise ValueError(
                        f"{path}: distributions need method {', '.join(SAMPLED[:-1])} or sobol"
                    )
        if self.method == "zip":
            lengths = {
                path: len(p.values) for path, p in self.parameters.items() if isinstance(p, Values)
            }
            if len(set(lengths.values())) > 1:
                raise ValueError(f"method zip needs equally long value lists, got {lengths}")
        return self


class StoreSpec(_Model):
    """What the store keeps of each sample beyond its noisy image and labels."""

    expected: StrictBool = False
    """Store the noise-free ``expected`` images too (float32: most of a sample's bytes).
    Statistics never need them (their per-sample signals are computed in the render task);
    a detection study renders them again when they are not stored."""


class Sweep(_Model):
    """A sweep file."""

    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")
    seed: int = Field(ge=0, le=2**63 - 1)
    realisations: int = Field(1, ge=1, le=1_000_000)
    output: str = Field(min_length=1, max_length=4096)
    scene: dict[str, Any] = Field(default_factory=dict)
    sweep: SweepSpec = SweepSpec()
    store: StoreSpec = StoreSpec()

    @field_validator("output")
    @classmethod
    def _printable(cls, output: str) -> str:
        if any(ord(character) < 32 or ord(character) == 127 for character in output):
            raise ValueError(f"control characters are not allowed, got {shown(output)}")
        return output


def scene_field(path: str):
    """The pydantic field a dotted path names in the scene (a leaf value).

    Raises
    ------
    BadSweepError
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
            raise BadSweepError(f"sweep.parameters.{path}: unknown path; {where} has {known}")
        field = fields[part]
        annotation = field.annotation
        is_model = isinstance(annotation, type) and issubclass(annotation, BaseModel)
        model = annotation if is_model else None
    if model is not None:
        raise BadSweepError(f"sweep.parameters.{path}: names a section, not a value")
    return field


def field_units(path: str) -> str:
    """The unit a scene field declares (`workers.settings.section.units`; "1": dimensionless)."""
    return scene_field(path).json_schema_extra["units"]


def sweep_json_schema() -> dict:
    """The JSON Schema (2020-12) of sweep files, the scene's sections and units included.

    `Sweep` takes the scene as a mapping (the service validates it as
    `workers.settings.scene.Scene`
    once measurement files are read); here the scene's own schema stands in its place, with
    the ``file`` a conditioning may give instead of ``points`` (`service.measurements`).
    Every scene field carries ``units`` (`workers.settings.section.units`).
    """
    schema = Sweep.model_json_schema()
    scene = Scene.model_json_schema()
    definitions = schema.setdefault("$defs", {})
    definitions.update(scene.pop("$defs", {}))
    definitions["Scene"] = scene
    definitions["Conditioning"]["properties"]["file"] = {
        "type": "string",
        "description": "CSV file of measured points (header x,y,elevation[,time]), relative "
        "to the sweep file; instead of points.",
    }
    described = schema["properties"]["scene"].get("description", "")
    schema["properties"]["scene"] = {"$ref": "#/$defs/Scene", "description": described}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}
