"""Differential tests of the whole stream: hostile messages interleaved with a valid stream change no map, and
services killed with SIGKILL at random moments of it lose nothing.

The same valid stream runs into fresh stacks (tests/stream_fuzz.py): clean, and clean again (KISS-ICP's
run-to-run noise, measured first: none, the maps come out to the bit); with hostile messages at seeded random
points, on every input key, one at a time and in bursts, from several clients at once; and with services
killed at seeded random moments and started again. benchmarks/fuzz_stream.py runs the same longer."""

from __future__ import annotations

import numpy as np
import pytest
from stream_fuzz import AFFORDANCES, hostile_plan, hostile_pool, run_stream

pytestmark = pytest.mark.slow
FRAMES = 15  # every 3rd frame of the generated walk: the floor is in view after about ten
HOSTILE = 120  # interleaved in the fuzzed run


@pytest.fixture(scope="module")
def clean(generated_sequence, tmp_path_factory):
    outcome = run_stream(generated_sequence, tmp_path_factory.mktemp("clean"), FRAMES)
    assert outcome.frames == FRAMES and set(outcome.maps) == set(AFFORDANCES), outcome
    assert outcome.refused == {} and outcome.exited == {}
    return outcome


def _watches_took_the_maps_of(run, clean) -> None:
    """Both watches (started with the stream, and after it) took the maps of the whole stream."""
    assert len(run.watched) == 2 and all(w["done"] and w["refused"] is None for w in run.watched), run.watched
    for watched in run.watched:
        assert {name: watched[name] for name in AFFORDANCES} == {n: clean.maps[n][2] for n in AFFORDANCES}


def test_the_clean_stream_maps_the_same_to_the_bit_every_run(clean, generated_sequence, tmp_path):
    again = run_stream(generated_sequence, tmp_path, FRAMES)
    assert (again.cloud, again.maps) == (clean.cloud, clean.maps)
    np.testing.assert_array_equal(np.array(again.poses), np.array(clean.poses))
    _watches_took_the_maps_of(again, clean)


def test_hostile_messages_interleaved_in_a_stream_change_no_map_and_are_all_answered(
    clean, generated_sequence, tmp_path
):
    rng = np.random.default_rng(55)
    pool = hostile_pool(rng, per_key=60)
    assert {h.service for h in pool} == {"assembler", "features", "inference"} and any(h.late for h in pool)
    fuzzed = run_stream(generated_sequence, tmp_path, FRAMES, hostile_plan(rng, pool, FRAMES, HOSTILE))
    print(f"hostile sent {fuzzed.sent}, refusals seen {fuzzed.refused}")
    assert sum(fuzzed.sent.values()) == HOSTILE and len(fuzzed.sent) == 3, fuzzed.sent
    assert fuzzed.refused == fuzzed.sent, "every hostile message answered on its service's error key"
    assert fuzzed.exited == {}, "no service exited or was restarted"
    assert fuzzed.frames == FRAMES
    assert fuzzed.cloud == clean.cloud, "the assembler's map"
    assert fuzzed.maps == clean.maps, "every affordance's map, to the bit"
    _watches_took_the_maps_of(fuzzed, clean)


def test_features_and_inference_killed_at_random_moments_map_as_the_uninterrupted_stream(
    clean, generated_sequence, tmp_path
):
    """Each fetches the latest map or fields with a get when it starts again: its maps are those of the
    stream that was never interrupted, to the bit (one of the kills falls while the last map is made)."""
    rng = np.random.default_rng(57)
    frames = rng.choice(np.arange(6, FRAMES + 1), 2, replace=False)
    kills = {int(frames[0]): ("features", float(rng.uniform(0, 0.3))), FRAMES: ("inference", 0.1)}
    kills[int(frames[1])] = ("inference", float(rng.uniform(0, 0.3)))
    killed = run_stream(generated_sequence, tmp_path, FRAMES, kills=kills)
    print(f"kills {kills}")
    assert set(killed.exited) == {"features", "inference"} and set(killed.exited.values()) == {"restarted"}
    assert (killed.cloud, killed.maps) == (clean.cloud, clean.maps)
    _watches_took_the_maps_of(killed, clean)


def test_an_assembler_killed_mid_frame_loses_no_frame_and_maps_the_same_places(
    clean, generated_sequence, tmp_path
):
    """Killed while it registers a frame (no pose out yet), started again from its state folder: every frame
    is in the map (the one in hand sent again by the sensor, or refused as a repeat if journaled). A restored
    assembler registers against its global map, not KISS-ICP's own local map (that is not journaled: every
    frame's points), so its poses may differ from the uninterrupted stream's by a millimetre or two; the
    places are the same."""
    rng = np.random.default_rng(58)
    frame, delay = int(rng.integers(3, FRAMES - 2)), float(rng.uniform(0, 0.15))
    killed = run_stream(generated_sequence, tmp_path, FRAMES, kills={frame: ("assembler", delay)})
    assert killed.exited == {"assembler": "restarted"}
    assert killed.frames == FRAMES and len(killed.poses) >= FRAMES
    moved = max(np.abs(a[:3, 3] - b[:3, 3]).max() for a, b in zip(clean.poses, killed.poses[-FRAMES:]))
    print(f"killed at frame {frame} + {delay:.3f} s: poses moved up to {1000 * moved:.2f} mm")
    assert moved < 0.005
    for name in AFFORDANCES:
        got, want = np.array(killed.maps[name][2]), np.array(clean.maps[name][2])
        assert got.shape == want.shape, name
        if len(want):
            np.testing.assert_allclose(got[:, :3], want[:, :3], atol=0.05, err_msg=name)  # x, y, theta
    assert all(w["done"] and w["refused"] is None for w in killed.watched), killed.watched
