"""`pip install affordmap` (no extras) maps a room: the core commands run with none of the optional dependency
groups' modules importable, and a command that needs a group says which one to install.

The modules are hidden from a child interpreter by a `sitecustomize` on its PYTHONPATH that puts a finder in
front of `sys.meta_path` raising ModuleNotFoundError for them, as an interpreter without them would."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

# what the [services], [ros] and [learn] extras install (pyproject.toml)
HIDDEN = ("zenoh", "kiss_icp", "google.protobuf", "cryptography", "rosbags", "sklearn", "osqp")
SERVICES_HINT = "needs the services extra: pip install 'affordmap[services]'"
LEARN_HINT = "needs the learn extra: pip install 'affordmap[learn]'"


@pytest.fixture(scope="module")
def core_only(tmp_path_factory) -> dict[str, str]:
    """An environment whose interpreter cannot import any module of the extras."""
    folder = tmp_path_factory.mktemp("core-only")
    (folder / "sitecustomize.py").write_text(
        textwrap.dedent(
            f"""
            import sys

            HIDDEN = {HIDDEN!r}


            class HideExtras:
                def find_spec(self, name, path=None, target=None):
                    if any(name == hidden or name.startswith(hidden + ".") for hidden in HIDDEN):
                        raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
                    return None


            sys.meta_path.insert(0, HideExtras())
            """
        )
    )
    pythonpath = os.pathsep.join(filter(None, [str(folder), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": pythonpath, "COLUMNS": "200", "NO_COLOR": "1"}


def run(env: dict, *args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "affordcli", *args],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=cwd,
    )


@pytest.mark.parametrize("module", HIDDEN)
def test_the_extras_modules_are_really_hidden(core_only, module):
    result = subprocess.run(
        [sys.executable, "-c", f"import {module}"], capture_output=True, text=True, env=core_only, timeout=60
    )
    assert result.returncode != 0 and "ModuleNotFoundError" in result.stderr


def test_help_and_the_listing_commands_run_without_the_extras(core_only):
    help_text = run(core_only, "--help")
    assert help_text.returncode == 0, help_text.stderr
    assert "map" in help_text.stdout and "serve" in help_text.stdout and "up" in help_text.stdout
    skeletons = run(core_only, "skeletons", "list")
    assert skeletons.returncode == 0 and "sitting-working" in skeletons.stdout, skeletons.stderr
    models = run(core_only, "models", "list")  # the shipped cascade models score without scikit-learn
    assert models.returncode == 0 and "cascade" in models.stdout, models.stderr


@pytest.mark.slow
def test_map_align_and_features_run_without_the_extras(core_only, small_room, tmp_path):
    mapped = run(core_only, "map", small_room, "--out", str(tmp_path / "maps"), "--quiet")
    assert mapped.returncode == 0, mapped.stderr
    for name in ("sitting-relaxing", "sitting-working", "standing-working"):
        assert (tmp_path / "maps" / f"{name}.json").is_file()
    assert (tmp_path / "maps" / "map.rrd").is_file()
    aligned = run(core_only, "align", small_room, "--json", "--out", str(tmp_path / "aligned.ply"))
    assert aligned.returncode == 0 and (tmp_path / "aligned.ply").is_file(), aligned.stderr
    features = run(core_only, "features", small_room, "-a", "sitting-working", "--json", "--quiet")
    assert features.returncode == 0 and '"poses"' in features.stdout, features.stderr


@pytest.mark.parametrize(
    ("command", "options", "hint"),
    [
        ("serve", ["assembler", "--connect", "tcp/127.0.0.1:7447", "--robot", "r"], SERVICES_HINT),
        ("router", ["--listen", "tcp/127.0.0.1:7447"], SERVICES_HINT),
        ("up", ["--rrd-dir", "rec"], SERVICES_HINT),
        ("status", ["--robot", "r"], SERVICES_HINT),
        ("certs", ["site"], SERVICES_HINT),
        ("watch", ["--connect", "tcp/127.0.0.1:7447", "--robot", "r", "--timeout", "1"], SERVICES_HINT),
        ("train", ["--data", "rooms", "-a", "sitting-working", "--out", "m.json"], LEARN_HINT),
        ("models rebuild", ["--out", "models"], LEARN_HINT),
    ],
)
def test_a_command_that_needs_an_extra_names_it_in_one_line(core_only, tmp_path, command, options, hint):
    result = run(core_only, *command.split(), *options, cwd=tmp_path)
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr == f"error: afford {command} {hint}\n"
    assert list(tmp_path.iterdir()) == []  # nothing was started or written
