"""Screenshots of the recordings as a person first opens them: the real Rerun viewer, headless (Xvfb and
software Vulkan) and with a fresh viewer state, renders `afford demo`'s map.rrd and the three recordings of
a service run opened together (a generated living room streamed as depth frames through the router and
the assembler, features and inference services), to docs/figures/recording-demo.png and
docs/figures/recording-services.png.

    .venv/bin/python benchmarks/recording_screenshots.py [--out docs/figures]     # about 2 minutes

Needs Xvfb and a Vulkan driver (`bash bootstrap.sh test` installs them as root: xvfb mesa-vulkan-drivers
libegl1 libxkbcommon-x11-0 libvulkan1). tests/test_screenshots.py checks the demo's screenshot."""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
AFFORD = [sys.executable, "-m", "affordcli"]
WINDOW = (1600, 1000)  # the viewer's window, in points (the screenshot has twice as many pixels each way)
FIGURE_WIDTH = 1200  # px: the docs' copy, palette-quantised to stay small


class ViewerUnavailable(RuntimeError):
    """The viewer cannot run here (no Xvfb, no Vulkan driver): what a test skips on."""


@contextlib.contextmanager
def headless_display():
    """An Xvfb display of its own (the first free number from 90). Its screen is much larger than the
    viewer's window, so the pointer, which starts at the screen's centre, is off the window: no hover
    tooltip in the shot. Composite: without it the window stays black."""
    if shutil.which("Xvfb") is None:
        raise ViewerUnavailable("no Xvfb (apt-get install xvfb mesa-vulkan-drivers libegl1 libvulkan1 ...)")
    number = next(n for n in range(90, 200) if not Path(f"/tmp/.X{n}-lock").exists())
    width, height = 4 * WINDOW[0] + 200, 4 * WINDOW[1] + 200
    xvfb = subprocess.Popen(
        ["Xvfb", f":{number}", "-screen", "0", f"{width}x{height}x24", "-extension", "Composite"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        yield f":{number}"
    finally:
        xvfb.terminate()
        xvfb.wait(timeout=10)


def screenshot(recordings: list[Path], out: Path, display: str, timeout: float = 180) -> Path:
    """The viewer's first view of `recordings` (opened together) as `out`, full resolution; the viewer's
    state (layouts, last camera) in a fresh folder, as a new user has it."""
    with tempfile.TemporaryDirectory() as home:
        env = {
            **os.environ,
            "DISPLAY": display,
            "WGPU_BACKEND": "vulkan",
            "XDG_DATA_HOME": home,
            "XDG_CONFIG_HOME": home,
            "XDG_CACHE_HOME": home,
            "XDG_RUNTIME_DIR": home,
        }
        out.unlink(missing_ok=True)
        command = [sys.executable, "-m", "rerun", "--screenshot-to", str(out)]
        command += ["--window-size", f"{WINDOW[0]}x{WINDOW[1]}", *map(str, recordings)]
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=timeout)
    if not out.is_file():
        raise ViewerUnavailable(
            f"the viewer wrote no screenshot (exit {done.returncode}): {done.stderr[-800:]}"
        )
    return out


def figure(shot: Path, out: Path) -> Path:
    """A small copy for the docs: FIGURE_WIDTH wide, 256 colours (an octree keeps each affordance's)."""
    from PIL import Image

    image = Image.open(shot).convert("RGB")
    image = image.resize((FIGURE_WIDTH, round(image.height * FIGURE_WIDTH / image.width)), Image.LANCZOS)
    image.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(out, optimize=True)
    return out


def demo_recording(folder: Path) -> Path:
    done = subprocess.run(AFFORD + ["demo", "--out", str(folder), "-q"], capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(done.stderr)
    return folder / "map.rrd"


def service_recordings(folder: Path) -> list[Path]:
    """A router and the three services on loopback; a generated living room's 40 depth frames published
    with `afford publish` and the maps awaited with `afford watch`; the services' recordings."""
    from affordcore.synth.dataset import write_sequence
    from affordcore.synth.rooms import generate_room
    from services.launch import Stack

    rng = np.random.default_rng(3)
    sequence = folder / "living.sequence"  # the end-to-end test's room and walk (tests/conftest.py)
    write_sequence(generate_room("living", rng, "living-e2e"), rng, sequence, "depth", frames=120)
    with Stack(folder / "run", env={"AFFORD_SERVICE__MAX_LAG": "600"}) as stack:  # every frame registered
        connect = ["--connect", stack.endpoint, "--robot", stack.robot]
        watch = subprocess.Popen(
            AFFORD + ["watch", *connect, "--frames", "40", "--timeout", "300", "--out", str(folder / "maps")],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        subprocess.run(
            AFFORD + ["publish", str(sequence), *connect, "--rate", "30", "--step", "3", "-q"], check=True
        )
        _, said = watch.communicate(timeout=360)
        if watch.returncode != 0:  # a screenshot of a run without its maps shows nothing worth a figure
            sys.exit(f"afford watch exited {watch.returncode}: {said.strip()}")
    return sorted((folder / "run").glob("*.rrd"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as work, headless_display() as display:
        work = Path(work)
        for name, recordings in (
            ("demo", [demo_recording(work / "demo")]),
            ("services", service_recordings(work / "services")),
        ):
            shot = screenshot(recordings, work / f"{name}.png", display)
            print(figure(shot, args.out / f"recording-{name}.png"))


if __name__ == "__main__":
    main()
