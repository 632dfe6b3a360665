"""The frozen base of every section of a scene (`workers.settings.scene.Scene` and what it nests).

Every field of a section declares its unit as data, ``json_schema_extra=units("m")``: the
store's swept coordinates carry it (`service.schema.field_units`) and the sweep file's JSON
Schema shows it (``oceanlidar schema``). Dimensionless fields, counts, flags and choices
declare ``"1"``.
"""

from pydantic import BaseModel, ConfigDict

__all__ = ["SceneError", "Section", "units"]


class SceneError(ValueError):
    """A scene valid field by field that cannot be rendered (a singular kriging system).

    An error in the input, found when the scene's work is built: the same on every retry,
    so the service reports it with the sample's parameters and never retries it.
    """


class Section(BaseModel):
    """A frozen, validated settings model: unknown fields refused, defaults validated too."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)


def units(symbol: str) -> dict[str, str]:
    """A field's ``json_schema_extra`` declaring its unit `symbol` (UDUNITS; "1": none)."""
    return {"units": symbol}
