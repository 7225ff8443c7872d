"""results.csv rows of targets that were not located: the ground truth stays in them."""
from __future__ import annotations

import csv

import numpy as np

from eye_in_hand.io.results import (
    FrameResult,
    ProcessResult,
    TargetResult,
    assign_truth,
    write_results,
)

T0 = 1_700_000_000_000_000_000
TRUE = {"a": np.array([0.40, 0.10, 0.02]), "b": np.array([0.55, 0.25, 0.02])}


def _located(tid: str, p_base: np.ndarray) -> TargetResult:
    return TargetResult(id=tid, name=tid, point_cam=np.array([0.0, 0.0, 0.5]),
                        cov_cam=np.eye(3) * 1e-8, residual_px=0.1, left_px=np.zeros(2),
                        right_px=np.zeros(2), status="ok", point_base=p_base,
                        cov_base=np.eye(3) * 1e-8)


def _frame(k: int, located: dict[str, np.ndarray]) -> FrameResult:
    targets = [_located(i, p) for i, p in located.items()]
    f = FrameResult(T0 + k, "ok" if targets else "no_target", targets=targets)
    if not targets:
        f.reason = "no blob"
    f.missing = {i: "no blob" for i in TRUE if i not in located}
    return f


def _truth(n: int, order: tuple[str, ...]) -> dict[int, list[np.ndarray]]:
    """The simulator's ground truth: per stamp, the true centres in world order (moving by
    1 mm per frame, so a row carries the truth of its own stamp)."""
    return {T0 + k: [TRUE[i] + [0.001 * k, 0, 0] for i in order] for k in range(n)}


def _rows(tmp_path, frames: list[FrameResult], ids: list[str],
          truth: dict[int, list[np.ndarray]]) -> list[dict[str, str]]:
    res = ProcessResult(frames=frames, counts={}, target_ids=ids)
    res.truth_match = assign_truth(frames, truth, ids)
    write_results(tmp_path / "out", res)
    return list(csv.DictReader((tmp_path / "out" / "results.csv").open()))


def _gt(row: dict[str, str]) -> np.ndarray:
    return np.array([float(row[k]) for k in ("gt_x", "gt_y", "gt_z")])


def test_one_target_no_target_rows_keep_the_ground_truth(tmp_path):
    off = np.array([0.0003, 0, 0])
    frames = [_frame(0, {"a": TRUE["a"] + off}), _frame(1, {}), _frame(2, {}),
              _frame(3, {"a": TRUE["a"] + [0.003, 0, 0] + off})]
    rows = _rows(tmp_path, frames, ["a"], _truth(4, ("a",)))
    assert [r["status"] for r in rows] == ["ok", "no_target", "no_target", "ok"]
    for k, r in enumerate(rows):
        assert np.allclose(_gt(r), TRUE["a"] + [0.001 * k, 0, 0], atol=1e-12), k
    assert [r["error_mm"] == "" for r in rows] == [False, True, True, False]
    assert float(rows[0]["error_mm"]) == float(rows[3]["error_mm"])
    assert all(r["x_base"] == "" for r in rows[1:3])


def test_one_target_never_located_keeps_the_ground_truth(tmp_path):
    rows = _rows(tmp_path, [_frame(0, {}), _frame(1, {})], ["a"], _truth(2, ("a",)))
    for k, r in enumerate(rows):
        assert r["status"] == "no_target" and r["reason"] == "no blob"
        assert np.allclose(_gt(r), TRUE["a"] + [0.001 * k, 0, 0], atol=1e-12)


def test_several_targets_a_missing_row_gets_its_own_matched_truth(tmp_path):
    # truth in the order (b, a): the ids are matched by position, not by order
    def frames() -> list[FrameResult]:
        return [_frame(0, {"a": TRUE["a"], "b": TRUE["b"]}), _frame(1, {"a": TRUE["a"]}),
                _frame(2, {"b": TRUE["b"] + [0.002, 0, 0]})]

    rows = _rows(tmp_path, frames(), ["a", "b"], _truth(3, ("b", "a")))
    assert [(r["target"], r["status"]) for r in rows] == [
        ("a", "ok"), ("b", "ok"), ("a", "ok"), ("b", "no_target"), ("a", "no_target"),
        ("b", "ok")]
    for n, r in enumerate(rows):
        k = n // 2
        assert np.allclose(_gt(r), TRUE[r["target"]] + [0.001 * k, 0, 0], atol=1e-12), n
    # a truth-less bag: the columns stay empty
    rows = _rows(tmp_path / "none", frames(), ["a", "b"], {})
    assert all(r["gt_x"] == "" for r in rows)


def test_a_truth_table_reads_as_the_dict_of_lists_it_replaces():
    """``process`` keeps the ground truth in a :class:`TruthTable` (columns): the same
    stamps in first-added order, the same points per stamp in the order added (stamps out of
    order and repeated, as a bag's log order may give them), and the same matches."""
    from eye_in_hand.io.results import TruthTable

    rng = np.random.default_rng(3)
    as_dict: dict[int, list[np.ndarray]] = {}
    table = TruthTable()
    for stamp in [T0 + 5, T0 + 2, T0 + 5, T0 + 9, T0 + 2, T0 + 5, T0 + 1]:
        p = rng.normal(size=3)
        as_dict.setdefault(stamp, []).append(p)
        table.add(stamp, p)
    assert list(table) == list(as_dict) and len(table) == len(as_dict) == 4
    for stamp, points in as_dict.items():
        got = table[stamp]
        assert len(got) == len(points)
        for a, b in zip(got, points, strict=True):
            assert a.shape == (3,) and a.tobytes() == b.tobytes()   # to the last bit
    assert table.get(T0 + 3) is None and T0 + 4 not in table and T0 + 9 in table
    table.add(T0 + 3, np.zeros(3))                 # an add after a lookup is seen
    assert table[T0 + 3][0].tolist() == [0.0, 0.0, 0.0] and len(table) == 5
    assert not TruthTable() and list(TruthTable()) == []


def test_the_truth_from_a_table_is_the_truth_from_a_dict(tmp_path):
    from eye_in_hand.io.results import TruthTable

    def frames() -> list[FrameResult]:
        return [_frame(k, {"a": TRUE["a"] + [0.001 * k + 0.0002, 0, 0]} if k % 3 else {})
                for k in range(6)]

    truth = _truth(6, ("b", "a"))
    table = TruthTable()
    for stamp, points in truth.items():
        for p in points:
            table.add(stamp, p)
    a, b = frames(), frames()
    assert assign_truth(a, truth, ["a"]) == assign_truth(b, table, ["a"])
    for fa, fb in zip(a, b, strict=True):
        assert fa.truth_base.tobytes() == fb.truth_base.tobytes()
        assert fa.truth_by_id.keys() == fb.truth_by_id.keys()


def test_prepared_output_types_leave_the_writer_nothing_to_generate(tmp_path, monkeypatch):
    """``process`` runs prepare_output_types while its workers locate: writing the output bag
    afterwards generates no definition and no serializer (a fresh type store here, so that
    no other test has made them already), and the bag is what it is without preparing."""
    from types import SimpleNamespace

    from rosbags.typesys import Stores, get_typestore

    from eye_in_hand.io import results
    from eye_in_hand.ros.outputs import OutputSettings

    frames = [_frame(k, {"a": TRUE["a"], "b": TRUE["b"]}) for k in range(3)]
    opts = SimpleNamespace(outputs=OutputSettings(hand_eye_T=np.eye(4), stereo_T=np.eye(4),
                                                  target_frame="target"),
                           camera_frame="camera_left_optical_frame", base_frame="base_link")

    def run(out, prepare: bool) -> tuple[set[str], list[str]]:
        store = get_typestore(Stores.ROS2_JAZZY)
        monkeypatch.setattr(results, "default_typestore", lambda: store)
        if prepare:
            results.prepare_output_types()
        made = set(store.cache)
        generated: list[str] = []
        real = store.generate_msgdef
        monkeypatch.setattr(store, "generate_msgdef",
                            lambda t, **kw: generated.append(t) or real(t, **kw))
        res = ProcessResult(frames=frames, counts={}, target_ids=["a", "b"])
        res.truth_match = assign_truth(frames, _truth(3, ("a", "b")), ["a", "b"])
        write_results(out, res, opts)
        return set(store.cache) - made, generated

    new, generated = run(tmp_path / "prepared" / "out", True)
    assert new == set() and generated == []
    new, generated = run(tmp_path / "cold" / "out", False)
    assert "tf2_msgs/msg/TFMessage" in new and generated      # what preparing did
    for name in ("out.mcap", "metadata.yaml", "results.csv"):
        assert (tmp_path / "prepared" / "out" / name).read_bytes() == \
            (tmp_path / "cold" / "out" / name).read_bytes()
