"""The frozen base of every section of a scene (`workers.scene.Scene` and what it nests)."""

from pydantic import BaseModel, ConfigDict

__all__ = ["Section"]


class Section(BaseModel):
    """A frozen, validated settings model: unknown fields refused, defaults validated too."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)
