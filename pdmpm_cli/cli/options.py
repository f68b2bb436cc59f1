"""Options shared by several commands."""

from pathlib import Path
from typing import Annotated

import typer

SceneArg = Annotated[Path, typer.Argument(help="Scene YAML file.", show_default=False)]
SetOpt = Annotated[
    list[str],
    typer.Option("--set", "-s", help="Override a scene value before validation, e.g. --set bodies.0.material.mu=2e5."),
]
VariantOpt = Annotated[
    str | None,
    typer.Option("--variant", "-V", help="Apply one of the scene's named variants (its top-level 'variants:').",
                 show_default=False),
]
