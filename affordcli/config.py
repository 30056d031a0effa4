"""`afford config`: every setting, its default and the variable that overrides it."""

from __future__ import annotations

import typer

from .common import user_errors

app = typer.Typer()


@app.command(rich_help_panel="Settings")
def config(
    current: bool = typer.Option(
        False, "--current", help="print the effective settings (defaults + AFFORD_* overrides) as JSON"
    ),
) -> None:
    """Print every setting's default and the environment variable that overrides it."""
    with user_errors():
        from affordcore.settings import describe_defaults
        from services.settings import ServiceSettings

        if current:
            typer.echo(ServiceSettings().model_dump_json(indent=2))
            return
        for variable, default, description in describe_defaults(ServiceSettings):
            typer.echo(f"{variable}={default}    # {description}" if description else f"{variable}={default}")
