"""`pdmpm schema`: the scene JSON Schema, for editors (YAML language servers) and documentation."""

import json
from pathlib import Path
from typing import Annotated

import typer


def schema(
    output: Annotated[Path | None, typer.Option("--output", "-o", help="Write to this file instead of stdout.")] = None,
):
    """Print the JSON Schema of scene files (every field with its unit)."""
    from pdmpm_cli.scene.schema import Scene

    text = json.dumps(Scene.model_json_schema(), indent=2)
    if output is None:
        typer.echo(text)
    else:
        from pdmpm_cli.errors import OutputError
        from pdmpm_cli.io.atomic import atomic_write_text

        try:
            atomic_write_text(output, text + "\n")
        except OSError as error:
            raise OutputError(f"{output}: cannot write the schema ({error.strerror})") from None
