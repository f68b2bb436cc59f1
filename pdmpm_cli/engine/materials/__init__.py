"""Material registry: the scene's `model:` name -> its MaterialKind (materials/base.py).

Adding a material means one module (its schema, parameters, arrays, kernels and hooks, ending in `KIND`) and one
entry in BUILTIN. Modules named in the environment variable PDMPM_MATERIALS (comma-separated import paths, each
with a `KIND`) are registered too: a material can live outside this package (the tests' linear spring does).
"""

import importlib
import os

from pdmpm_cli.engine.materials import elastic, plastic, viscoelastic
from pdmpm_cli.engine.materials.base import MaterialKind

BUILTIN = (elastic.KIND, plastic.KIND, viscoelastic.KIND)


def _registry() -> dict[str, MaterialKind]:
    kinds = list(BUILTIN)
    for name in filter(None, (s.strip() for s in os.environ.get("PDMPM_MATERIALS", "").split(","))):
        kinds.append(importlib.import_module(name).KIND)
    return {k.name: k for k in kinds}


MATERIALS: dict[str, MaterialKind] = _registry()


def kind_of(section) -> str:
    """The registry entry a body runs (a plastic body that can never yield runs as elastic)."""
    kind = MATERIALS[section.model]
    return kind.runs_as(section) if kind.runs_as else kind.name



def declared_fields() -> dict:
    """Every array the engine or a registered material declares, by name (engine.fields.Field)."""
    from pdmpm_cli.engine import fields

    out = {f.name: f for f in fields.CORE + fields.GRIDS + fields.FBAR + fields.GRID_DENSITY + fields.PAIR
                                  + fields.FRACTURE + fields.FRACTURE_CELLS + fields.CONTACT + fields.CRACK_SIDES}
    for kind in MATERIALS.values():
        for f in kind.fields:
            if out.setdefault(f.name, f) != f:
                raise ValueError(f"material {kind.name} declares {f.name} differently from another declaration")
    return out
