"""`afford map`'s last stage in worker processes (`outputs.map_and_write`) writes what one process writes: the
same JSON and PNG bytes, the same recording entities, maps back in the models' order."""

from __future__ import annotations

import sys

import pytest

from affordcore.example import example_room
from affordcore.geometry.features import FeatureLayout
from affordcore.learn.model import choose_models
from affordcore.mapping.outputs import map_and_write, write_map_outputs
from affordcore.mapping.pipeline import map_affordances, prepare_scene
from affordcore.mapping.recording import recorded_entities
from affordcore.settings import Settings


@pytest.fixture(scope="module")
def room():
    settings = Settings()
    scene = prepare_scene(example_room(), settings, "none")
    models = choose_models([], [], FeatureLayout.from_settings(settings))
    return scene, models, settings


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only")
def test_workers_write_what_one_process_writes(room, tmp_path):
    scene, models, settings = room
    models = models[:2]  # two workers: enough to show the order and the bytes
    serial = map_affordances(scene.fields, scene.layout, models, settings)
    write_map_outputs(scene, serial, models, tmp_path / "one", tmp_path / "one" / "map.rrd")
    heard, timings = [], {}
    maps, written = map_and_write(
        scene,
        models,
        settings,
        tmp_path / "workers",
        tmp_path / "workers" / "map.rrd",
        workers=len(models),
        on_map=lambda affordance, _: heard.append(affordance),
        timings=timings,
    )
    assert list(maps) == [m.affordance for m in models] == list(serial)
    assert sorted(heard) == sorted(maps)
    assert [p.name for p in written] == [
        name for m in models for name in (f"{m.affordance}.json", f"{m.affordance}.png")
    ] + ["map.rrd"]
    for path in written[:-1]:
        assert path.read_bytes() == (tmp_path / "one" / path.name).read_bytes(), path.name
    assert recorded_entities(written[-1]) == recorded_entities(tmp_path / "one" / "map.rrd")
    assert {f"score + map {m.affordance}" for m in models} <= set(timings)


def test_one_process_and_no_recording(room, tmp_path):
    scene, models, settings = room
    maps, written = map_and_write(scene, models[:1], settings, tmp_path, None, workers=1)
    assert list(maps) == [models[0].affordance]
    assert [p.name for p in written] == [f"{models[0].affordance}.json", f"{models[0].affordance}.png"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only")
def test_an_error_writing_a_map_is_raised_naming_the_map(room, tmp_path, monkeypatch):
    """Each map is drawn by a process forked from the writer: what goes wrong there reaches the caller."""
    from affordcore.mapping import outputs

    scene, models, settings = room

    def broken(points, world_from_input, amap, *rest):
        raise OSError(f"no room left for {amap.affordance}")

    monkeypatch.setattr(outputs, "_json_and_png", broken)  # before the writer is forked: it inherits it
    first = models[0].affordance
    with pytest.raises(RuntimeError, match=f"writing the {first} map: OSError.'no room left for {first}'"):
        map_and_write(scene, models[:2], settings, tmp_path, tmp_path / "map.rrd", workers=2)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the writer is forked on Linux only")
def test_the_room_is_handed_to_the_writer_without_waiting_for_it(room, tmp_path, monkeypatch):
    """The writer reads the room only once its imports are done; the command computes the fields
    meanwhile, so handing the room over (megabytes through a 64 KB pipe) must not wait for the writer.
    Closed early (an error before the maps), the writer is ended and nothing hangs."""
    import threading
    import time

    from affordcore.mapping import outputs

    def never_reads(connection, *outputs_wanted):
        time.sleep(600)

    monkeypatch.setattr(outputs, "_writer_main", never_reads)
    scene = room[0]
    assert scene.cloud.points.nbytes > 1 << 20
    writer = outputs.OutputWriter()
    handed = threading.Event()

    def hand_over():
        writer.start_scene(scene, ["sitting-working"], tmp_path, None)
        handed.set()

    threading.Thread(target=hand_over, daemon=True).start()
    assert handed.wait(60), "start_scene waited for the writer to read the room"
    writer.close()
    assert not writer._process.is_alive()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the writer is forked on Linux only")
def test_a_writer_closed_before_it_finished_is_ended_not_waited_for(monkeypatch):
    """A command that fails before its maps (an empty file, a cloud without a floor) closes its writer
    before `finish`: the writer, still importing matplotlib and rerun, is killed, not waited for (the error
    came seconds late). Here the writer would end by itself after 3 s; it must not get to."""
    import signal
    import time

    from affordcore.mapping import outputs

    monkeypatch.setattr(outputs, "_writer_main", lambda connection, *outputs_wanted: time.sleep(3))
    with pytest.raises(ValueError, match="empty file"), outputs.OutputWriter() as writer:
        raise ValueError("an empty file")
    assert writer._process.exitcode == -signal.SIGKILL


def test_a_plan_shows_the_room_under_its_ceiling():
    """A laser scan's ceiling is a third of its points: the plan's highest point per cell is taken under
    `CEILING_CUT`, so a table shows at its height and the floor around it at the floor's, not all ceiling;
    the plan still spans the whole cloud."""
    import numpy as np

    from affordcore.mapping.plots import CEILING_CUT, plan_heights

    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(0, 4, (20_000, 2)), np.zeros(20_000)])
    table = np.column_stack([rng.uniform(1, 2, (2_000, 2)), np.full(2_000, 0.75)])
    ceiling = np.column_stack([rng.uniform(-0.5, 4.5, (20_000, 2)), np.full(20_000, 2.6)])
    assert CEILING_CUT < 2.6
    top, corner = plan_heights(np.concatenate([floor, table, ceiling]), cell=0.25)
    assert np.allclose(corner, [-0.5, -0.5], atol=0.01) and top.shape == (21, 21)  # the ceiling's extent
    cells = corner + (np.indices(top.shape).transpose(1, 2, 0) + 0.5) * 0.25
    on_table = ((cells > 1.1) & (cells < 1.9)).all(axis=2)
    on_floor = ((cells > 0.1) & (cells < 3.9)).all(axis=2) & ~((cells > 0.9) & (cells < 2.1)).all(axis=2)
    assert np.allclose(top[on_table], 0.75) and np.allclose(top[on_floor], 0.0)
    assert np.isnan(top[0]).all()  # beyond the walls only ceiling: nothing under it to show


@pytest.mark.parametrize("stretch", [(1.0, 1.0), (1.0, 0.25), (0.3, 1.0)], ids=["square", "wide", "tall"])
def test_a_map_plan_keeps_its_text_inside_the_figure_and_its_colour_bar_beside_the_plan(
    room, tmp_path, monkeypatch, stretch
):
    """The plan figure is laid out by hand (`plots._plan_figure`), not by matplotlib's constrained layout: for
    a room as deep as wide, four times as wide and three times as deep, every text (title, ticks, axis and
    colour-bar labels, legend) lies inside the figure, and the colour bar stands right of the plan, apart."""
    import matplotlib.pyplot as plt
    import numpy as np

    from affordcore.mapping.plots import plot_map

    scene, models, settings = room
    amap = map_affordances(scene.fields, scene.layout, models[:1], settings)[models[0].affordance]
    assert amap.confidence.max() > amap.threshold  # the colour bar is drawn
    figures = []
    monkeypatch.setattr(plt, "close", lambda figure: figures.append(figure))
    points = scene.cloud.points * np.array([*stretch, 1.0])
    plot_map(points, amap, tmp_path / "plan.png")
    (figure,) = figures
    renderer = figure.canvas.get_renderer()
    drawn = figure.get_tightbbox(renderer).transformed(figure.dpi_scale_trans)  # in pixels, what was drawn
    assert drawn.x0 >= -1 and drawn.y0 >= -1, drawn
    assert drawn.x1 <= figure.bbox.x1 + 1 and drawn.y1 <= figure.bbox.y1 + 1, (drawn, figure.bbox)
    plan, bar = figure.axes[:2]
    plan_box, bar_box = plan.get_window_extent(renderer), bar.get_window_extent(renderer)
    assert bar_box.x0 > plan_box.x1 and not plan_box.overlaps(bar_box)
    plt.close(figure)
