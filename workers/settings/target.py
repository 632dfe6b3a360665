"""The scene's target section: its shape (a registered `workers.targets` plug-in) and place.

Validated settings only, building nothing: each shape's own checks are its plug-in's
(`workers.targets.base.TargetShape.check`); the renderers build the shape's maps and records
from this section (`workers.setup.builder.scene_setup`). Every field declares its unit as data
(`workers.settings.section.units`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_serializer, model_validator

from workers.settings.section import Section, units
from workers.targets.base import SHAPES

__all__ = ["Target"]


class Target(Section):
    """The object under the sea: a moored-mine sphere, a flat panel, a cylinder, or nothing."""

    shape: str = Field(
        "sphere",
        description="A registered shape (`workers.targets`): `sphere`, `disk` (flat "
        "horizontal panel), `cylinder` (horizontal, closed: `radius`, `length`, "
        "`heading_deg`) or `none`.",
        json_schema_extra={**units("1"), "enum": sorted(SHAPES)},
    )
    radius: float = Field(
        0.3,
        gt=0.0,
        le=100.0,
        description="Sphere, disk or cylinder radius.",
        json_schema_extra=units("m"),
    )
    depth: float = Field(
        5.0,
        gt=0.0,
        le=200.0,
        description="Depth of the sphere's centre, of the disk, or of the cylinder's axis.",
        json_schema_extra=units("m"),
    )
    length: float = Field(
        2.0,
        strict=True,  # a number, never a string: its dump may leave it out (`_dump`)
        gt=0.0,
        le=200.0,
        description="Cylinder length, end cap to end cap (other shapes ignore it).",
        json_schema_extra=units("m"),
    )
    heading_deg: float = Field(
        0.0,
        strict=True,  # a number, never a string: its dump may leave it out (`_dump`)
        ge=-360.0,
        le=360.0,
        description="Compass heading of the cylinder's axis, clockwise from north (+y): 0 "
        "lies north-south, 90 east-west (other shapes ignore it).",
        json_schema_extra=units("degree"),
    )
    x: float | None = Field(
        None,
        ge=-1.0e4,
        le=1.0e4,
        description="East position; null puts the target on the central ray "
        "(refracted by a flat sea).",
        json_schema_extra=units("m"),
    )
    y: float | None = Field(
        None,
        ge=-1.0e4,
        le=1.0e4,
        description="North position; null as for `x`.",
        json_schema_extra=units("m"),
    )
    reflectance: float = Field(
        0.2,
        ge=0.0,
        le=1.0,
        description="Lambertian reflectance ρ (the paper's 20 % is 0.2).",
        json_schema_extra=units("1"),
    )
    shading: Literal["lambert", "paper"] = Field(
        "lambert",
        description="Shading: `lambert` (cosine of the surface normal and ray; physical), "
        "or `paper`, the paper's area weights (`ponder`), kept only to reproduce its "
        "figures: it does not conserve energy (a white sphere returns 2x a white disk of "
        "its radius where a Lambertian one returns 2/3, and its limb pixels exceed the "
        "brightest physical value several times over, more at finer pixels); do not use "
        "it for training data; a sphere's only (a disk or a cylinder with it is refused).",
        json_schema_extra=units("1"),
    )
    visibility_threshold: float = Field(
        0.05,
        gt=0.0,
        le=10.0,
        description="Relative change of a gate's noise-free image over the target mask (the "
        "sample against its target-free twin, `target_effect_relative`) from which the "
        "target counts as seen in that gate: `in_gate` if it brightens the mask by at least "
        "this, `shadow` if it darkens it by at least this, else `unseen` (docs/model.md §8). "
        "A label's rule only: training may re-threshold `target_effect_relative`.",
        json_schema_extra=units("1"),
    )

    @field_validator("shape")
    @classmethod
    def _registered(cls, shape: str) -> str:
        if shape not in SHAPES:
            raise ValueError(
                f"not a registered target shape; choose from {', '.join(sorted(SHAPES))}"
            )
        return shape

    @model_serializer(mode="wrap")
    def _dump(self, handler):
        """The fields, less other shapes' own (`TargetShape.fields`) left at their defaults.

        So a scene without a cylinder dumps as before the cylinder's fields existed, and
        its sweep's digest (`service.sweep`) is unchanged.
        """
        data = handler(self)
        if isinstance(data, dict):
            own = set(SHAPES[self.shape].fields)
            for shape in SHAPES.values():
                for name in set(shape.fields) - own:
                    if getattr(self, name) == type(self).model_fields[name].default:
                        data.pop(name, None)
        return data

    @model_validator(mode="after")
    def _submerged(self) -> Target:
        if (self.x is None) != (self.y is None):
            raise ValueError(
                "set both x and y, or neither (the target then sits on the central ray)"
            )
        shape = SHAPES[self.shape]
        if self.shading not in shape.shadings:
            raise ValueError(
                f"shading: {self.shading} is not defined for a {self.shape} (the paper's "
                f"area weights are a sphere's); choose from {', '.join(shape.shadings)}"
            )
        shape.check(self)
        return self
