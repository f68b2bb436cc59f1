"""The base of every validated input model: the scene's sections (scene.schema) and the materials' own parameter
sections (engine.materials), which the scene schema collects from the material registry."""

from pydantic import BaseModel, ConfigDict

Vec3 = tuple[float, float, float]


class Strict(BaseModel):
    """Immutable, unknown keys rejected, every float finite (.inf and .nan are refused where they are written, not
    met as a blow-up or an overflow later)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
