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
    .venv/bin/python benchmarks/mutation.py --all --jobs 2                    # 21,854 mutants: days
    .venv/bin/python benchmarks/mutation.py --all --sample 10 --jobs 2        # an estimate of that: hours

`--sample N` draws N mutants of each module at random (`--seed`) and runs them all in one scratch copy against
every test that reaches the mutated function (as mutmut finds them from one run of the suite). mutmut sees
only the calls made in the test process, so the mutants it finds no test for (code the tests run in forked
workers and subprocesses: the map's scoring workers and writer, the services) are run once more against the
test files that import their module, the mutant written into the copy's source. Then it estimates the share
detected over all the modules' mutants, each module weighted by its count of mutants (a stratified sample),
with a 95 % interval: a few hundred mutants bound the figure to a few points for a fraction of the days.
`--reuse` tallies an earlier run again (after listing equivalent mutants) without rerunning what it has
verdicts for.

Each module is mutated in a scratch copy of the repository's tracked files (`<out>/<module>/`, or
`<out>/sample/`; default out `bench-data/mutation`), never in the working tree; `../shared` is linked where
the tests look for it, so those that read it run. Slow end-to-end tests are left out (`-m "not slow"`): they
import everything and decide little here. mutmut 3 is in the test extra (`bash bootstrap.sh test` installs
it)."""

from __future__ import annotations

import argparse
import json
import math
import os
import random
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


def scratch_copy(name: str, sources: list[Path], tests: list[str], out: Path) -> Path:
    """A copy of the tracked files with mutmut's settings for these sources in its pyproject.toml."""
    copy = out / name / "repo"
    if copy.exists():
        shutil.rmtree(copy)
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True)
    for tracked_name in tracked.stdout.splitlines():
        source = ROOT / tracked_name
        if source.is_file():
            target = copy / tracked_name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    shared = (ROOT / ".." / "shared").resolve()
    for beside in (copy.parent, copy):  # the tests run in the copy and in mutmut's own copy of it, mutants/
        if shared.exists() and not (beside / "shared").exists():
            (beside / "shared").symlink_to(shared)
    settings = {
        "source_paths": [str(source) for source in sources],
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


MUTMUT = [sys.executable, "-m", "mutmut"]
LISTING = """import sys; from pathlib import Path
from mutmut.mutation.file_mutation import mutate_file_contents
from mutmut.utils.format_utils import get_mutant_name
for name in sys.argv[1:]:
    path = Path(name)
    for mutant in mutate_file_contents(name, path.read_text()).mutant_names:
        print(get_mutant_name(path, mutant))
"""


def mutant_names(copy: Path, module: Path) -> list[str]:
    """Every mutant mutmut makes of `module`, by name, without running anything (inside the scratch copy,
    whose settings mutmut reads)."""
    listed = subprocess.run(
        [sys.executable, "-c", LISTING, str(module)], cwd=copy, capture_output=True, text=True, check=True
    )
    return listed.stdout.split()


def run_mutmut(copy: Path, jobs: int, chosen: list[str]) -> dict[str, str]:
    """Run mutmut in the copy (on the chosen mutants, or all) and return {mutant: status}."""
    with open(copy.parent / "mutmut.log", "w") as log:
        run = [*MUTMUT, "run", "--max-children", str(jobs), *chosen]
        subprocess.run(run, cwd=copy, stdout=log, stderr=log)
    return read_results(copy, chosen or None)


def tally(module: Path, status: dict[str, str], copy: Path, out: Path) -> dict:
    """Counts of one module's mutants by what became of them; the survivors not shown equivalent, with
    their diffs, to `<out>/<module>.survivors.txt`. A timeout counts as detected (as Stryker and
    cosmic-ray count it); "other" (mutmut's suspicious, segfault, not checked) is left out of the share."""
    counts = dict.fromkeys(("killed", "survived", "no tests", "timeout", "other"), 0)
    for value in status.values():
        counts[value if value in counts else "other"] += 1
    listed = equivalent()
    survivors = [name for name, value in status.items() if value in ("survived", "no tests")]
    left = [name for name in survivors if name not in listed]
    with open(out / f"{row_name(module)}.survivors.txt", "w") as report:
        for name in left:
            diff = subprocess.run([*MUTMUT, "show", name], cwd=copy, capture_output=True, text=True)
            report.write(f"{diff.stdout}\n")
    detected = counts["killed"] + counts["timeout"]
    judged = detected + len(left)
    return {
        "module": str(module),
        "total": len(status),
        **counts,
        "equivalent": len(survivors) - len(left),
        "detected": detected,
        "judged": judged,
        "killed share": detected / judged if judged else float("nan"),
    }


def run_module(module: Path, out: Path, jobs: int, every_test: bool = False) -> dict:
    """Mutate one module in its scratch copy and count what became of each mutant: against the test files
    that import it, or (`every_test`) against every test that runs the mutated function, as mutmut finds
    them from a run of the whole suite."""
    tests = importing_tests(module) if not every_test else ["tests"]
    if not tests:
        return {"module": str(module), "tests": 0, "total": 0, "note": "no test file imports it"}
    copy = scratch_copy(row_name(module), [module], tests, out)
    start = time.perf_counter()
    status = run_mutmut(copy, jobs, [])
    return {**tally(module, status, copy, out), "tests": len(tests), "seconds": time.perf_counter() - start}


def run_sample(found: list[Path], out: Path, jobs: int, sample: int, seed: int, reuse: bool) -> list[dict]:
    """`sample` mutants of each module drawn at random, all run in one copy against every test that reaches
    the mutated function; each module's row also holds its count of mutants ("all mutants"). With `reuse`,
    the copy and mutmut's results of an earlier run (the same draw) are taken as they are."""
    copy = out / "sample" / "repo"
    if not reuse:
        copy = scratch_copy("sample", found, ["tests"], out)
    draw = random.Random(seed)
    every = {module: mutant_names(copy, module) for module in found}
    chosen = {module: sorted(draw.sample(names, min(sample, len(names)))) for module, names in every.items()}
    names = [name for names in chosen.values() for name in names]
    status = run_mutmut(copy, jobs, names) if not reuse else read_results(copy, names)
    rows = []
    for module in found:
        module_status = {name: status[name] for name in chosen[module]}
        module_status.update(importers_look(copy, module, module_status, jobs, out))
        row = tally(module, module_status, copy, out)
        rows.append({**row, "tests": "reaching", "all mutants": len(every[module])})
    return rows


def importers_look(copy: Path, module: Path, status: dict[str, str], jobs: int, out: Path) -> dict[str, str]:
    """The mutants no test reached, as mutmut saw it, run against the test files that import their module,
    slow tests included: mutmut records which tests call a function in the test process only, so code the
    tests run in a forked worker or a subprocess (the map's scoring workers, its writer, the services) reads
    as unreached, and so does code only the slow end-to-end tests run (training). Each mutant is written into
    the copy's source (`mutmut apply`) and the tests run with the copy first on every process's path; the
    source is restored after (from `<module>.orig`, also when a run was killed midway). Verdicts are
    remembered in `<out>/importers.json`."""
    unreached = [name for name, value in status.items() if value == "no tests"]
    tests = importing_tests(module)
    if not unreached or not tests:
        return {}
    memo_path = out / "importers.json"
    memo = json.loads(memo_path.read_text()) if memo_path.exists() else {}
    source, pristine = copy / module, copy / f"{module}.orig"
    if pristine.exists():
        shutil.copy2(pristine, source)
    else:
        shutil.copy2(source, pristine)
    env = {**os.environ, "PYTHONPATH": str(copy)}
    pytest = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider"]
    if jobs > 1:
        pytest += ["-n", str(jobs)]
    for name in (n for n in unreached if n not in memo):
        try:
            subprocess.run([*MUTMUT, "apply", name], cwd=copy, capture_output=True, check=True)
            code = subprocess.run(
                [*pytest, *tests], cwd=copy, env=env, capture_output=True, timeout=IMPORTERS_TIMEOUT
            ).returncode
        except subprocess.TimeoutExpired:
            code = "timeout"
        finally:
            shutil.copy2(pristine, source)
        memo[name] = VERDICT.get(code, "timeout")
        memo_path.write_text(json.dumps(memo, indent=1))
    return {name: memo[name] for name in unreached}


IMPORTERS_TIMEOUT = 900  # s of wall time for one mutant's importing tests, slow ones included
# pytest's exit codes: tests failed, or could not be collected or run (the mutant broke an import), is a kill
VERDICT = {0: "survived", 1: "killed", 2: "killed", 3: "killed", 5: "no tests"}


def read_results(copy: Path, names: list[str] | None = None) -> dict[str, str]:
    """{mutant: status} from mutmut's results in the copy: of every mutant, or of the named ones ("not
    checked" for one mutmut has no verdict for)."""
    results = subprocess.run(
        [*MUTMUT, "results", "--all", "true"], cwd=copy, capture_output=True, text=True
    ).stdout
    status = dict(line.strip().rsplit(": ", 1) for line in results.splitlines() if ": " in line)
    return status if names is None else {name: status.get(name, "not checked") for name in names}


def stratified(rows: list[dict]) -> tuple[float, float]:
    """The share detected over all the modules' non-equivalent mutants, estimated from samples (each module
    weighted by its mutants, less the share of its sample shown equivalent), and the half-width of its 95 %
    interval (normal approximation; each module's variance from (detected + 1) / (judged + 2), so a module
    whose few sampled mutants were all caught still counts as uncertain; finite-population corrected)."""
    weight, share, variance = [], [], []
    for row in rows:
        if not row.get("judged"):
            continue
        population = row["all mutants"] * row["judged"] / (row["judged"] + row["equivalent"])
        p = row["detected"] / row["judged"]
        smoothed = (row["detected"] + 1) / (row["judged"] + 2)
        correction = max(0.0, 1 - row["judged"] / population)
        weight.append(population)
        share.append(p)
        variance.append(smoothed * (1 - smoothed) / row["judged"] * correction)
    total = sum(weight)
    estimate = sum(w * p for w, p in zip(weight, share)) / total
    half = 1.96 * math.sqrt(sum((w / total) ** 2 * v for w, v in zip(weight, variance)))
    return estimate, half


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
    parser.add_argument("--sample", type=int, default=0, help="mutants drawn at random from each module")
    parser.add_argument("--seed", type=int, default=0, help="the draw's seed")
    parser.add_argument(
        "--reuse", action="store_true", help="with --sample: tally an earlier run's copy, running nothing new"
    )
    args = parser.parse_args()
    if not args.modules and not args.all:
        parser.error("name modules, or --all")
    args.out.mkdir(parents=True, exist_ok=True)
    found = modules(args.modules)
    print(f"{os.cpu_count()} cores, {args.jobs} mutant(s) at a time", flush=True)
    header = (
        "| module | tests | mutants | killed | survived | not reached | timeout | other | equivalent "
        "| share |"
    )
    print(header + "\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|", flush=True)
    if args.sample:
        rows = run_sample(found, args.out, args.jobs, args.sample, args.seed, args.reuse)
    else:
        rows = (run_module(module, args.out, args.jobs, args.every_test) for module in found)
    kept = []
    for row in rows:
        kept.append(row)
        if not row["total"]:
            print(f"| {row['module']} | 0 | - | - | - | - | - | - | - | {row.get('note', '')} |", flush=True)
            continue
        mutants = f"{row['total']} of {row['all mutants']}" if "all mutants" in row else row["total"]
        print(
            f"| {row['module']} | {row['tests']} | {mutants} | {row['killed']} | {row['survived']} | "
            f"{row['no tests']} | {row['timeout']} | {row['other']} | {row['equivalent']} | "
            f"{row['killed share']:.0%} |",
            flush=True,
        )
    detected, judged = sum(r.get("detected", 0) for r in kept), sum(r.get("judged", 0) for r in kept)
    if judged:
        share = f"{detected / judged:.1%}"
        print(f"\nrun: {detected} of {judged} non-equivalent mutants killed or timed out ({share})")
    if args.sample and judged:
        estimate, half = stratified(kept)
        print(f"all the modules' mutants, estimated: {estimate:.1%} +- {half:.1%} (95 %)")
    (args.out / "results.json").write_text(json.dumps(kept, indent=1))


if __name__ == "__main__":
    main()
