"""`pdmpm scenes`: the bundled example scenes (the paper's Table 1 and the quick start), one line each."""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table


def scene_folder(folder: Path | None) -> Path:
    """The folder given, else ./scenes, else the scenes/ folder of the source checkout pdmpm runs from."""
    from pdmpm_cli.errors import InputError

    if folder is not None:
        if not folder.is_dir():
            raise InputError(f"{folder}: not a folder; give the folder holding the scene YAML files")
        return folder
    for candidate in (Path("scenes"), Path(__file__).resolve().parents[2] / "scenes"):
        if candidate.is_dir():
            return candidate
    raise InputError("no scenes/ folder here or beside the pdmpm sources; run from a pdmpm checkout or give the folder")


def scenes(
    folder: Annotated[Path | None, typer.Argument(help="Folder of scene files (default ./scenes).",
                                                  show_default=False)] = None,
):
    """List the scenes in a folder: file, what it shows, bodies (geometry mode, material) and variants."""
    from pdmpm_cli.scene.loader import load_scene
    from pdmpm_cli.scene.schema import Scene

    console = Console(highlight=False, emoji=False, soft_wrap=True)
    table = Table(box=None, pad_edge=False)
    for column in ("scene", "shows", "bodies", "variants"):
        table.add_column(column)
    for path in sorted(scene_folder(folder).glob("*.yaml")):
        scene, _ = load_scene(path, Scene)
        bodies = ", ".join(f"{b.name} ({b.geometry.mode} {b.material.model}{' fracture' if b.fracture else ''})"
                           for b in scene.bodies)
        table.add_row(escape(path.name), escape(scene.description), escape(bodies), escape(", ".join(scene.variants)))
    console.print(table)
