"""What every command shares: one-line errors instead of tracebacks, progress bars, peak memory, help
texts."""

from __future__ import annotations

import os
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


# The optional dependency groups (pyproject.toml) and the modules each brings: `pip install affordmap` maps a
# room; a command that needs more names the group to install.
EXTRAS = {
    "services": ("zenoh", "google.protobuf", "kiss_icp", "cryptography"),
    "ros": ("rosbags",),
    "learn": ("sklearn", "osqp", "open3d"),
    "cluster": ("ray",),
}


class UserError(Exception):
    """Bad input: reported as one line on stderr with exit code 2, never a traceback."""


def _command() -> str:
    """The command being run, e.g. `afford serve` (for messages)."""
    try:
        from typer.main import get_current_context

        context = get_current_context()
        below_root = context.command_path[len(context.find_root().command_path) :].strip()
        return f"afford {below_root}".strip()
    except Exception:  # no click context (called outside a command): say it plainly
        return "this command"


def _extra_of(module: str) -> str | None:
    """The optional dependency group that installs `module` (a dotted name, or its first part)."""
    for extra, modules in EXTRAS.items():
        for name in modules:
            if module == name or module.startswith(name + ".") or name.startswith(module + "."):
                return extra
    return None


def missing_extra_message(extra: str) -> str:
    return f"{_command()} needs the {extra} extra: pip install 'affordmap[{extra}]'"


def require_extra(extra: str) -> None:
    """Fail (one line, exit 2) before any work when a module of the optional dependency group `extra` is not
    installed."""
    from importlib.util import find_spec

    for module in EXTRAS[extra]:
        try:
            found = find_spec(module) is not None
        except (ImportError, ValueError):  # a missing parent package (google for google.protobuf)
            found = False
        if not found:
            raise UserError(missing_extra_message(extra))


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
    except ModuleNotFoundError as error:  # an optional dependency group that is not installed
        extra = _extra_of(error.name or "")
        if extra is None:
            raise
        fail(missing_extra_message(extra))


def fail(message: str, code: int = 2) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def progress(quiet: bool, speed_window: float = 30.0):
    """A rich progress bar on stderr (none with --quiet) with the time left, from the pace over the last
    `speed_window` seconds; it disappears when done."""
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
        speed_estimate_period=speed_window,
    )


def work_progress(quiet: bool, seconds_per_unit: float, start_weight: float = 0.1):
    """A rich progress bar like `progress`'s over weighted work (the task's total and advances are units of
    work, shown as a percentage; advance it with `advance_work`) whose time left shows from the start: the
    work left at a pace that starts at `seconds_per_unit` (the caller's guess) and moves to the mean pace
    measured as work is done (the guess counts as if `start_weight` of the total had been done at it). The
    pace is measured from the last step of no work (preparing), so that a long preparation the total does not
    count does not make the work look slow."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, ProgressColumn, TaskProgressColumn, TextColumn
    from rich.text import Text

    class TimeLeft(ProgressColumn):
        max_refresh = 0.5  # as rich's own: no jitter

        def render(self, task) -> Text:
            if task.total is None or task.finished:
                return Text("", style="progress.remaining")
            prior = start_weight * task.total
            since = task.fields.get("since", task.start_time)
            elapsed = 0.0 if since is None else max(0.0, task.get_time() - since)
            pace = (elapsed + seconds_per_unit * prior) / (task.completed + prior)
            minutes, seconds = divmod(int(pace * (task.total - task.completed)), 60)
            hours, minutes = divmod(minutes, 60)
            return Text(f"{hours:d}:{minutes:02d}:{seconds:02d} left", style="progress.remaining")

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TimeLeft(),
        console=Console(stderr=True),
        transient=True,
        disable=quiet,
    )


def advance_work(bar, task, message: str, work: float) -> None:
    """A step of a `work_progress` bar: `work` units done (none: a preparing step, which restarts the clock
    the pace is measured from)."""
    bar.update(task, description=message, advance=work, **({} if work else {"since": bar.get_time()}))


def output_folder(path: Path, option: str = "--out") -> Path:
    """`path` as a folder outputs can be written to, made if missing; checked before any work starts, so a
    bad --out costs a message, not the minutes of work before it."""
    if path.exists() and not path.is_dir():
        raise UserError(f"{option} {path} is a file; give a folder (it is made if missing)")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UserError(f"{option} {path} cannot be made: {error.strerror}") from None
    probe = path / ".afford-write-check"
    try:
        probe.touch()
        probe.unlink()
    except OSError as error:
        raise UserError(f"{option} {path} is not writable: {error.strerror}") from None
    return path


def output_file(path: Path, option: str = "--out") -> Path:
    """`path` as a file an output can be written to (its folder made if missing), checked before any work
    starts, as `output_folder` checks a folder."""
    if path.is_dir():
        raise UserError(f"{option} {path} is a folder; give a file name")
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise UserError(f"{option} {path}: {parent} is a file, not a folder")
    output_folder(parent, option=f"{option} {path}: the folder")
    if path.exists() and not os.access(path, os.W_OK):
        raise UserError(f"{option} {path} is not writable")
    return path


def peak_rss_mb() -> float:
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024 if sys.platform != "darwin" else peak / 2**20


def names(text: str) -> list[str]:
    """The items of a comma-separated option."""
    return [part.strip() for part in text.split(",") if part.strip()]
