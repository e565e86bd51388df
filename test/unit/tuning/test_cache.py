"""``tuning/cache.py``: scores kept on disk for one context, refused for another."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from soc_estimator_ros.tuning.cache import ScoreCache, context_of, tuning_key


@pytest.fixture
def inputs(tmp_path: Path) -> tuple[Path, list[str]]:
    params = tmp_path / "pack.yaml"
    params.write_text("name: pack\n")
    bag = tmp_path / "bag_a"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("a\n")
    (bag / "bag_a.mcap").write_bytes(b"\x00\x01")
    csv = tmp_path / "b.csv"
    csv.write_text("time_s,current_a\n")
    return params, [str(bag), str(csv)]


def test_scores_come_back_as_written_inf_included(inputs, tmp_path):
    params, recs = inputs
    ctx = context_of("hybrid", params, recs, 0.3)
    path = tmp_path / "scores.jsonl"
    cache = ScoreCache(path, ctx)
    assert len(cache) == 0 and cache.get({"r": 0.1}) is None
    cache.put({"r": 0.1, "q_diag.0": 1e-9}, [1.5, math.inf])
    cache.put({"r": 0.3}, [2.0, 3.0])
    again = ScoreCache(path, ctx)
    assert len(again) == 2 and again.skipped == 0
    # The key is the values to 12 digits: 0.1 + 0.2 is the 0.3 written.
    np.testing.assert_array_equal(again.get({"r": 0.1 + 0.2}), [2.0, 3.0])
    np.testing.assert_array_equal(again.get({"q_diag.0": 1e-9, "r": 0.1}), [1.5, math.inf])
    with pytest.raises(ValueError, match="3 scores for 2 recordings"):
        again.put({"r": 1.0}, [1.0, 2.0, 3.0])


def test_a_cache_for_other_inputs_is_refused_naming_what_differs(inputs, tmp_path):
    params, recs = inputs
    path = tmp_path / "scores.jsonl"
    ScoreCache(path, context_of("hybrid", params, recs, 0.3)).put({"r": 0.1}, [1.0, 2.0])
    (Path(recs[0]) / "bag_a.mcap").write_bytes(b"\x00\x02")  # one byte of one bag
    with pytest.raises(ValueError, match=r"\(recordings_sha256 differ\)"):
        ScoreCache(path, context_of("hybrid", params, recs, 0.3))
    with pytest.raises(ValueError, match=r"estimator, recordings_sha256, wrong_start differ"):
        ScoreCache(path, context_of("t2rc_ukf", params, recs, 0.0))
    other = tmp_path / "other.jsonl"
    for text in (b"not json\n", b"\xff\xfe\x00binary"):
        other.write_bytes(text)
        with pytest.raises(ValueError, match=f"--cache {other}: not a soc_tune cache"):
            ScoreCache(other, context_of("hybrid", params, recs, 0.3))


def test_a_line_cut_short_by_a_stop_is_skipped_and_counted(inputs, tmp_path):
    params, recs = inputs
    ctx = context_of("hybrid", params, recs, 0.3)
    path = tmp_path / "scores.jsonl"
    cache = ScoreCache(path, ctx)
    cache.put({"r": 0.1}, [1.0, 2.0])
    cache.put({"r": 0.2}, [3.0, 4.0])
    text = path.read_text()
    path.write_text(text[: len(text) - 9])  # the last line loses its end, as a kill leaves it
    again = ScoreCache(path, ctx)
    assert (len(again), again.skipped) == (1, 1)
    assert again.get({"r": 0.2}) is None
    # A row of the wrong length (a hand edit) is skipped too, not used.
    with path.open("a") as fh:
        fh.write("\n" + json.dumps({"values": {"r": 0.5}, "scores": [1.0]}) + "\n")
    assert ScoreCache(path, ctx).skipped == 2


def test_tuning_key_ignores_order_and_the_thirteenth_digit():
    assert tuning_key({"a": 1.0, "b": 2.0}) == tuning_key({"b": 2.0, "a": 1.0 + 1e-15})
    assert tuning_key({"a": 1.0}) != tuning_key({"a": 1.0 + 1e-9})
