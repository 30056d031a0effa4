"""Differential fuzzing of the whole stream: hostile messages interleaved with a valid one change no map.

The same valid stream runs three times into fresh stacks: twice as it is (KISS-ICP's run-to-run noise,
measured first: none, the maps come out to the bit) and once with hostile messages at seeded random points, on
every input key, one at a time and in bursts, from several clients at once (tests/stream_fuzz.py). The fuzzed
run's maps must equal the clean ones to the bit, every hostile message must be answered on its service's error
key, no service may exit, and both watchers (started with the stream, and after it) must take the maps of the
whole stream as their answer. benchmarks/fuzz_stream.py runs the same with more messages and seeds."""

from __future__ import annotations

import numpy as np
import pytest
from stream_fuzz import AFFORDANCES, hostile_plan, hostile_pool, run_stream

pytestmark = pytest.mark.slow
FRAMES = 15  # every 3rd frame of the generated walk: the floor is in view after about ten
HOSTILE = 120  # interleaved in the fuzzed run


def test_hostile_messages_interleaved_in_a_stream_change_no_map_and_are_all_answered(
    generated_sequence, tmp_path
):
    clean = run_stream(generated_sequence, tmp_path / "clean", FRAMES)
    again = run_stream(generated_sequence, tmp_path / "again", FRAMES)
    assert clean.frames > 0 and set(clean.maps) == set(AFFORDANCES), clean
    assert (again.cloud, again.maps) == (clean.cloud, clean.maps), "the clean stream is not repeatable"

    rng = np.random.default_rng(55)
    pool = hostile_pool(rng, per_key=60)
    assert {h.service for h in pool} == {"assembler", "features", "inference"}
    fuzzed = run_stream(
        generated_sequence, tmp_path / "fuzzed", FRAMES, hostile_plan(rng, pool, FRAMES, HOSTILE)
    )
    print(f"hostile sent {fuzzed.sent}, refusals seen {fuzzed.refused}")
    assert sum(fuzzed.sent.values()) == HOSTILE and len(fuzzed.sent) == 3, fuzzed.sent
    assert fuzzed.refused == fuzzed.sent, "every hostile message answered on its service's error key"
    assert clean.refused == {}
    assert fuzzed.exited == {} and clean.exited == {}, "no service exited or was restarted"
    assert fuzzed.frames == clean.frames == FRAMES
    assert fuzzed.cloud == clean.cloud, "the assembler's map"
    assert fuzzed.maps == clean.maps, "every affordance's map, to the bit"
    # both watches took the maps of the whole stream, as the clean run's watches did
    for run in (clean, fuzzed):
        assert len(run.watched) == 2 and all(w["done"] and w["refused"] is None for w in run.watched), (
            run.watched
        )
        for watched in run.watched:
            assert {name: watched[name] for name in AFFORDANCES} == {n: clean.maps[n][2] for n in AFFORDANCES}
