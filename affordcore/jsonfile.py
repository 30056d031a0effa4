"""Reading the project's JSON files (labels, skeletons, models) with errors that name the file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def read_json(path: Path, error: type[Exception]) -> Any:
    """The parsed document, or `error` saying which file could not be read or parsed, and why."""
    try:
        return json.loads(path.read_text())
    except OSError as problem:
        raise error(f"{path}: cannot read ({problem.strerror or problem})") from problem
    except (json.JSONDecodeError, UnicodeDecodeError) as problem:
        raise error(f"{path}: not valid JSON ({problem})") from problem
