"""What every command shares: one-line errors instead of tracebacks, progress bars, peak memory, help
texts."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import typer

GRAVITY_HELP = (
    "auto (find the floor), none (already z-up, floor at 0), or X,Y,Z: gravity's direction in the "
    "cloud's frame"
)
CONNECT_HELP = "zenoh endpoint of the router, e.g. tcp/192.168.1.10:7447 (repeatable)"
ROBOT_HELP = "the robot's name: its keys are afford/@v1/<robot>/..."
ZENOH_CONFIG_HELP = (
    "a zenoh JSON5 config file to start from: TLS certificates, access control (docs/security.md); "
    "default: AFFORD_SERVICE__ZENOH_CONFIG"
)


class UserError(Exception):
    """Bad input: reported as one line on stderr with exit code 2, never a traceback."""


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn the errors bad input raises (invalid settings, files, values) into one line and exit code 2."""
    from pydantic import ValidationError

    try:
        yield
    except ValidationError as error:
        fail(
            f"invalid settings: {error.errors()[0].get('msg', error)} (check the AFFORD_* environment "
            "variables)"
        )
    except (UserError, ValueError, OSError, MemoryError) as error:
        fail(str(error))


def fail(message: str, code: int = 2) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def progress(quiet: bool):
    """A rich progress bar on stderr (none with --quiet); it disappears when done."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=True,
        disable=quiet,
    )


def output_folder(path: Path, option: str = "--out") -> Path:
    """`path` as a folder outputs can be written to, made if missing; checked before any work starts, so a
    bad --out costs a message, not the minutes of work before it."""
    if path.exists() and not path.is_dir():
        raise UserError(f"{option} {path} is a file; give a folder (it is made if missing)")
    path.mkdir(parents=True, exist_ok=True)
    probe = path / ".afford-write-check"
    try:
        probe.touch()
        probe.unlink()
    except OSError as error:
        raise UserError(f"{option} {path} is not writable: {error.strerror}") from None
    return path


def peak_rss_mb() -> float:
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024 if sys.platform != "darwin" else peak / 2**20


def names(text: str) -> list[str]:
    """The items of a comma-separated option."""
    return [part.strip() for part in text.split(",") if part.strip()]
