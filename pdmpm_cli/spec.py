"""The base of every validated input model: the scene's sections (scene.schema) and the materials' own parameter
sections (engine.materials), which the scene schema collects from the material registry."""

from pydantic import BaseModel, ConfigDict

Vec3 = tuple[float, float, float]


class Strict(BaseModel):
    """Immutable, unknown keys rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)
