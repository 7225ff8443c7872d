"""core.distances: pairwise distances over frames, truth, known distances, truth matching."""
from __future__ import annotations

import math

import numpy as np
import pytest

from eye_in_hand.core.distances import (
    apply_known_distances,
    distance_table,
    match_truth,
    pairwise_distances,
    target_stats,
)
from eye_in_hand.errors import InputError


def _scene(rng, n=50, noise=0.0005):
    centres = {"a": np.array([0.4, 0.1, 0.02]), "b": np.array([0.5, 0.12, 0.02]),
               "c": np.array([0.45, 0.25, 0.05])}
    truth = {k: np.tile(c, (n, 1)) for k, c in centres.items()}
    tracks = {k: t + rng.normal(0, noise, t.shape) for k, t in truth.items()}
    return centres, truth, tracks


def test_pairs_match_a_per_frame_reference_with_missing_frames():
    rng = np.random.default_rng(1)
    centres, truth, tracks = _scene(rng)
    tracks["a"][[3, 7, 11]] = np.nan          # a missing in three frames
    tracks["b"][[7, 20]] = np.nan             # b in two (one shared with a)
    pairs = pairwise_distances(tracks, truth)
    assert [(p.a, p.b) for p in pairs] == [("a", "b"), ("a", "c"), ("b", "c")]
    ab = pairs[0]
    both = [k for k in range(50) if k not in (3, 7, 11, 20)]
    d = [np.linalg.norm(tracks["a"][k] - tracks["b"][k]) for k in both]
    assert ab.frames == len(both) == 46
    assert ab.mean_m == pytest.approx(np.mean(d), abs=1e-12)
    assert ab.std_m == pytest.approx(np.std(d, ddof=1), abs=1e-12)
    true_ab = np.linalg.norm(centres["a"] - centres["b"])
    assert ab.truth_m == pytest.approx(true_ab, abs=1e-12)
    assert ab.error_mm == pytest.approx(1000 * (np.mean(d) - true_ab), abs=1e-9)
    assert ab.truth_source == "ground_truth"
    # noise of 0.5 mm per axis: the distance's spread is ~0.7 mm, its mean within a fraction
    assert 0.4 < 1000 * ab.std_m < 1.1 and abs(ab.error_mm) < 0.3


def test_a_pair_never_seen_together_and_a_single_frame():
    t = {"a": np.array([[0, 0, 0], [np.nan] * 3, [0, 0, 0.0]]),
         "b": np.array([[np.nan] * 3, [1, 0, 0], [0, 0, 0.5]])}
    (p,) = pairwise_distances(t)
    assert p.frames == 1 and p.mean_m == pytest.approx(0.5) and math.isnan(p.std_m)
    assert math.isnan(p.truth_m) and p.to_dict()["std_mm"] is None
    t["a"][2] = np.nan
    (p,) = pairwise_distances(t)
    assert p.frames == 0 and math.isnan(p.mean_m)


def test_known_distances_override_and_unmatched_entries():
    rng = np.random.default_rng(2)
    centres, truth, tracks = _scene(rng)
    pairs = pairwise_distances(tracks, truth)
    known = [("c", "a", 0.2), ("a", "zz", 0.1)]
    out, unmatched = apply_known_distances(pairs, known)
    ac = out[1]
    assert (ac.a, ac.b, ac.truth_source, ac.truth_m) == ("a", "c", "known", 0.2)
    assert ac.error_mm == pytest.approx(1000 * (pairs[1].mean_m - 0.2))
    assert out[0] == pairs[0] and unmatched == [("a", "zz", 0.1)]


def test_target_stats_rms_against_truth():
    rng = np.random.default_rng(3)
    _, truth, tracks = _scene(rng, n=200, noise=0.001)
    tracks["b"][:10] = np.nan
    stats = {s.id: s for s in target_stats(tracks, truth)}
    assert stats["b"].located == 190 and stats["b"].truth_frames == 190
    e = np.linalg.norm(tracks["a"] - truth["a"], axis=1)
    assert stats["a"].rms_mm == pytest.approx(1000 * np.sqrt(np.mean(e ** 2)))
    assert 1.5 < stats["a"].rms_mm < 2.0      # sqrt(3) mm expected


def test_match_truth_is_a_nearest_assignment_in_any_order():
    truth = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]])
    located = {"x": truth[2] + 0.004, "y": truth[0] - 0.003, "z": truth[1] + 0.001,
               "ghost": np.array([np.nan] * 3)}
    assert match_truth(located, truth) == {"x": 2, "y": 0, "z": 1}
    # two located ids near one truth: the better one gets it, the other the free truth
    assert match_truth({"p": truth[0] + 0.001, "q": truth[0] + 0.002}, truth[:2]) == \
        {"p": 0, "q": 1}
    assert match_truth({"p": truth[0] + 0.02}, truth, max_distance_m=0.01) == {}


def test_bad_shapes_are_input_errors():
    with pytest.raises(InputError, match=r"tracks\['b'\]: expected shape \(2, 3\)"):
        pairwise_distances({"a": np.zeros((2, 3)), "b": np.zeros((3, 3))})
    with pytest.raises(InputError, match="infinite"):
        pairwise_distances({"a": np.full((2, 3), np.inf), "b": np.zeros((2, 3))})


def test_table_lines():
    rng = np.random.default_rng(4)
    _, truth, tracks = _scene(rng)
    lines = distance_table(pairwise_distances(tracks, truth), target_stats(tracks, truth))
    assert lines[0].split()[:2] == ["pair", "frames"]
    assert lines[1].startswith("a - b") and lines[1].rstrip().endswith("ground_truth")
    assert any(line.startswith("target") for line in lines) and lines[-1].startswith("c ")



def test_truth_distance_is_averaged_over_the_frames_both_were_located():
    """Moving targets: the true distance changes from frame to frame, and a pair's truth and
    error are taken over exactly the frames in which both targets were located."""
    n = 20
    k = np.arange(n)[:, None]
    truth = {"a": np.hstack([0.01 * k, np.zeros((n, 2))]), "b": np.tile([0.3, 0.0, 0.0], (n, 1))}
    tracks = {key: v + 1e-4 for key, v in truth.items()}
    tracks["a"][[0, 1, 2]] = np.nan                    # a missing while the truth is far
    (ab,) = pairwise_distances(tracks, truth)
    true_d = np.abs(0.3 - 0.01 * np.arange(n))
    assert ab.frames == n - 3
    assert ab.truth_m == pytest.approx(true_d[3:].mean(), abs=1e-12)
    assert ab.truth_m != pytest.approx(true_d.mean(), abs=1e-4)
    assert ab.error_mm == pytest.approx(0.0, abs=1e-9)
