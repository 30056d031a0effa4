"""Mutation testing of the core and the wire: how many single-point changes of the code the tests catch.

mutmut changes one thing at a time in a module (a sign, a constant, a comparison, an argument, a default) and
runs the test files that import the module against each change; a change they all pass "survived". Per
module this prints the mutants, how many the tests killed, how many survived, how many the importing tests
never reach ("not reached": the module's function runs in no test that imports it), timeouts (the tests
ran past mutmut's limit: a loop that no longer ends, a limit that lets a test's input grow huge; detected,
as Stryker and cosmic-ray count them), the mutants listed as equivalent (`benchmarks/mutation_equivalent.txt`:
a change that cannot alter behaviour, each with why), and the share detected (killed or timed out) of the
rest. Survivors, with their diffs, go to `<out>/<module>.survivors.txt`.

    .venv/bin/python benchmarks/mutation.py affordcore/learn/thresholds.py   # one module: 5-15 min, one core
    .venv/bin/python benchmarks/mutation.py --all --jobs 2                    # the four packages: hours

Each module is mutated in a scratch copy of the repository's tracked files (`<out>/<module>/`, default
out `bench-data/mutation`), never in the working tree; `../shared` is linked beside the copy so the tests
that read it run. Slow end-to-end tests are left out (`-m "not slow"`): they import everything and decide
little here. mutmut 3 is in the test extra (`bash bootstrap.sh test` installs it)."""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("affordcore/learn", "affordcore/mapping", "affordcore/geometry", "affordwire")
EQUIVALENT = ROOT / "benchmarks" / "mutation_equivalent.txt"


def modules(paths: list[str]) -> list[Path]:
    """The Python modules to mutate: the files given, or every module of the four packages (generated
    protobuf code and package markers left out)."""
    if paths:
        return [Path(p) for p in paths]
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            relative = path.relative_to(ROOT)
            if "proto" in relative.parts or path.name == "__init__.py":
                continue
            found.append(relative)
    return found


def importing_tests(module: Path) -> list[str]:
    """The test files that import `module` (`import a.b.c`, `from a.b.c import x`, `from a.b import c`)."""
    dotted = ".".join(module.with_suffix("").parts)
    parent, name = dotted.rsplit(".", 1)
    direct = re.compile(rf"\b{re.escape(dotted)}\b")
    from_parent = re.compile(rf"from {re.escape(parent)} import \(?[^)]*?\b{name}\b", re.S)
    tests = []
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        text = path.read_text()
        if direct.search(text) or from_parent.search(text):
            tests.append(str(path.relative_to(ROOT)))
    return tests


def scratch_copy(module: Path, tests: list[str], out: Path) -> Path:
    """A copy of the tracked files with mutmut's settings for this module in its pyproject.toml."""
    copy = out / "_".join(module.with_suffix("").parts) / "repo"
    if copy.exists():
        shutil.rmtree(copy)
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True)
    for name in tracked.stdout.splitlines():
        source = ROOT / name
        if source.is_file():
            target = copy / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    shared = (ROOT / ".." / "shared").resolve()
    if shared.exists() and not (copy.parent / "shared").exists():
        (copy.parent / "shared").symlink_to(shared)
    settings = {
        "source_paths": [str(module)],
        "pytest_add_cli_args_test_selection": tests,
        "pytest_add_cli_args": ["-p", "no:cacheprovider", "-q", "-x", "-m", "not slow"],
        # every tracked top-level entry: the tests read the docs, schemas, Dockerfiles and pyproject.toml too
        "also_copy": sorted({name.split("/")[0] for name in tracked.stdout.splitlines()}),
    }
    lines = ["", "[tool.mutmut]"] + [f"{key} = {json.dumps(value)}" for key, value in settings.items()]
    with open(copy / "pyproject.toml", "a") as toml:
        toml.write("\n".join(lines) + "\n")
    return copy


def equivalent() -> dict[str, str]:
    """{mutant name: why it cannot change behaviour} from benchmarks/mutation_equivalent.txt."""
    listed = {}
    if EQUIVALENT.exists():
        for line in EQUIVALENT.read_text().splitlines():
            name, _, why = line.partition("#")
            if name.strip():
                listed[name.strip()] = why.strip()
    return listed


def run_module(module: Path, out: Path, jobs: int, every_test: bool = False) -> dict:
    """Mutate one module in its scratch copy and count what became of each mutant: against the test files
    that import it, or (`every_test`) against every test that runs the mutated function, as mutmut finds
    them from a run of the whole suite."""
    tests = importing_tests(module) if not every_test else ["tests"]
    row = {"module": str(module), "tests": len(tests)}
    if not tests:
        return {**row, "total": 0, "note": "no test file imports it"}
    copy = scratch_copy(module, tests, out)
    mutmut = [sys.executable, "-m", "mutmut"]
    env = dict(os.environ)
    start = time.perf_counter()
    with open(copy.parent / "mutmut.log", "w") as log:
        subprocess.run(
            [*mutmut, "run", "--max-children", str(jobs)], cwd=copy, stdout=log, stderr=log, env=env
        )
    row["seconds"] = time.perf_counter() - start
    results = subprocess.run([*mutmut, "results"], cwd=copy, capture_output=True, text=True, env=env).stdout
    status = dict(line.strip().rsplit(": ", 1) for line in results.splitlines() if ": " in line)
    counts = {"killed": 0, "survived": 0, "no tests": 0, "timeout": 0, "suspicious": 0}
    stats = copy / "mutants" / "mutmut-cicd-stats.json"
    subprocess.run([*mutmut, "export-cicd-stats"], cwd=copy, capture_output=True, env=env)
    if stats.exists():
        exported = json.loads(stats.read_text())
        counts["killed"], total = exported["killed"], exported["total"]
    else:
        total = len(status)
    for value in status.values():
        if value in counts and value != "killed":
            counts[value] += 1
    listed = equivalent()
    survivors = [name for name, value in status.items() if value in ("survived", "no tests")]
    shown_equivalent = [name for name in survivors if name in listed]
    left = [name for name in survivors if name not in listed]
    with open(out / f"{row_name(module)}.survivors.txt", "w") as report:
        for name in left:
            diff = subprocess.run([*mutmut, "show", name], cwd=copy, capture_output=True, text=True, env=env)
            report.write(f"{diff.stdout}\n")
    judged = counts["killed"] + len(left) + counts["timeout"]
    return {
        **row,
        "total": total,
        **counts,
        "equivalent": len(shown_equivalent),
        "killed share": (counts["killed"] + counts["timeout"]) / judged if judged else float("nan"),
    }


def row_name(module: Path) -> str:
    return "_".join(module.with_suffix("").parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("modules", nargs="*", help="module files (default with --all: the four packages)")
    parser.add_argument("--all", action="store_true", help="every module of the four packages")
    parser.add_argument(
        "--jobs", type=int, default=1, help="mutants run side by side (mutmut --max-children)"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "bench-data" / "mutation")
    parser.add_argument(
        "--every-test",
        action="store_true",
        help="run each mutant against every test that reaches its function, not only the importing files",
    )
    args = parser.parse_args()
    if not args.modules and not args.all:
        parser.error("name modules, or --all")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"{os.cpu_count()} cores, {args.jobs} mutant(s) at a time", flush=True)
    header = (
        "| module | tests | mutants | killed | survived | not reached | timeout | equivalent | killed share |"
    )
    print(header + "\n|---|---:|---:|---:|---:|---:|---:|---:|---:|", flush=True)
    for module in modules(args.modules):
        row = run_module(module, args.out, args.jobs, args.every_test)
        rows.append(row)
        if not row["total"]:
            print(f"| {module} | 0 | - | - | - | - | - | - | {row.get('note', '')} |", flush=True)
            continue
        print(
            f"| {module} | {row['tests']} | {row['total']} | {row['killed']} | {row['survived']} | "
            f"{row['no tests']} | {row['timeout']} | {row['equivalent']} | {row['killed share']:.0%} |",
            flush=True,
        )
    killed = sum(r.get("killed", 0) + r.get("timeout", 0) for r in rows)
    judged = sum(
        r.get("killed", 0)
        + r.get("survived", 0)
        + r.get("no tests", 0)
        + r.get("timeout", 0)
        - r.get("equivalent", 0)
        for r in rows
    )
    if judged:
        share = f"{killed / judged:.0%}"
        print(f"\nall: {killed} of {judged} non-equivalent mutants killed or timed out ({share})")
    (args.out / "results.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
