"""How right the maps are: learners trained on generated rooms, tested on held-out generated rooms and on the
two real rooms, every pose scored as `afford map` scores it.

One fixed split by seed: `afford synth --rooms N --seed S` (generated once into --data, reused after), rooms
taken in generation order (kinds alternate) and dealt by index: the last `--test` are test rooms, the
`--validation` before them choose thresholds (and the structured SVM's iteration), the rest train. Test
rooms and the real rooms in ../shared/data/rooms are never trained or tuned on. Per affordance and learner:

* pose precision / recall / F1 at the model's threshold (the paper's metric) and average precision;
* place recall (labelled places with a skeleton on them) and false skeletons per room, for the skeleton map
  (places counted from each room's median score, the models' rule, and beside it with the absolute threshold
  that was best on the same validation rooms);
* the same with loose tolerances (0.3 m, 0.5 rad) in place of DESIGN.md's (0.15 m, 0.4 rad);
* a learning curve over the number of training rooms, and plan views of the worst generated test rooms.

    .venv/bin/python benchmarks/accuracy.py                    # the documented run (about an hour, 2 cores)
    .venv/bin/python benchmarks/accuracy.py --rooms 24 --test 6 --validation 4 --curve 6,14   # a quick look

Writes results.json, results.md and figures to --out (default docs/accuracy) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL_ROOMS = ROOT.parent / "shared" / "data" / "rooms"
LOOSE = {"xy_tolerance": 0.3, "theta_tolerance": 0.5}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=150, help="generated rooms in all")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--test", type=int, default=24, help="the last this many rooms are test rooms")
    parser.add_argument("--validation", type=int, default=16, help="the this many before them validate")
    parser.add_argument("--data", type=Path, default=ROOT / "bench-data" / "accuracy")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "accuracy")
    parser.add_argument("--learners", default="linear-tuned,ssvm,cascade")
    parser.add_argument("--curve", default="12,30,60", help="training-room counts of the learning curve")
    parser.add_argument("--curve-learners", default="linear-tuned,cascade")
    parser.add_argument("--affordances", default="sitting-relaxing,sitting-working,standing-working")
    parser.add_argument("--models", type=Path, help="also write the full run's cascade models here")
    args = parser.parse_args()

    from affordcore.features import FeatureLayout
    from affordcore.learn.defaults import data_record, split_by_index
    from affordcore.learn.examples import Task, data_set_rooms, load_rooms, room_examples
    from affordcore.learn.train import train_on_rooms
    from affordcore.settings import Settings

    started = time.perf_counter()
    settings = Settings()
    layout = FeatureLayout.from_settings(settings)
    files = {f.name: f for f in generated_rooms(args)}
    train, validation, test = (
        [files[name] for name in part] for part in split_by_index(list(files), args.validation, args.test)
    )
    print(
        f"{len(train)} training, {len(validation)} validation, {len(test)} test rooms; {os.cpu_count()} cores"
    )
    rooms = {r.name: r for r in load_rooms(list(files.values()), settings, lambda name: None)}
    real = load_rooms(data_set_rooms(REAL_ROOMS), settings) if REAL_ROOMS.is_dir() else []
    train_names, validation_names = [f.name for f in train], [f.name for f in validation]
    results: dict = {
        "split": {"train": train_names, "validation": validation_names, "test": [f.name for f in test]}
    }
    results["rows"], results["curve"], models = [], [], {}
    for affordance in args.affordances.split(","):
        task = Task(affordance, settings, layout)
        examples = {name: room_examples(rooms[name], task) for name in train_names + validation_names}
        for learner in args.learners.split(","):
            t0 = time.perf_counter()
            model = train_on_rooms(examples, train_names, validation_names, task, learner, seed=args.seed)
            seconds = time.perf_counter() - t0
            models[(affordance, learner)] = model
            for name, test_rooms in (("generated", [rooms[f.name] for f in test]), ("real", real)):
                held = [r for r in test_rooms if r.labels.of(affordance)] if name == "real" else test_rooms
                if held:
                    row = score_rooms(model, held, task)
                    results["rows"].append(
                        {
                            "affordance": affordance,
                            "learner": learner,
                            "rooms": name,
                            "train_seconds": seconds,
                            **row,
                        }
                    )
                    print_row(results["rows"][-1])
        for n in [int(v) for v in args.curve.split(",") if int(v) < len(train_names)] + [len(train_names)]:
            for learner in args.curve_learners.split(","):
                model = models.get((affordance, learner)) if n == len(train_names) else None
                model = model or train_on_rooms(
                    examples, train_names[:n], validation_names, task, learner, seed=args.seed
                )
                row = score_rooms(model, [rooms[f.name] for f in test], task, loose=False)
                results["curve"].append(
                    {"affordance": affordance, "learner": learner, "train_rooms": n, **row}
                )
                print(
                    f"  curve {affordance} {learner} {n} rooms: F1 {row['f1']:.2f}, AP {row['ap']:.2f}, "
                    f"places {row['place_recall']:.2f}, false/room {row['false_per_room']:.1f}"
                )
        del examples
        learner = "cascade" if (affordance, "cascade") in models else args.learners.split(",")[-1]
        generated = next(
            r
            for r in results["rows"]
            if (r["affordance"], r["learner"], r["rooms"]) == (affordance, learner, "generated")
        )
        worst_room_figures(
            args,
            models[(affordance, learner)],
            generated["per_room"],
            [rooms[f.name] for f in test],
            list(files.values()),
            task,
        )
        if args.models and (affordance, "cascade") in models:
            args.models.mkdir(parents=True, exist_ok=True)
            model = models[(affordance, "cascade")]
            model.parameters["data"] = data_record(len(files), args.seed, [f.name for f in test])
            model.save(args.models / f"{affordance}.model.json")
    results["seconds"] = time.perf_counter() - started
    results["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    results["cores"] = os.cpu_count()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (args.out / "results.md").write_text(markdown(results, args))
    plot_curve(results["curve"], args.out / "learning-curve.png")
    print(markdown(results, args))


def generated_rooms(args) -> list:
    """The first `args.rooms` rooms of the data set, generated on the first run (and again when more rooms are
    wanted or the generator's code changed). Room i of a data set depends only on the seed and i, so a smaller
    run uses a prefix of a larger data set."""
    from affordcore.learn.examples import data_set_rooms
    from affordcore.synth.dataset import SynthOptions, synthesize

    stamp = args.data / "accuracy-options.json"
    have = json.loads(stamp.read_text()) if stamp.exists() else {}
    wanted = {"seed": args.seed, "generator": generator_version()}
    if have.get("rooms", 0) < args.rooms or {k: have.get(k) for k in wanted} != wanted:
        print(f"generating {args.rooms} rooms into {args.data} ...")
        synthesize(SynthOptions(rooms=args.rooms, seed=args.seed), args.data)
        stamp.write_text(json.dumps({"rooms": args.rooms, **wanted}))
    # by generation index, not by name: names start with the room kind, and kinds are dealt round-robin,
    # so every part of the split holds every kind
    rooms = sorted(data_set_rooms(args.data), key=lambda files: int(files.name.rsplit("-", 1)[1]))
    return rooms[: args.rooms]


def generator_version() -> str:
    """A digest of the generator's source: rooms made by other code are made again."""
    import hashlib

    digest = hashlib.sha256()
    for path in sorted((ROOT / "affordcore" / "synth").glob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def score_rooms(model, rooms: list, task, loose: bool = True) -> dict:
    """Pose and place metrics of a model over rooms (strict tolerances, and loose ones when asked)."""
    from sklearn.metrics import average_precision_score

    from affordcore.learn.thresholds import room_scores
    from affordcore.learn.train import metrics

    row = {}
    for prefix, tolerances in (("", {}), ("loose_", LOOSE)) if loose else (("", {}),):
        scored = [room_scores(model, room, task.layout, task.settings, **tolerances) for room in rooms]
        scores = np.concatenate([r.scores for r in scored])
        labels = np.concatenate([r.labels for r in scored])
        at = metrics(scores, labels, model.threshold)
        # the model's place rule (relative to each room's median score), and the absolute threshold that
        # was the best choice on the same validation rooms, from the same scores
        counts = np.sum([r.places(model.place_cut_from(r.reference)) for r in scored], axis=0)
        absolute = model.validation.get("absolute_place_threshold", model.skeleton_threshold)
        found_abs, _, false_abs = np.sum([r.places(absolute) for r in scored], axis=0)
        found, _, false = counts
        n_labels = sum(len(r.label_best) for r in scored)
        row.update(
            {
                f"{prefix}precision": at["precision"],
                f"{prefix}recall": at["recall"],
                f"{prefix}f1": at["f1"],
                f"{prefix}ap": float(average_precision_score(labels > 0, scores))
                if (labels > 0).any()
                else 0.0,
                f"{prefix}places": f"{found}/{n_labels}",
                f"{prefix}place_recall": found / n_labels if n_labels else float("nan"),
                f"{prefix}false_per_room": false / len(rooms),
                f"{prefix}absolute_places": f"{found_abs}/{n_labels}",
                f"{prefix}absolute_false_per_room": false_abs / len(rooms),
            }
        )
        row[f"{prefix}per_room"] = {}
        for r in scored:
            found_here, _, false_here = r.places(model.place_cut_from(r.reference))
            row[f"{prefix}per_room"][r.room] = {"missed": len(r.label_best) - found_here, "false": false_here}
    return row


def worst_room_figures(args, model, per_room: dict, test_rooms: list, files: list, task) -> None:
    """Plan views of the two generated test rooms where `model` errs most (`per_room`: its missed and false
    places per room, from the table's run)."""
    from affordcore.pipeline import map_affordances
    from affordcore.plots import plot_map
    from affordcore.scene import load_cloud

    affordance = model.affordance
    worst = sorted(per_room, key=lambda n: -(per_room[n]["missed"] + per_room[n]["false"]))[:2]
    cloud_of = {f.name: f.cloud for f in files}
    folder = args.out / "figures"
    folder.mkdir(parents=True, exist_ok=True)
    for name in worst:
        room = next(r for r in test_rooms if r.name == name)
        amap = map_affordances(room.fields, task.layout, [model], task.settings)[affordance]
        points = load_cloud(cloud_of[name]).points
        plot_map(points, amap, folder / f"worst-{affordance}-{name}.png", labels=room.labels)


def print_row(row: dict) -> None:
    print(
        f"{row['affordance']:17s} {row['learner']:13s} {row['rooms']:9s} P/R/F1 {row['precision']:.2f}/"
        f"{row['recall']:.2f}/{row['f1']:.2f} AP {row['ap']:.2f} places {row['places']} false/room "
        f"{row['false_per_room']:.1f} (absolute threshold: {row['absolute_places']}, "
        f"{row['absolute_false_per_room']:.1f}) | loose F1 {row['loose_f1']:.2f} places "
        f"{row['loose_places']} false/room {row['loose_false_per_room']:.1f} ({row['train_seconds']:.0f} s)"
    )


def markdown(results: dict, args) -> str:
    paper = json.loads((ROOT / "affordcore" / "data" / "paper_results.json").read_text())["affordances"]
    split = results["split"]
    lines = [
        f"Command: `.venv/bin/python benchmarks/accuracy.py --rooms {args.rooms} --seed {args.seed} --test "
        f"{args.test} --validation {args.validation} --curve {args.curve}`; {len(split['train'])} training, "
        f"{len(split['validation'])} validation, {len(split['test'])} generated test rooms; "
        f"{results['seconds'] / 60:.0f} min, peak RSS {results['peak_rss_gb']:.1f} GB, "
        f"{results['cores']} cores.",
        "",
        "| affordance | learner | rooms | pose P / R / F1 | AP | places found | false / room | "
        "absolute threshold: places, false / room | loose: F1 | loose: places | loose: false / room | "
        "paper SSVM P / R / F1 |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['affordance']} | {r['learner']} | {r['rooms']} | {r['precision']:.2f} / "
            f"{r['recall']:.2f} / **{r['f1']:.2f}** | {r['ap']:.2f} | {r['places']} | "
            f"{r['false_per_room']:.1f} | {r['absolute_places']}, {r['absolute_false_per_room']:.1f} | "
            f"{r['loose_f1']:.2f} | {r['loose_places']} | {r['loose_false_per_room']:.1f} | "
            f"{paper.get(r['affordance'], {}).get('structured_svm', '-')} |"
        )
    lines += [
        "",
        "Learning curve (generated test rooms):",
        "",
        "| affordance | learner | training rooms | pose F1 | AP | place recall | false / room |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in results["curve"]:
        lines.append(
            f"| {r['affordance']} | {r['learner']} | {r['train_rooms']} | {r['f1']:.2f} | {r['ap']:.2f} | "
            f"{r['place_recall']:.2f} | {r['false_per_room']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def plot_curve(curve: list[dict], path: Path) -> None:
    from affordcore.plots import pyplot

    plt = pyplot()
    affordances = list(dict.fromkeys(r["affordance"] for r in curve))
    figure, axes = plt.subplots(1, 3, figsize=(14, 4), constrained_layout=True)
    for metric, ax in zip(("f1", "place_recall", "false_per_room"), axes):
        for affordance in affordances:
            for learner in dict.fromkeys(r["learner"] for r in curve):
                points = [
                    (r["train_rooms"], r[metric])
                    for r in curve
                    if r["affordance"] == affordance and r["learner"] == learner
                ]
                if points:
                    n, v = zip(*points)
                    ax.plot(n, v, "o-" if learner == "cascade" else "s--", label=f"{affordance} / {learner}")
        ax.set_xlabel("training rooms")
        ax.set_title(
            {"f1": "pose F1", "place_recall": "place recall", "false_per_room": "false skeletons / room"}[
                metric
            ]
        )
    axes[0].legend(fontsize=7)
    figure.savefig(path, dpi=110)
    plt.close(figure)


if __name__ == "__main__":
    main()
