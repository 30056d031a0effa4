"""The `afford` app: the themes' commands in one typer app, grouped by theme in `--help`."""

from __future__ import annotations

import typer

from . import config, learning, robot, room, skeletons, stack

app = typer.Typer(
    help="affordmap: where people can sit, relax, work and stand in a 3D room, from its point cloud.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
for theme in (room, learning, skeletons, robot, stack, config):
    app.add_typer(theme.app)


def _version(value: bool) -> None:
    if value:
        from affordcore import version

        typer.echo(f"affordmap {version()}")
        raise typer.Exit()


@app.callback()
def main(
    show_version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="print the version and exit"
    ),
) -> None:
    """affordmap: where people can sit, relax, work and stand in a 3D room, from its point cloud."""
