"""Skeleton commands: the affordance types, one skeleton file each (`skeletons list | show | derive`)."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import UserError, output_file, output_folder, require_extra, user_errors

app = typer.Typer()
skeletons_app = typer.Typer(help="The virtual skeletons, one per affordance type.", no_args_is_help=True)
app.add_typer(skeletons_app, name="skeletons", rich_help_panel="Skeletons")


@skeletons_app.command("list")
def skeletons_list() -> None:
    """List the affordance types (one skeleton file each)."""
    with user_errors():
        from affordcore.geometry.skeleton import all_skeletons
        from affordcore.settings import Settings

        for skeleton in all_skeletons(Settings().skeleton_dirs):
            typer.echo(f"{skeleton.affordance:<20} torso {skeleton.torso_height:.2f} m  {skeleton.source}")
            if skeleton.description:
                typer.echo(f"{'':<20} {skeleton.description}")


@skeletons_app.command("show")
def skeletons_show(
    out: Path = typer.Option(Path("skeletons.png"), "--out", help="PNG to write"),
    affordance: list[str] | None = typer.Option(
        None, "--affordance", "-a", help="only these (repeatable); default: all"
    ),
) -> None:
    """Draw the skeletons (front and side views on the floor) as one PNG."""
    with user_errors():
        from affordcore.geometry.skeleton import all_skeletons, get_skeleton
        from affordcore.mapping.plots import plot_skeletons
        from affordcore.settings import Settings

        output_file(out)
        folders = Settings().skeleton_dirs
        skeletons = (
            [get_skeleton(name, folders) for name in affordance] if affordance else all_skeletons(folders)
        )
        typer.echo(f"wrote {plot_skeletons(skeletons, out)}")


@skeletons_app.command("derive")
def skeletons_derive(
    data: Path | None = typer.Option(
        None, "--data", help="MSR DailyActivity3D skeletons (.npz); default: ../shared/data/skeletons/..."
    ),
    out: Path | None = typer.Option(
        None, "--out", help="folder for <affordance>.json; default: the package's skeleton folder"
    ),
    png: Path | None = typer.Option(None, "--png", help="also draw the models and their clusters (PNG)"),
) -> None:
    """Derive the skeleton files from real Kinect skeletons: filter, canonicalise, K-means, medoid, adult
    scale."""
    with user_errors():
        from affordcore.geometry.skeleton import BUILTIN_DIR
        from affordcore.geometry.skeleton_models import default_data_path, derive, write_skeleton
        from affordcore.mapping.plots import plot_skeletons

        require_extra("learn")  # K-means and silhouettes: scikit-learn
        output_folder(
            out or BUILTIN_DIR, "--out" if out else "--out (default: the package's skeleton folder)"
        )
        if png:
            output_file(png, "--png")
        data = data or default_data_path()
        if not data.is_file():
            raise UserError(
                f"{data}: skeleton data set not found (pass --data, see ../shared/data/README.md)"
            )
        result = derive(data)
        _print_derivation(result)
        for skeleton in result.skeletons:
            typer.echo(f"wrote {write_skeleton(skeleton, out or BUILTIN_DIR)}")
        if png:
            typer.echo(f"wrote {plot_skeletons(result.skeletons, png, result.members)}")


def _print_derivation(result) -> None:
    """The frames each filter kept, the scale, and each model's cluster."""
    groups = list(result.filters["loaded"])
    typer.echo(f"{'frames':<22}" + "".join(f"{g:>18}" for g in groups))
    for name, row in result.filters.items():
        label = name if name in ("loaded", "kept") else f"- {name}"
        typer.echo(f"{label:<22}" + "".join(f"{row[g]:>18,}" for g in groups))
    scale = result.scale
    typer.echo(
        f"scale: standing head-to-foot span {scale['median_span']:.3f} m (median) -> "
        f"{scale['target_span']:.3f} m "
        f"(x{scale['factor']:.3f}; per subject x{scale['subject_min']:.3f} to x{scale['subject_max']:.3f}); "
        f"body: median bone lengths of {scale['body_frames']} standing frames"
    )
    for skeleton in result.skeletons:
        info = result.clusters[skeleton.affordance]
        turns = info["forearm_turns"]
        typer.echo(
            f"{skeleton.affordance}: {info['frames']} frames, K={info['k']} "
            f"(silhouette {info['silhouettes'][info['k']]:.3f}), sizes {info['sizes']}, chose cluster "
            f"{info['chosen']} ({info['sizes'][info['chosen']]} frames), medoid {info['medoid']}, "
            f"torso {skeleton.torso_height:.3f} m"
            + (f", forearms turned {turns[0]:.0f} and {turns[1]:.0f} degrees" if turns else "")
        )
