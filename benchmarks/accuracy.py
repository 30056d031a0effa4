"""How right the maps are: learners trained on generated rooms, tested on held-out generated rooms and on the
real validation rooms, every pose scored as `afford map` scores it.

One fixed split by seed: `afford synth --rooms N --seed S` (generated once into --data, reused after), rooms
taken in generation order (kinds alternate) and dealt by index: the last `--test` are test rooms, the
`--validation` before them choose thresholds (and the structured SVM's iteration), the rest train. The real
validation rooms (../shared/data/rooms and validation/, the ScanNet cloud rebuilt into bench-data/validation)
are never trained on; they calibrate the place models beside the generated validation rooms (weighing
AFFORD_LEARN__REAL_SHARE of them; `--no-real-calibration`: not), so their rows are in-sample for the
place models and cuts. Test rooms are never trained or tuned on. Per affordance and learner:

* pose precision / recall / F1 at the model's threshold (the paper's metric) and average precision;
* place recall (labelled places with a skeleton on them) and false skeletons per room, for the skeleton map
  (places counted from each room's median score, the models' rule, and beside it with the absolute threshold
  that was best on the same validation rooms);
* the same with loose tolerances (0.3 m, 0.5 rad) in place of DESIGN.md's (0.15 m, 0.4 rad);
* a learning curve over the number of training rooms, and plan views of the worst generated test rooms.

    .venv/bin/python benchmarks/accuracy.py                    # the documented run (about an hour, 2 cores)
    .venv/bin/python benchmarks/accuracy.py --rooms 24 --test 6 --validation 4 --curve 6,14   # a quick look
    .venv/bin/python benchmarks/accuracy.py --shipped          # the shipped models on their own test rooms

`--shipped` scores the shipped models instead of training: they record the data set and test rooms they were
trained for (`afford models rebuild` trains them as this benchmark does), so on that split the tables are the
full run's without its training (minutes, not the better part of an hour); no learning curve.

`--unseen N` (48; 0: none) also scores the models on N generated rooms of another seed (`--unseen-seed`,
one no data set of the project uses; generated once into bench-data/unseen-SEED), every scan style dealt in
turn: rows "unseen seed S" and one per style, beside the test rooms of the split. Rooms of a seed the models
never saw are what the generated-room targets are set on; the split's test rooms share the training
rooms' seed.

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
# the real validation rooms (ScanNet's cloud rebuilt into bench-data/validation, its labels in shared)
REAL_ROOMS = [ROOT.parent / "shared" / "data" / d for d in ("rooms", "validation")] + [
    ROOT / "bench-data" / "validation"
]


def main() -> None:
    from affordcore.learn.defaults import ROOMS, SEED, TEST, VALIDATION

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=ROOMS, help="generated rooms in all")
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument(
        "--styles", help="scan styles dealt to rooms in turn (afford synth --styles; default: every style)"
    )
    parser.add_argument("--test", type=int, default=TEST, help="the last this many rooms are test rooms")
    parser.add_argument(
        "--validation", type=int, default=VALIDATION, help="the this many before them validate"
    )
    parser.add_argument("--data", type=Path, default=ROOT / "bench-data" / "accuracy")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "accuracy")
    parser.add_argument(
        "--furniture",
        default="base",
        help="what the generated rooms are furnished from (afford synth --furniture)",
    )
    parser.add_argument("--learners", default="cascade")
    parser.add_argument("--curve", default="30", help="training-room counts of the learning curve")
    parser.add_argument("--curve-learners", default="cascade")
    parser.add_argument("--affordances", default="sitting-relaxing,sitting-working,standing-working")
    parser.add_argument("--models", type=Path, help="also write the full run's cascade models here")
    parser.add_argument(
        "--shipped", action="store_true", help="score the shipped models on their own split, no training"
    )
    parser.add_argument(
        "--trained",
        type=Path,
        help="as --shipped, for the models in this folder (an afford models rebuild --out, or --models)",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        help="the room cache (default: learn.cache_dir); rooms are read from it one at a time",
    )
    parser.add_argument(
        "--unseen", type=int, default=48, help="also score on this many rooms of another seed (0: none)"
    )
    parser.add_argument("--unseen-seed", type=int, default=UNSEEN_SEED, help="that seed")
    parser.add_argument(
        "--no-real-calibration",
        action="store_true",
        help="fit the place models on the generated validation rooms alone, not on the real ones beside them "
        "(afford models rebuild without --real)",
    )
    args = parser.parse_args()
    args.shipped = args.shipped or args.trained is not None

    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.cache import RoomCache
    from affordcore.learn.defaults import data_record, data_set_styles, split_by_index
    from affordcore.learn.examples import Task, labelled_rooms, load_rooms, split_examples
    from affordcore.learn.train import train_on_rooms
    from affordcore.settings import Settings

    started = time.perf_counter()
    settings = Settings()
    cache = RoomCache(args.cache) if args.cache else RoomCache.from_settings(settings)
    layout = FeatureLayout.from_settings(settings)
    files = {f.name: f for f in generated_rooms(args)}
    train, validation, test = (
        [files[name] for name in part] for part in split_by_index(list(files), args.validation, args.test)
    )
    print(
        f"{len(train)} training, {len(validation)} validation, {len(test)} test rooms; {os.cpu_count()} cores"
    )
    # rooms hold their labels; fields and sampled rows are read from the cache one room at a time
    needed = test if args.shipped else list(files.values())  # the shipped models need no training rooms
    rooms = {r.name: r for r in load_rooms(needed, settings, cache=cache)}
    real_folders = [folder for folder in REAL_ROOMS if folder.is_dir()]
    real = load_rooms(labelled_rooms(real_folders), settings, cache=cache)
    calibrating = [] if args.no_real_calibration else real
    train_names, validation_names = [f.name for f in train], [f.name for f in validation]
    results: dict = {
        "split": {"train": train_names, "validation": validation_names, "test": [f.name for f in test]}
    }
    results["rows"], results["curve"], results["reliability"], models = [], [], [], {}
    results["operating"] = []
    groups = test_groups(args.data, [f.name for f in test], [r.name for r in real])
    unseen = unseen_rooms(args, settings, cache)
    groups.update(unseen_groups(args, [r.name for r in unseen]))
    shipped = shipped_models_for(args, [f.name for f in test]) if args.shipped else {}
    for affordance in args.affordances.split(","):
        task = Task(affordance, settings, layout)
        examples = {} if shipped else split_examples(rooms, train_names, validation_names, task, cache)
        for learner in args.learners.split(","):
            t0 = time.perf_counter()
            model = shipped.get(affordance) or train_on_rooms(
                examples, train_names, validation_names, task, learner, seed=args.seed, real=calibrating
            )
            seconds = time.perf_counter() - t0
            models[(affordance, learner)] = model
            test_rooms = [rooms[f.name] for f in test] + unseen + real
            results_of = room_results(model, test_rooms, task)
            for group, names in groups.items():
                row = {
                    "affordance": affordance,
                    "learner": learner,
                    "rooms": group,
                    "train_seconds": seconds,
                    "place_cut": model.places.cut if model.places is not None else None,
                    **summarise(model, results_of, names),
                }
                results["rows"].append(row)
                if model.places is not None:
                    results["operating"].append(
                        {
                            "affordance": affordance,
                            "learner": learner,
                            "rooms": group,
                            "cut": model.places.cut,
                            "points": operating_curve(results_of, names),
                        }
                    )
                    results["reliability"].append(
                        {
                            "affordance": affordance,
                            "learner": learner,
                            "rooms": group,
                            "bins": reliability(results_of, names),
                        }
                    )
                print_row(row)
            del results_of
        for n in [] if shipped else curve_sizes(args.curve, len(train_names)):
            for learner in args.curve_learners.split(","):
                model = models.get((affordance, learner)) if n == len(train_names) else None
                model = model or train_on_rooms(
                    examples,
                    train_names[:n],
                    validation_names,
                    task,
                    learner,
                    seed=args.seed,
                    real=calibrating,
                )
                test_names = [f.name for f in test]
                row = summarise(
                    model, room_results(model, [rooms[n] for n in test_names], task, False), test_names, False
                )
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
            model.parameters["data"] = data_record(
                len(files), args.seed, [f.name for f in test], data_set_styles(args.data)
            )
            model.save(args.models / f"{affordance}.model.json")
    results["seconds"] = time.perf_counter() - started
    results["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    results["cores"] = os.cpu_count()
    results["place_probability"] = settings.map.place_probability
    args.out.mkdir(parents=True, exist_ok=True)
    if args.shipped:  # no curve measured: the last training run's stays, said to be that run's
        before = args.out / "results.json"
        results["curve"] = json.loads(before.read_text()).get("curve", []) if before.exists() else []
    else:
        plot_curve(results["curve"], args.out / "learning-curve.png")
    (args.out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (args.out / "results.md").write_text(markdown(results, args))
    plot_reliability(results["reliability"], args.out / "reliability.png")
    plot_operating(results["operating"], args.out / "operating.png")
    print(markdown(results, args))


def curve_sizes(curve: str, train_rooms: int) -> list[int]:
    """The learning curve's training-room counts: those asked for below the full set, and the full set."""
    return [int(v) for v in curve.split(",") if int(v) < train_rooms] + [train_rooms]


def shipped_models_for(args, test_names: list[str]) -> dict:
    """{affordance: the shipped cascade model}, refused (SystemExit naming the difference) unless each was
    trained for this benchmark's data set and split: scoring it on rooms it trained on would flatter it."""
    from affordcore.learn.defaults import data_record, data_set_styles
    from affordcore.learn.model import load_model, models_in, shipped_models

    if args.learners != "cascade":
        raise SystemExit(f"--shipped scores the shipped cascade models; --learners {args.learners} cannot")
    wanted = data_record(args.rooms, args.seed, test_names, data_set_styles(args.data))
    models = {}
    for affordance in args.affordances.split(","):
        path = (models_in(args.trained) if args.trained else shipped_models()).get(affordance)
        if path is None:
            raise SystemExit(f"--shipped: no shipped model for {affordance}")
        model = load_model(path)
        if model.parameters.get("data") != wanted:
            raise SystemExit(
                f"--shipped: {path.name} was trained on {model.parameters.get('data')}, not on this run's "
                f"{args.rooms} rooms of seed {args.seed} with its {len(test_names)} test rooms"
            )
        models[affordance] = model
    return models


def generated_rooms(args) -> list:
    """The first `args.rooms` rooms of the data set, generated on the first run (and again when more rooms are
    wanted or the generator's code changed). Room i of a data set depends only on the seed and i, so a smaller
    run uses a prefix of a larger data set."""
    from affordcore.learn.examples import data_set_rooms
    from affordcore.synth.batch import synthesize
    from affordcore.synth.dataset import SynthOptions
    from affordcore.synth.styles import STYLES

    stamp = args.data / "accuracy-options.json"
    have = json.loads(stamp.read_text()) if stamp.exists() else {}
    styles = tuple(args.styles.split(",")) if args.styles else tuple(STYLES)
    wanted = {
        "seed": args.seed,
        "generator": generator_version(),
        "styles": list(styles),
        "furniture": args.furniture,
    }
    if have.get("rooms", 0) < args.rooms or {k: have.get(k) for k in wanted} != wanted:
        print(f"generating {args.rooms} rooms into {args.data} ...")
        options = SynthOptions(rooms=args.rooms, seed=args.seed, styles=styles, furniture=args.furniture)
        synthesize(options, args.data)
        stamp.write_text(json.dumps({"rooms": args.rooms, **wanted}))
    # by generation index, not by name: names start with the room kind, and kinds are dealt round-robin,
    # so every part of the split holds every kind
    rooms = sorted(data_set_rooms(args.data), key=lambda files: int(files.name.rsplit("-", 1)[1]))
    return rooms[: args.rooms]


def test_groups(data: Path, generated: list[str], real: list[str]) -> dict[str, list[str]]:
    """The rooms each row of the table is over: every generated test room, those of each scan style, the real
    rooms together and each one alone."""
    groups = style_groups(data, "generated", generated)
    if real:
        groups["real"] = real
        groups.update({f"real/{'_'.join(name.split('_')[:2])}": [name] for name in real})
    return groups


UNSEEN_SEED = 101  # no data set, test or benchmark of the project uses it


def style_groups(data: Path, label: str, names: list[str], prefix: str = "") -> dict[str, list[str]]:
    """{label: names, "label/STYLE": those of each scan style}, the styles from the data set's summary.json
    (`prefix`: what the names add to the data set's own room names)."""
    summary = json.loads((data / "summary.json").read_text())
    style = {prefix + room["room"]: room.get("style", "fused") for room in summary["rooms"]}
    groups = {label: names}
    for name in dict.fromkeys(style[n] for n in names):
        groups[f"{label}/{name}"] = [n for n in names if style[n] == name]
    return groups


def unseen_rooms(args, settings, cache) -> list:
    """`--unseen` rooms of `--unseen-seed` (generated once into bench-data/unseen-SEED), their names prefixed
    (`unseen_prefix`) so that they never share a name with the split's rooms."""
    from dataclasses import replace
    from types import SimpleNamespace

    from affordcore.learn.examples import load_rooms

    if not args.unseen:
        return []
    # base furniture whatever the split's: models trained on either are scored on the same rooms
    wanted = SimpleNamespace(
        data=unseen_folder(args),
        rooms=args.unseen,
        seed=args.unseen_seed,
        styles=args.styles,
        furniture="base",
    )
    files = generated_rooms(wanted)
    return [
        replace(room, name=unseen_prefix(args) + room.name)
        for room in load_rooms(files, settings, cache=cache)
    ]


def unseen_prefix(args) -> str:
    return f"seed {args.unseen_seed}: "


def unseen_folder(args) -> Path:
    return ROOT / "bench-data" / f"unseen-{args.unseen_seed}"


def unseen_groups(args, names: list[str]) -> dict[str, list[str]]:
    """The unseen rooms' rows: all of them, and those of each scan style."""
    if not names:
        return {}
    return style_groups(unseen_folder(args), f"unseen seed {args.unseen_seed}", names, unseen_prefix(args))


def generator_version() -> str:
    """A digest of the generator's source: rooms made by other code are made again."""
    from affordcore.synth.batch import generator_digest

    return generator_digest()


def room_results(model, rooms: list, task, loose: bool = True) -> dict:
    """Per room, scored once: what the summaries need, strict and (with `loose`) loose tolerances."""
    from affordcore.labels import LOOSE_TOLERANCES
    from affordcore.learn.thresholds import room_scores
    from affordcore.mapping.pipeline import score_model

    results = {}
    cut = task.settings.map.place_probability  # None: each model's own cut
    absolute = model.validation.get("absolute_place_threshold", model.skeleton_threshold)
    for room in rooms:
        grid_and_scores = score_model(model, room.fields, task.layout, task.settings)
        results[room.name] = {}
        for prefix, tolerances in (("", {}), ("loose_", LOOSE_TOLERANCES)) if loose else (("", {}),):
            r = room_scores(model, room, task.layout, task.settings, grid_and_scores, **tolerances)
            result = {
                "scores": r.scores,
                "labels": r.labels,
                "n_labels": len(r.label_best),
                "score_cut": r.places(model.place_cut_from(r.reference)),
                "absolute": r.places(absolute),
            }
            if model.places is not None:
                candidates = r.model_candidates(model)
                p = model.places.probability(candidates.evidence)
                own = model.places.cut if cut is None else cut
                radius = task.settings.map.nms_radius
                result["probability"] = candidates.places(p, own, radius)
                result["within_reach"] = candidates.within_reach()
                result["operating"] = [candidates.places(p, c, radius) for c in OPERATING_CUTS]
                counted = ~candidates.ignored
                result["reliability"] = (p[counted], candidates.used[counted])
            results[room.name][prefix] = result
    return results


def place_cuts(results: dict) -> str:
    """The probability the places had to reach: `map.place_probability` when set, else each model's cut."""
    if results.get("place_probability") is not None:
        return str(results["place_probability"])
    cuts = {
        f"{r['affordance']} ({r['learner']})": r.get("place_cut")
        for r in results["rows"]
        if r["rooms"] == "generated"
    }
    return "each model's own cut: " + ", ".join(f"{k} {v}" for k, v in cuts.items())


def summarise(model, results: dict, names: list[str], loose: bool = True) -> dict:
    """Pose and place metrics of a model over rooms (`room_results`' entries of `names`). Places are the
    model's own rule: its place model at `map.place_probability` when it has one, else its score cut; the
    score cut and the absolute threshold are kept beside for comparison."""
    from sklearn.metrics import average_precision_score

    from affordcore.learn.train import metrics

    row: dict = {"room_count": len(names)}
    for prefix in ("", "loose_") if loose else ("",):
        parts = [results[name][prefix] for name in names]
        scores = np.concatenate([r["scores"] for r in parts])
        labels = np.concatenate([r["labels"] for r in parts])
        at = metrics(scores, labels, model.threshold)
        n_labels = sum(r["n_labels"] for r in parts)
        rule = "probability" if model.places is not None else "score_cut"
        found, _, false = np.sum([r[rule] for r in parts], axis=0)
        cut_found, _, cut_false = np.sum([r["score_cut"] for r in parts], axis=0)
        found_abs, _, false_abs = np.sum([r["absolute"] for r in parts], axis=0)
        reach = sum(r.get("within_reach", 0) for r in parts)
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
                f"{prefix}within_reach": f"{reach}/{n_labels}" if model.places is not None else "-",
                f"{prefix}false_per_room": false / len(names),
                f"{prefix}score_cut_places": f"{cut_found}/{n_labels}",
                f"{prefix}score_cut_false_per_room": cut_false / len(names),
                f"{prefix}absolute_places": f"{found_abs}/{n_labels}",
                f"{prefix}absolute_false_per_room": false_abs / len(names),
            }
        )
        rule_of = {name: results[name][prefix][rule] for name in names}
        row[f"{prefix}per_room"] = {
            name: {"missed": results[name][prefix]["n_labels"] - found_here, "false": false_here}
            for name, (found_here, _, false_here) in rule_of.items()
        }
    return row


RELIABILITY_BINS = np.linspace(0.0, 1.0, 6)


def reliability(results: dict, names: list[str]) -> list[dict]:
    """Predicted against observed frequency of the candidate places of rooms `names`, in RELIABILITY_BINS."""
    pairs = [results[name][""].get("reliability") for name in names]
    pairs = [pair for pair in pairs if pair is not None]
    if not pairs:
        return []
    p = np.concatenate([pair[0] for pair in pairs])
    used = np.concatenate([pair[1] for pair in pairs])
    which = np.clip(np.digitize(p, RELIABILITY_BINS[1:-1]), 0, len(RELIABILITY_BINS) - 2)
    return [
        {
            "bin": [float(RELIABILITY_BINS[b]), float(RELIABILITY_BINS[b + 1])],
            "candidates": int(np.sum(which == b)),
            "predicted": float(p[which == b].mean()),
            "observed": float(used[which == b].mean()),
        }
        for b in range(len(RELIABILITY_BINS) - 1)
        if np.any(which == b)
    ]


# place probabilities a map can be asked for (`map.place_probability`): the operating curve's points
OPERATING_CUTS = np.round(np.concatenate([[0.02], np.arange(0.05, 0.951, 0.05)]), 2)
TABLE_CUTS = (0.1, 0.2, 0.3, 0.5, 0.7)  # the ones results.md tabulates


def operating_curve(results: dict, names: list[str]) -> list[dict]:
    """Place recall and false skeletons per room of rooms `names` at every one of OPERATING_CUTS: what a map
    asked for places of at least that probability would hold."""
    parts = [results[name][""] for name in names if "operating" in results[name][""]]
    if not parts:
        return []
    labelled = sum(part["n_labels"] for part in parts)
    counts = np.sum([part["operating"] for part in parts], axis=0)  # (cuts, 3): found, kept, false
    return [
        {
            "cut": float(cut),
            "found": int(found),
            "labelled": labelled,
            "recall": float(found / labelled) if labelled else float("nan"),
            "false_per_room": float(false / len(parts)),
        }
        for cut, (found, _, false) in zip(OPERATING_CUTS, counts)
    ]


def own_point(row: dict) -> dict:
    """The point of an operating curve (`row`, as results["operating"] holds it) at the model's own cut."""
    return min(row["points"], key=lambda p: abs(p["cut"] - row["cut"]))


def best_within(points: list[dict], false_per_room: float) -> dict | None:
    """The point of an operating curve with the most places found among those with at most
    `false_per_room` false skeletons per room (the highest cut among equals); None when none is."""
    within = [p for p in points if p["false_per_room"] <= false_per_room]
    return max(within, key=lambda p: (p["found"], p["cut"])) if within else None


def worst_room_figures(args, model, per_room: dict, test_rooms: list, files: list, task) -> None:
    """Plan views of the two generated test rooms where `model` errs most (`per_room`: its missed and false
    places per room, from the table's run)."""
    from affordcore.geometry.scene import load_cloud
    from affordcore.mapping.pipeline import map_affordances
    from affordcore.mapping.plots import plot_map

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
        f"{row['affordance']:17s} {row['learner']:13s} {row['rooms']:20s} P/R/F1 {row['precision']:.2f}/"
        f"{row['recall']:.2f}/{row['f1']:.2f} AP {row['ap']:.2f} places {row['places']} false/room "
        f"{row['false_per_room']:.1f} (score cut: {row['score_cut_places']}, "
        f"{row['score_cut_false_per_room']:.1f}) | loose F1 {row['loose_f1']:.2f} places "
        f"{row['loose_places']} false/room {row['loose_false_per_room']:.1f} ({row['train_seconds']:.0f} s)"
    )


def markdown(results: dict, args) -> str:
    paper = json.loads((ROOT / "affordcore" / "data" / "paper_results.json").read_text())["affordances"]
    split = results["split"]
    lines = [
        f"Command: `.venv/bin/python benchmarks/accuracy.py --rooms {args.rooms} --seed {args.seed} --test "
        f"{args.test} --validation {args.validation} --curve {args.curve} --learners {args.learners}"
        f"{f' --trained {args.trained}' if args.trained else ' --shipped' if args.shipped else ''}"
        f"{f' --unseen {args.unseen} --unseen-seed {args.unseen_seed}' if args.unseen else ''}`; "
        f"{len(split['train'])} training, {len(split['validation'])} validation, {len(split['test'])} "
        f"generated test rooms; {results['seconds'] / 60:.0f} min, peak RSS {results['peak_rss_gb']:.1f} GB, "
        f"{results['cores']} cores. Places: the model's place model at probability >= "
        f"{place_cuts(results)}; beside them the score cut of the models before (relative to the "
        "room's median, floored).",
        "",
        "| affordance | learner | rooms | pose P / R / F1 | AP | places found | within reach | "
        "false / room | score cut: places, false / room | loose: F1 | loose: places | loose: false / room | "
        "paper SSVM P / R / F1 |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['affordance']} | {r['learner']} | {r['rooms']} ({r['room_count']}) | "
            f"{r['precision']:.2f} / {r['recall']:.2f} / **{r['f1']:.2f}** | {r['ap']:.2f} | {r['places']} | "
            f"{r.get('within_reach', '-')} | {r['false_per_room']:.1f} | "
            f"{r['score_cut_places']}, {r['score_cut_false_per_room']:.1f} | "
            f"{r['loose_f1']:.2f} | {r['loose_places']} | {r['loose_false_per_room']:.1f} | "
            f"{paper.get(r['affordance'], {}).get('structured_svm', '-')} |"
        )
    lines += [
        "",
        "Reliability of the place probabilities (every candidate place of the rooms: mean predicted "
        "probability against the share that is a labelled place, per bin; `n` candidates):",
        "",
        "| affordance | rooms | "
        + " | ".join(f"{a:.1f}-{b:.1f}" for a, b in zip(RELIABILITY_BINS, RELIABILITY_BINS[1:]))
        + " |",
        "|---|---|" + "---|" * (len(RELIABILITY_BINS) - 1),
    ]
    for r in results["reliability"]:
        cells = {tuple(b["bin"]): b for b in r["bins"]}
        row = [
            (lambda b: f"{b['predicted']:.2f} / {b['observed']:.2f} (n {b['candidates']})" if b else "")(
                cells.get((float(a), float(b)))
            )
            for a, b in zip(RELIABILITY_BINS, RELIABILITY_BINS[1:])
        ]
        lines.append(f"| {r['affordance']} | {r['rooms']} | " + " | ".join(row) + " |")
    lines += operating_table(results["operating"])
    lines += [
        "",
        "Learning curve (generated test rooms"
        + ("; from the last training run, --shipped does not measure it):" if args.shipped else "):"),
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


def operating_table(rows: list[dict]) -> list[str]:
    """results.md's table of the operating curves: places found and false skeletons per room at a few place
    probabilities, and the most places any of OPERATING_CUTS finds with at most 1 false skeleton per room."""
    if not rows:
        return []
    lines = [
        "",
        "Operating curve of the place probability (`AFFORD_MAP__PLACE_PROBABILITY`): places found, false "
        "skeletons per room, at each probability; the model's own cut in the last column but one; the last, "
        "the most places found at any probability with at most 1 false skeleton per room (the "
        "targets' budget):",
        "",
        "| affordance | rooms | "
        + " | ".join(f"p >= {c}" for c in TABLE_CUTS)
        + " | own cut | most places, <= 1 false / room |",
        "|---|---|" + "---|" * (len(TABLE_CUTS) + 2),
    ]
    for r in rows:
        if not r["points"]:
            continue
        at = {p["cut"]: p for p in r["points"]}
        cells = [
            f"{p['found']}/{p['labelled']}, {p['false_per_room']:.1f}"
            for p in (at.get(c) for c in TABLE_CUTS)
            if p
        ]
        own = own_point(r)
        best = best_within(r["points"], 1.0)
        best_cell = (
            f"{best['found']}/{best['labelled']}, {best['false_per_room']:.1f} (p >= {best['cut']})"
            if best
            else "-"
        )
        lines.append(
            f"| {r['affordance']} | {r['rooms']} | "
            + " | ".join(cells)
            + f" | {r['cut']}: {own['found']}/{own['labelled']}, {own['false_per_room']:.1f} | {best_cell} |"
        )
    return lines


def _affordance_panels(rows: list[dict], height: float):
    """pyplot, a figure of one panel per affordance of `rows` (None when there is none) and its (affordance,
    axes) pairs."""
    from affordcore.mapping.plots import pyplot

    plt = pyplot()
    affordances = list(dict.fromkeys(r["affordance"] for r in rows))
    if not affordances:
        return plt, None, []
    figure, axes = plt.subplots(
        1, len(affordances), figsize=(4.6 * len(affordances), height), constrained_layout=True, squeeze=False
    )
    return plt, figure, list(zip(affordances, axes[0]))


def plot_operating(rows: list[dict], path: Path) -> None:
    """Place recall against false skeletons per room as the place probability a map asks for falls: one panel
    per affordance, the generated test rooms (black), each scan style (thin) and the real rooms (red); the
    model's own cut is circled, and the grey lines are the targets' budget of 1 false skeleton per room and
    their 0.9 of the places."""
    plt, figure, panels = _affordance_panels(rows, 4.4)
    if figure is None:
        return
    styles = dict.fromkeys(r["rooms"] for r in rows if r["rooms"].startswith("generated/"))
    colours = [
        c for k, c in enumerate(plt.get_cmap("tab10").colors) if k != 3
    ]  # tab10's red: the real rooms'
    palette = dict(zip(styles, colours))
    for affordance, ax in panels:
        ax.axvline(1.0, color="grey", lw=1, ls=":", label="1 false / room")
        ax.axhline(0.9, color="grey", lw=1, ls="-.", label="0.9 of the places")
        for r in rows:
            if r["affordance"] != affordance or not r["points"]:
                continue
            if r["rooms"] == "generated":
                look = {"color": "black", "lw": 2.0, "label": "generated (all styles)"}
            elif r["rooms"] == "real":
                look = {"color": "crimson", "lw": 2.0, "label": "real rooms"}
            elif r["rooms"].startswith("unseen") and "/" not in r["rooms"]:
                look = {"color": "dimgray", "lw": 2.0, "ls": "--", "label": r["rooms"]}
            elif r["rooms"] in palette:
                look = {
                    "color": palette[r["rooms"]],
                    "lw": 0.9,
                    "alpha": 0.8,
                    "label": r["rooms"].split("/", 1)[1],
                }
            else:
                continue  # a single real room: the real rooms' line has it
            false = [p["false_per_room"] for p in r["points"]]
            recall = [p["recall"] for p in r["points"]]
            ax.plot(false, recall, **{"ls": "-", **look})
            own = own_point(r)
            ax.plot(own["false_per_room"], own["recall"], "o", mfc="none", color=look["color"], ms=7)
        ax.set(
            xlim=(-0.05, 3.0),
            ylim=(-0.02, 1.02),
            xlabel="false skeletons per room",
            ylabel="share of labelled places found",
            title=f"{affordance} (circle: the model's cut)",
        )
        ax.legend(fontsize=7, loc="lower right")
    figure.savefig(path, dpi=110)
    plt.close(figure)


def plot_reliability(reliability_rows: list[dict], path: Path) -> None:
    """The reliability diagram: one panel per affordance, every generated test room (black) and the real rooms
    (red); each bin's dot is as large as its number of candidates, and the diagonal is perfect calibration.
    Per scan style: the table in results.md (too few candidates per style and bin for a readable line)."""
    plt, figure, panels = _affordance_panels(reliability_rows, 4.6)
    if figure is None:
        return
    for affordance, ax in panels:
        ax.plot([0, 1], [0, 1], color="grey", lw=1, ls=":", label="calibrated")
        for r in reliability_rows:
            if r["affordance"] != affordance or r["rooms"] not in ("generated", "real") or not r["bins"]:
                continue
            colour = "black" if r["rooms"] == "generated" else "crimson"
            predicted = [b["predicted"] for b in r["bins"]]
            observed = [b["observed"] for b in r["bins"]]
            counts = np.array([b["candidates"] for b in r["bins"]])
            ax.plot(predicted, observed, "-", color=colour, lw=1.2, alpha=0.7)
            ax.scatter(predicted, observed, s=12 + 6 * np.sqrt(counts), color=colour, label=r["rooms"])
            for x, y, n in zip(predicted, observed, counts):
                ax.annotate(
                    f"{n}", (x, y), textcoords="offset points", xytext=(5, -10), fontsize=7, color=colour
                )
        ax.set(
            xlim=(-0.02, 1.02),
            ylim=(-0.02, 1.02),
            xlabel="predicted probability of a place",
            ylabel="share that are labelled places",
            title=affordance,
        )
        ax.set_aspect("equal")
        ax.legend(fontsize=8, loc="upper left")
    figure.savefig(path, dpi=110)
    plt.close(figure)


def plot_curve(curve: list[dict], path: Path) -> None:
    from affordcore.mapping.plots import pyplot

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
