"""Every figure the project draws (matplotlib on the Agg backend, no screen needed): fields, maps, labels,
skeletons and the evaluation's curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry.fields import SceneFields
from ..geometry.grid import PoseGrid
from ..geometry.skeleton import BONE_ENDS, BONES, Skeleton, skeleton_files
from ..labels import GroundTruth, LabelSet, affordance_colours

# m above the floor: a plan shows the room under the points above this, and so does the recording's view from
# above: a ceiling (a third of a laser scan's points) or a lamp would be the highest point of every cell
CEILING_CUT = 2.0


def pyplot():
    """matplotlib's pyplot on the Agg backend: every figure here goes to a file, no screen needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def place_summary(amap) -> str:
    """What the map kept, and what a lower probability would add: '3 places (probability >= 0.30; +2 at
    >= 0.1)'."""
    from .maps import UNSURE_PROBABILITY

    count = len(amap.skeletons)
    places = f"{count} place" + ("" if count == 1 else "s")
    if not np.isfinite(amap.place_probability):
        return places
    more = f"; +{amap.unsure_places} at >= {UNSURE_PROBABILITY:g}" if amap.unsure_places else ""
    return f"{places} (probability >= {amap.place_probability:.2f}{more})"


def plot_fields(fields: SceneFields, path: str | Path, slice_height: float = 0.45) -> Path:
    """Plan views of a room's fields: the height of the highest occupied voxel, and the distance field at
    ``slice_height`` (seat height by default), with the floor footprint the pose grid covers."""
    plt = pyplot()

    lattice = fields.lattice
    z = lattice.origin[2] + np.arange(lattice.shape[2]) * lattice.resolution
    occupied = fields.occupancy > 0.5
    top = np.where(occupied.any(axis=2), z[np.argmax(np.where(occupied, z, -np.inf), axis=2)], np.nan)
    k = int(np.clip(round((slice_height - lattice.origin[2]) / lattice.resolution), 0, lattice.shape[2] - 1))
    half = lattice.resolution / 2
    extent = (
        lattice.origin[0] - half,
        lattice.upper[0] + half,
        lattice.origin[1] - half,
        lattice.upper[1] + half,
    )
    x0, y0, x1, y1 = fields.footprint

    figure, axes = plt.subplots(1, 2, figsize=(12, 5.5), constrained_layout=True)
    panels = [
        (top, "viridis", "height of the highest occupied voxel (m)"),
        (fields.distance[:, :, k], "magma", f"distance to the nearest surface at z = {z[k]:.2f} m (m)"),
    ]
    for axis, (image, cmap, title) in zip(axes, panels):
        shown = axis.imshow(image.T, origin="lower", extent=extent, cmap=cmap, interpolation="nearest")
        axis.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="cyan", lw=1.2, ls="--"))
        axis.set_title(title, fontsize=10)
        axis.set_xlabel("x (m)")
        axis.set_ylabel("y (m)")
        axis.set_aspect("equal")
        figure.colorbar(shown, ax=axis, shrink=0.8)
    figure.suptitle(
        f"voxel fields, {lattice.resolution * 100:.0f} cm voxels; dashed: floor footprint of the pose grid"
    )
    path = Path(path)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def plan_heights(points: np.ndarray, cell: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """The cloud seen from above: the highest point's height up to `CEILING_CUT` per `cell` square (NaN where
    there is none), (nx, ny), and the (x, y) of the first cell's corner (the whole cloud's extent). One pass
    over the points; `plot_map` of several maps of one room can share it."""
    low, high = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    points = points[points[:, 2] <= CEILING_CUT]
    shape = np.ceil((high - low) / cell).astype(int) + 1
    index = np.floor((points[:, :2] - low) / cell).astype(int)
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (index[:, 0], index[:, 1]), points[:, 2])  # defined for repeated cells, as = is not
    top[np.isinf(top)] = np.nan
    return top, low


# the plan figure's frame, in inches: its width, the margins around the plan and the colour bar right of it
_PLAN_FIGURE_WIDTH, _PLAN_LEFT, _PLAN_RIGHT, _PLAN_BOTTOM, _PLAN_TOP = 9.0, 0.75, 1.6, 0.55, 0.6
_BAR_GAP, _BAR_WIDTH, _BAR_SHARE = 0.2, 0.18, 0.7


def _plan_figure(plt, aspect: float):
    """(figure, the plan's axes, the colour bar's axes) of a map's plan view for a room `aspect` (y span
    over x span) times as deep as it is wide: the plan spans the figure's width less its margins, and the
    figure is as tall as the plan at that width (for a room at least 0.4 times as deep as wide: a narrower
    one is centred in that height, which the colour bar and its label need). Laid out here, not by
    matplotlib's constrained layout, which draws every figure twice to measure it (docs/maps.md, "Speed",
    has what that cost)."""
    width = _PLAN_FIGURE_WIDTH - _PLAN_LEFT - _PLAN_RIGHT
    plan_height = width * max(0.4, aspect)
    w, h = _PLAN_FIGURE_WIDTH, plan_height + _PLAN_BOTTOM + _PLAN_TOP
    figure = plt.figure(figsize=(w, h))
    ax = figure.add_axes((_PLAN_LEFT / w, _PLAN_BOTTOM / h, width / w, plan_height / h))
    ax.set_anchor("E")  # labels beyond the cloud make the plan narrower than its box: keep it by the bar
    bar_height = _BAR_SHARE * plan_height
    bar_bottom = _PLAN_BOTTOM + (plan_height - bar_height) / 2
    bar = figure.add_axes(
        ((_PLAN_LEFT + width + _BAR_GAP) / w, bar_bottom / h, _BAR_WIDTH / w, bar_height / h)
    )
    return figure, ax, bar


def plot_map(
    points: np.ndarray,
    amap,
    path: str | Path,
    cell: float = 0.05,
    labels=None,
    plan: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """Plan view of one affordance map: the cloud from above (the highest point per 5 cm cell, darker =
    higher), the confidence map as filled contours above the model's threshold, and each skeleton of the
    skeleton map as a dot with an arrow along its facing, labelled with its score. Given a `LabelSet`, the
    affordance's ground-truth labels are drawn too (orange, with their facing). `plan`: the cloud's
    `plan_heights` at `cell`, when already computed (one room, several maps)."""
    plt = pyplot()

    grid = amap.grid
    top, low = plan if plan is not None else plan_heights(points, cell)
    shape = top.shape
    figure, ax, bar = _plan_figure(plt, shape[1] / shape[0])
    ax.imshow(
        top.T,
        origin="lower",
        extent=(low[0], low[0] + shape[0] * cell, low[1], low[1] + shape[1] * cell),
        cmap="Greys",
        vmin=-0.5,
        vmax=2.5,
        interpolation="nearest",
    )
    confidence = amap.confidence.T  # rows y, columns x
    top = float(np.max(confidence))
    if top > amap.threshold:
        levels = np.linspace(amap.threshold, top, 8)
        filled = ax.contourf(grid.x, grid.y, confidence, levels=levels, cmap="viridis", alpha=0.55)
        figure.colorbar(filled, cax=bar, label="decision value (above the model's threshold)")
    else:
        bar.set_visible(False)
    for (x, y, _, theta, _), text in zip(amap.skeletons, amap.place_labels()):
        ax.plot(x, y, "o", color="crimson", ms=6)
        ax.annotate(
            "",
            (x + 0.35 * np.cos(theta), y + 0.35 * np.sin(theta)),
            (x, y),
            arrowprops={"arrowstyle": "->", "color": "crimson", "lw": 1.6},
        )
        ax.text(x, y - 0.18, text, color="crimson", fontsize=7, ha="center", va="top")
    for label in labels.of(amap.affordance) if labels is not None else []:
        ends = np.array([label.at] if label.at is not None else [label.start, label.end])
        ax.plot(ends[:, 0], ends[:, 1], "-o", color="darkorange", lw=3, ms=4, alpha=0.8)
        middle = ends.mean(axis=0)
        ax.annotate(
            "",
            middle + 0.3 * np.array([np.cos(label.facing), np.sin(label.facing)]),
            middle,
            arrowprops={"arrowstyle": "->", "color": "darkorange", "lw": 1.6},
        )
    _draw_views(ax, amap.next_views)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    positives = f"{len(amap.positives):,} poses above the threshold"
    # over the figure, not the plan: a tall room's plan is narrower than the title
    figure.suptitle(f"{amap.affordance}: {place_summary(amap)}, {positives}")
    if len(amap.skeletons):
        ax.plot([], [], "o", color="crimson", label="place (p: probability a person can use it)")
    if labels is not None and labels.of(amap.affordance):
        ax.plot([], [], "-o", color="darkorange", lw=3, ms=4, label="labelled place (the room's labels)")
    if amap.next_views:
        ax.plot([], [], "s", color="royalblue", label="next view (its number, gain in bits)")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=7)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return Path(path)


def _draw_views(ax, views: list) -> None:
    """Each suggested view: the camera (a square), its field of view as two rays of a metre, its rank and
    gain, and a dotted line to each of the candidate places it would settle most."""
    from .next_views import DRAWN_LOOKS

    for rank, view in enumerate(views, 1):
        ax.plot(view.x, view.y, "s", color="royalblue", ms=6)
        for side in (-1, 1):
            edge = view.heading + side * np.radians(29)
            ax.plot([view.x, view.x + np.cos(edge)], [view.y, view.y + np.sin(edge)], color="royalblue", lw=1)
        for x, y, _ in view.looks_at[:DRAWN_LOOKS]:
            ax.plot([view.x, x], [view.y, y], ":", color="royalblue", lw=0.8)
        ax.text(view.x, view.y + 0.15, f"{rank}: {view.gain:.2f}", color="royalblue", fontsize=7, ha="center")


def plot_labels(
    points: np.ndarray,
    labels: LabelSet,
    path: str | Path,
    grid: PoseGrid | None = None,
    ground_truth: dict[str, GroundTruth] | None = None,
    max_points: int = 200_000,
) -> Path:
    """Top view of a room: the cloud up to `CEILING_CUT` coloured by height, each label as its segment or
    point in its affordance's colour with arrows along ``facing``, unlabelled regions hatched, and optionally
    the grid's footprint (dashed) and the (x, y) cells that are positive at some theta (shaded)."""
    plt = pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon

    ground_truth = ground_truth or {}
    points = np.asarray(points, dtype=np.float64)
    points = points[points[:, 2] <= CEILING_CUT]
    if len(points) > max_points:
        points = points[np.random.default_rng(0).choice(len(points), max_points, replace=False)]
    points = points[np.argsort(points[:, 2])]  # higher points drawn last: what a view from above sees
    # the built-in types take part so that an affordance has the same colour in every room's plot
    colours = affordance_colours(set(labels.affordances) | set(ground_truth) | set(skeleton_files()))

    span = np.ptp(points[:, :2], axis=0) if len(points) else np.ones(2)
    scale = 10 / max(span.max(), 1.0)
    figure, axis = plt.subplots(
        figsize=(max(7.0, span[0] * scale + 2.5), max(5.0, span[1] * scale + 2.5)), layout="constrained"
    )
    shown = axis.scatter(
        points[:, 0],
        points[:, 1],
        c=points[:, 2],
        s=0.4,
        cmap="Greys",
        vmin=-0.8,
        vmax=max(2.0, float(np.percentile(points[:, 2], 99))) if len(points) else 2.0,
        linewidths=0,
        rasterized=True,
    )
    figure.colorbar(shown, ax=axis, shrink=0.7, label="height of the point (m)")
    handles = []
    for name, truth in sorted(ground_truth.items()):
        cells = truth.positive.any(axis=0)
        if not cells.any():
            continue
        image = np.zeros((*cells.shape, 4))
        image[cells] = (*colours[name][:3], 0.45)
        axis.imshow(
            image.transpose(1, 0, 2),
            origin="lower",
            interpolation="nearest",
            zorder=2,
            extent=_extent(truth.grid),
        )
        handles.append(
            Patch(
                color=colours[name], alpha=0.45, label=f"{name}: positive cells ({truth.counts()[0]:,} poses)"
            )
        )
    if grid is not None:
        x0, x1, y0, y1 = _extent(grid)
        axis.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="tab:cyan", ls="--", lw=1))
        handles.append(Line2D([], [], color="tab:cyan", ls="--", label="pose grid footprint"))
    for region in labels.unlabelled_regions:
        axis.add_patch(Polygon(region.polygon, fill=False, hatch="///", ec="dimgray", lw=1, zorder=3))
    if labels.unlabelled_regions:
        handles.append(Patch(fill=False, hatch="///", ec="dimgray", label="unlabelled region (not scored)"))
    arrow = 0.35
    for label in labels.labels:
        colour = colours[label.affordance]
        if label.at is not None:
            bases = np.array([label.at])
            axis.plot(*label.at, "o", ms=8, color=colour, mec="black", mew=0.8, zorder=5)
        else:
            ends = np.array([label.start, label.end])
            axis.plot(*ends.T, "-", lw=4, color=colour, solid_capstyle="round", zorder=5)
            axis.plot(*ends.T, "-", lw=0.8, color="black", zorder=5)
            bases = ends[0] + np.linspace(0, 1, 3)[:, None] * (ends[1] - ends[0])
        for base in bases:
            axis.annotate(
                "",
                base + arrow * np.array([np.cos(label.facing), np.sin(label.facing)]),
                base,
                arrowprops=dict(arrowstyle="-|>", color=colour, lw=2, mutation_scale=14),
                zorder=6,
            )
    for name in labels.affordances:
        count = len(labels.of(name))
        handles.append(
            Line2D(
                [],
                [],
                color=colours[name],
                lw=4,
                marker="o",
                mec="black",
                label=f"{name}: {count} label{'s' * (count != 1)} (arrows: facing)",
            )
        )
    figure.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=9, frameon=False)
    axis.set_aspect("equal")
    axis.margins(0.03)
    axis.set_xlabel("x (m)")
    axis.set_ylabel("y (m)")
    axis.grid(alpha=0.25)
    axis.set_title(f"{labels.scene}\n{labels.cloud}: labels over the cloud seen from above", fontsize=10)
    path = Path(path)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def _extent(grid: PoseGrid) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1): the outer edges of the grid's cells."""
    half = (grid.step if np.isfinite(grid.step) else 0.1) / 2
    return (grid.x[0] - half, grid.x[-1] + half, grid.y[0] - half, grid.y[-1] + half)


def plot_skeletons(
    skeletons: list[Skeleton],
    path: str | Path,
    members: dict[str, np.ndarray] | None = None,
    max_members: int = 150,
) -> Path:
    """One row per skeleton: front (y-z, seen from the front) and side (x-z, seen from its right) views
    standing on the floor, left bones blue and right red, and faintly up to ``max_members`` frames of its
    cluster (each with its own proportions, at the model's torso height). One PNG."""
    plt = pyplot()
    from matplotlib.collections import LineCollection

    def segments(joints: np.ndarray, h: int, lift: float) -> np.ndarray:
        placed = joints[..., [h, 2]] + [0.0, lift]
        return np.stack([placed[..., BONE_ENDS[:, 0], :], placed[..., BONE_ENDS[:, 1], :]], axis=-2).reshape(
            -1, 2, 2
        )

    colours = ["tab:blue" if "L_" in a + b else "tab:red" if "R_" in a + b else "k" for a, b in BONES]
    figure, axes = plt.subplots(
        len(skeletons), 2, figsize=(7.5, 4.2 * len(skeletons)), squeeze=False, constrained_layout=True
    )
    for row, skeleton in zip(axes, skeletons):
        crowd = (members or {}).get(skeleton.affordance, np.empty((0, 15, 3)))
        shown = (
            crowd[np.unique(np.linspace(0, len(crowd) - 1, max_members).astype(int))] if len(crowd) else crowd
        )
        note = f"\n(grey: {len(shown)} of the cluster's {len(crowd)} frames)" if len(crowd) else ""
        for axis, (h, view) in zip(row, [(1, "front, y-z"), (0, "side, x-z")]):
            lift = skeleton.torso_height
            axis.add_collection(LineCollection(segments(shown, h, lift), colors="0.5", lw=0.5, alpha=0.08))
            axis.add_collection(LineCollection(segments(skeleton.joints, h, lift), colors=colours, lw=2.5))
            axis.plot(
                skeleton.joints[:, h], skeleton.joints[:, 2] + skeleton.torso_height, "o", color="k", ms=3
            )
            axis.axhline(0.0, color="saddlebrown", lw=2)
            axis.set(
                xlim=(-0.7, 0.7) if h else (-0.5, 0.9),
                ylim=(-0.05, 1.9),
                aspect="equal",
                xlabel=f"{'xy'[h]} (m)",
                ylabel="z (m), floor at 0",
            )
            axis.set_title(f"{skeleton.affordance} ({view}){note}", fontsize=9)
            axis.grid(alpha=0.3)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def plot_imbalance(evaluation, path: Path) -> None:
    """F1 on the test rooms against the training imbalance, per affordance and learner (an `Evaluation`)."""
    plt = pyplot()

    sweep = evaluation.sweep()
    affordances = list(dict.fromkeys(o.affordance for o in evaluation.outcomes))
    fig, axes = plt.subplots(
        1, len(affordances), figsize=(5 * len(affordances), 4), squeeze=False, sharey=True
    )
    for ax, affordance in zip(axes[0], affordances):
        runs = [o for o in sweep if o.affordance == affordance]
        for learner in dict.fromkeys(o.learner for o in runs):
            points = sorted((o.train_ratio, o.f1) for o in runs if o.learner == learner)
            ax.plot(*zip(*points), marker="o", label=learner)
        ax.set_xscale("log", base=2)
        ax.set_title(affordance)
        ax.set_xlabel("negatives per positive in training (rightmost: all data)")
        ax.grid(alpha=0.3)
    _save(
        fig, axes, "F1 on the test rooms", "Imbalance test: F1 against the training imbalance (fold 1)", path
    )


def plot_ssvm_iterations(evaluation, path: Path) -> None:
    """The structured SVM's training and validation F1 per cutting-plane iteration (an `Evaluation`)."""
    plt = pyplot()

    runs = [o for o in evaluation.outcomes if o.learner == "ssvm" and o.fold == 0 and not o.sweep]
    fig, axes = plt.subplots(
        1, max(1, len(runs)), figsize=(5 * max(1, len(runs)), 4), squeeze=False, sharey=True
    )
    for ax, run in zip(axes[0], runs):
        train_f1, validation_f1 = run.report["train_f1"], run.report["validation_f1"]
        steps = np.arange(1, len(train_f1) + 1)
        ax.plot(steps, train_f1, label="training rooms")
        ax.plot(steps, validation_f1, label="validation rooms")
        ax.axvline(run.report["best_iteration"], color="grey", ls="--", label="kept (best on validation)")
        ax.set_title(run.affordance)
        ax.set_xlabel("cutting-plane iteration")
        ax.grid(alpha=0.3)
    if not runs:
        axes[0][0].text(0.5, 0.5, "the structured SVM was not evaluated", ha="center", va="center")
    _save(fig, axes, "F1", "Structured SVM: F1 per iteration (fold 1)", path)


def _save(fig, axes, ylabel: str, title: str, path: Path) -> None:
    """One row of panels: the y label on the first, the legend on the last, the title over all."""
    axes[0][0].set_ylabel(ylabel)
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    pyplot().close(fig)
