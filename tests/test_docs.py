"""The manual stays true to the code: every `afford` command in the README's and docs' code blocks is one the
command line has, and every AFFORD_* variable they name is a setting."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# a setting's variable: AFFORD_<SECTION>__<FIELD> (a bare AFFORD_ROS__ names the family)
VARIABLE = re.compile(r"\bAFFORD_([A-Z]+(?:_[A-Z]+)*)__([A-Z][A-Z0-9_]*[A-Z0-9])\b")


def code_lines(page: Path) -> list[str]:
    """The lines of the page's fenced code blocks."""
    lines, inside = [], False
    for line in page.read_text().splitlines():
        if line.lstrip().startswith("```"):
            inside = not inside
        elif inside:
            lines.append(line)
    return lines


def commands() -> set[tuple[str, ...]]:
    """(command[, subcommand]) of every `afford ...` a code block runs."""
    from typer.main import get_command

    from affordcli.app import app

    groups = {name for name, command in get_command(app).commands.items() if hasattr(command, "commands")}
    found = set()
    for page in PAGES:
        for line in code_lines(page):
            for match in re.finditer(
                r"(?:^|[\s;&|(])(?:\.venv/bin/)?afford\s+([a-z][a-z-]*)(?:\s+([a-z][a-z-]*))?", line
            ):
                first, second = match.groups()
                found.add((first, second) if first in groups and second else (first,))
    return found


def test_every_command_the_docs_run_is_one_the_command_line_has():
    from typer.testing import CliRunner

    from affordcli.app import app

    runner, wanted = CliRunner(), sorted(commands())
    assert ("map",) in wanted and ("ros-bridge",) in wanted  # the scan finds the docs' commands
    failed = {}
    for command in wanted:
        result = runner.invoke(app, [*command, "--help"])
        if result.exit_code != 0:
            failed[" ".join(command)] = result.output[-300:]
    assert not failed, failed


def settings_named() -> dict[str, set[str]]:
    """{variable: pages naming it} of every AFFORD_<SECTION>__<FIELD> in the README and docs."""
    named: dict[str, set[str]] = {}
    for page in PAGES:
        for match in VARIABLE.finditer(page.read_text()):
            named.setdefault(match.group(0), set()).add(page.name)
    return named


@pytest.mark.parametrize("variable", sorted(settings_named()))
def test_every_setting_the_docs_name_exists(variable):
    from services.settings import ServiceSettings

    section, field = (part.lower() for part in VARIABLE.fullmatch(variable).groups())
    sections = ServiceSettings.model_fields
    assert section in sections, f"{variable} ({settings_named()[variable]}): no settings section {section!r}"
    fields = sections[section].annotation.model_fields
    assert field in fields, f"{variable} ({settings_named()[variable]}): {section} has no {field!r}"


def test_the_changelog_s_newest_release_is_the_package_s_version():
    """A version moves with each capability: the one pyproject.toml gives is CHANGELOG.md's newest release."""
    import re
    import tomllib

    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    releases = re.findall(
        r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", (ROOT / "CHANGELOG.md").read_text(), re.M
    )
    assert releases and releases[0] == version, (releases[:3], version)


def test_the_reference_pages_are_what_the_code_generates():
    """docs/reference/ is written from the settings classes and the typer app: a setting or an option changed
    without rerunning docs/reference/generate.py fails here."""
    import runpy

    generate = runpy.run_path(str(ROOT / "docs" / "reference" / "generate.py"))
    for name, page in generate["PAGES"].items():
        written = (ROOT / "docs" / "reference" / name).read_text()
        assert written == page(), f"docs/reference/{name} is stale: rerun docs/reference/generate.py"
