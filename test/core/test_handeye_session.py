"""core.handeye.session: the live capture rule, refusals, samples and status, without ROS.

The robot streams poses into a PoseBuffer as a driver would (poses may lag the images); frames
are opaque tokens and the board observation comes from a synthetic problem, so every rule of
the capture is checked with exact numbers.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from eye_in_hand.core.handeye.observe import Observation
from eye_in_hand.core.handeye.samples import HandEyeSample
from eye_in_hand.core.handeye.session import (
    CalibrationSession,
    CaptureRequest,
    SessionConfig,
    receive_age_rule,
)
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.sync import PoseBuffer
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import HandEyeError, InputError

MS = 1_000_000


class Cell:
    """A synthetic problem's poses played as a live cell: stop i holds problem pose i."""

    def __init__(self, n: int = 12, setup: str = "eye_in_hand", **cfg) -> None:
        self.problem = make_problem(n, setup=setup, seed=3, noise_px=0.2)
        self.poses = PoseBuffer(100_000)
        self.stop = 0
        self.session = CalibrationSession(
            SessionConfig(setup=setup, **cfg), board=None, views=self.problem.views,
            poses=self.poses, decode=lambda frame: frame, observe=self.observe)
        self.seen_board = True

    def observe(self, name, images, base_T_ee, board, views):
        if not self.seen_board:
            return Observation(None, "board not found in the left image (no corners)")
        s = self.problem.samples[images["stop"]]
        return Observation(HandEyeSample(name, base_T_ee, s.cam_T_board, s.observations))

    def pose(self, stop: int) -> np.ndarray:
        return self.problem.samples[stop].base_T_ee

    def stream(self, t0_ns: int, t1_ns: int, stop: int, *, rate_hz: float = 250.0,
               motion=None) -> None:
        """Robot poses from t0 to t1 (inclusive) at one stop, or moving (motion(t) -> T)."""
        step = int(1e9 / rate_hz)
        newest = self.poses.newest_ns
        for t in [*range(t0_ns, t1_ns, step), t1_ns]:
            if newest is not None and t <= newest:
                continue
            self.poses.add(t, self.pose(stop) if motion is None else motion(t))


def _capture(cell: Cell, *, frame_ns: int, stop: int, pose_until_ns: int, now_s: float = 0.0):
    s = cell.session
    req = s.request_capture(now_s)
    s.add_frame(frame_ns, {"stop": stop})
    cell.stream(frame_ns - 500 * MS, pose_until_ns, stop)
    ready = s.ready(now_s)
    return req, ready


def test_capture_waits_for_poses_after_the_image_then_takes_the_sample():
    cell = Cell()
    s = cell.session
    cell.stream(0, 1000 * MS, 0)                 # poses up to t = 1 s
    s.add_frame(990 * MS, {"stop": 0})           # a frame before the request: never used
    req = s.request_capture(now_s=0.0)
    s.add_frame(1000 * MS, {"stop": 0})          # the first frame after the request
    assert s.ready(0.1) == []                    # poses stop at the image: window not covered
    cell.stream(1000 * MS, 1150 * MS, 0)         # poses 50 ms late: still short of +200 ms
    assert s.ready(0.2) == []
    cell.stream(1150 * MS, 1200 * MS, 0)
    (got,) = s.ready(0.3)
    assert got is req and got.frame_stamp_ns == 1000 * MS
    out = s.complete(got)
    assert out.ok and out.index == 0 and out.reason == ""
    assert out.record.stamp_ns == 1000 * MS
    np.testing.assert_allclose(out.record.sample.base_T_ee, cell.pose(0))


def test_moving_robot_is_refused_with_the_distance_it_moved():
    cell = Cell()
    s = cell.session
    T0 = cell.pose(0)

    def moving(t):  # 5 mm/s along x: 1 mm in 0.2 s, over the 0.4 mm still limit
        T = T0.copy()
        T[0, 3] += 0.005 * t / 1e9
        return T

    req = s.request_capture(0.0)
    s.add_frame(1000 * MS, {"stop": 0})
    cell.stream(0, 1300 * MS, 0, motion=moving)
    out = s.complete(s.ready(0.1)[0])
    assert not out.ok and out.reason == "moving"
    assert "moved 1.00 mm" in out.message and "wait until it stops" in out.message
    assert s.records == [] and req.id == 0


def test_slow_drift_below_the_limit_is_still():
    cell = Cell()
    s = cell.session
    T0 = cell.pose(0)

    def drift(t):  # 1 mm/s: 0.2 mm at the window edge, under 0.4 mm
        T = T0.copy()
        T[1, 3] += 0.001 * t / 1e9
        return T

    s.request_capture(0.0)
    s.add_frame(1000 * MS, {"stop": 0})
    cell.stream(0, 1300 * MS, 0, motion=drift)
    assert s.complete(s.ready(0.1)[0]).ok


def test_rotation_counts_for_stillness():
    cell = Cell()
    s = cell.session
    T0 = cell.pose(0)

    def turning(t):  # 0.03 rad/s about z: 6 mrad at the window edge, over 2 mrad
        return T0 @ from_rotvec([0.0, 0.0, 0.03 * t / 1e9], [0.0, 0.0, 0.0])

    s.request_capture(0.0)
    s.add_frame(1000 * MS, {"stop": 0})
    cell.stream(0, 1300 * MS, 0, motion=turning)
    out = s.complete(s.ready(0.1)[0])
    assert out.reason == "moving" and "0.344 deg" in out.message


def test_no_pose_after_the_image_times_out_with_no_pose():
    cell = Cell(capture_timeout_s=1.0)
    s = cell.session
    cell.stream(0, 1000 * MS, 0)
    s.request_capture(0.0)
    s.add_frame(1100 * MS, {"stop": 0})          # image newer than every pose
    assert s.ready(0.5) == []
    (req,) = s.ready(1.0)                        # deadline
    out = s.complete(req)
    assert out.reason == "no_pose" and "100 ms before the image" in out.message


def test_no_pose_before_the_window_is_refused():
    cell = Cell()
    s = cell.session
    s.request_capture(0.0)
    s.add_frame(1000 * MS, {"stop": 0})
    cell.stream(1000 * MS, 1300 * MS, 0)         # nothing before the image
    out = s.complete(s.ready(0.1)[0])
    assert out.reason == "no_pose" and "around the image" in out.message


def test_no_frame_times_out_with_no_image():
    cell = Cell(capture_timeout_s=0.5)
    s = cell.session
    cell.stream(0, 1000 * MS, 0)
    s.add_frame(500 * MS, {"stop": 0})           # before the request: not used
    s.request_capture(10.0)
    assert s.ready(10.4) == []
    out = s.complete(s.ready(10.5)[0])
    assert out.reason == "no_image" and "camera topics" in out.message


def test_board_not_seen_is_refused_and_counted():
    cell = Cell()
    cell.seen_board = False
    req, ready = _capture(cell, frame_ns=1000 * MS, stop=0, pose_until_ns=1300 * MS)
    out = cell.session.complete(ready[0])
    assert out.reason == "board_not_seen" and "whole board" in out.message
    assert len(cell.session.skipped) == 1 and cell.session.records == []


def test_second_capture_at_the_same_still_pose_is_a_duplicate():
    cell = Cell()
    s = cell.session
    _, ready = _capture(cell, frame_ns=1000 * MS, stop=0, pose_until_ns=1300 * MS)
    assert s.complete(ready[0]).ok
    _, ready = _capture(cell, frame_ns=1400 * MS, stop=0, pose_until_ns=1700 * MS)
    out = s.complete(ready[0])
    assert out.reason == "duplicate" and "already taken as sample_000" in out.message
    assert len(s.records) == 1
    _, ready = _capture(cell, frame_ns=3000 * MS, stop=1, pose_until_ns=3300 * MS)
    assert s.complete(ready[0]).ok and len(s.records) == 2


def test_stillness_window_is_checked_on_both_sides():
    """A robot still after the image but moving before it is refused (window is +- w)."""
    cell = Cell()
    s = cell.session
    T0 = cell.pose(0)

    def arriving(t):  # moves at 10 mm/s until 0.95 s, still after
        T = T0.copy()
        T[2, 3] += 0.01 * (min(t, 950 * MS) - 950 * MS) / 1e9
        return T

    s.request_capture(0.0)
    s.add_frame(1000 * MS, {"stop": 0})
    cell.stream(0, 1300 * MS, 0, motion=arriving)
    out = s.complete(s.ready(0.1)[0])
    assert out.reason == "moving"


def test_remove_by_index_and_name_and_errors():
    cell = Cell()
    s = cell.session
    for k in range(3):
        _, ready = _capture(cell, frame_ns=(1 + 2 * k) * 1000 * MS, stop=k,
                            pose_until_ns=(1 + 2 * k) * 1000 * MS + 300 * MS)
        assert s.complete(ready[0]).ok
    assert [r.sample.name for r in s.records] == ["sample_000", "sample_001", "sample_002"]
    assert s.remove(name="sample_001").sample.name == "sample_001"
    assert s.remove(index=0).sample.name == "sample_000"
    with pytest.raises(InputError, match="no sample at index 5"):
        s.remove(index=5)
    with pytest.raises(InputError, match="no sample named 'x'.*sample_002"):
        s.remove(name="x")
    _, ready = _capture(cell, frame_ns=9000 * MS, stop=5, pose_until_ns=9300 * MS)
    assert s.complete(ready[0]).record.sample.name == "sample_003"   # names never reused


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_compute_and_status_after_a_live_session(setup):
    cell = Cell(n=12, setup=setup, min_samples=10, target_std_mm=5.0, target_std_deg=0.5)
    s = cell.session
    st = s.status()
    assert not st.good_enough and "0 of 10 samples" in st.problems[0]
    for k in range(12):
        t = (1 + 2 * k) * 1000 * MS
        _, ready = _capture(cell, frame_ns=t, stop=k, pose_until_ns=t + 300 * MS)
        assert s.complete(ready[0]).ok
    with pytest.raises(HandEyeError, match="need at least 3"):
        s.compute(s.samples[:2])
    res = s.compute()
    err_t = np.linalg.norm(res.X[:3, 3] - cell.problem.X[:3, 3]) * 1000
    assert err_t < 2.0
    st = s.status()
    assert st.samples == 12 and st.result is res
    assert st.rotation_spread_deg > 30 and st.axis_diversity > 0.05
    assert st.good_enough, st.problems
    strict = CalibrationSession(SessionConfig(setup=setup, target_std_mm=1e-6),
                                None, cell.problem.views, cell.poses, lambda f: f)
    strict.records = list(s.records)
    st2 = strict.status(result=res)
    assert not st2.good_enough and "above the target" in st2.problems[-1]


def test_config_is_checked():
    with pytest.raises(InputError, match="setup must be one of"):
        SessionConfig(setup="eye_on_hand")
    with pytest.raises(InputError, match="capture_timeout_s must be"):
        SessionConfig(capture_timeout_s=0.0)
    with pytest.raises(InputError, match="still_window_s must be"):
        SessionConfig(still_window_s=math.nan)


def test_a_frame_stamped_before_the_request_is_not_used():
    """A slow camera or renderer hands in a frame exposed before the request, after it: the
    request waits for a frame stamped after its own time."""
    cell = Cell()
    s = cell.session
    cell.stream(0, 3000 * MS, 0)
    req = s.request_capture(0.0, now_ns=2000 * MS)
    s.add_frame(1500 * MS, {"stop": 0}, received_ns=2100 * MS)   # exposed before the request
    assert req.frame_stamp_ns is None
    s.add_frame(2500 * MS, {"stop": 0}, received_ns=2600 * MS)
    assert req.frame_stamp_ns == 2500 * MS and req.frame_received_ns == 2600 * MS
    assert s.complete(s.ready(0.1)[0]).ok


def test_a_frame_stamped_exactly_at_the_request_or_the_newest_frame_is_not_used():
    """"Newer than" is strict: the frame already seen when the capture was asked (a second
    delivery of it, e.g. the in-process and the topic path both) and a frame stamped at the
    request's own time show the arm before the request, and are not bound."""
    cell = Cell()
    s = cell.session
    cell.stream(0, 3000 * MS, 0)
    s.add_frame(1000 * MS, {"stop": 0})
    req = s.request_capture(0.0)                      # after the newest frame, 1000 ms
    s.add_frame(1000 * MS, {"stop": 0})               # the same stamp again
    assert req.frame_stamp_ns is None
    req2 = s.request_capture(0.0, now_ns=2000 * MS)
    s.add_frame(2000 * MS, {"stop": 0})               # exactly at the request's time
    assert req2.frame_stamp_ns is None and req.frame_stamp_ns == 2000 * MS
    s.add_frame(2000 * MS + 1, {"stop": 0})
    assert req2.frame_stamp_ns == 2000 * MS + 1


def test_receive_age_is_measured_at_the_frame_arrival():
    """pose_kwargs gets the request: the node measures the poses' receive age against the
    frame's arrival, not against when a busy worker got to it."""
    cell = Cell()
    seen = []
    cell.session.pose_kwargs = lambda req: seen.append(req.frame_received_ns) or {}
    s = cell.session
    s.request_capture(0.0, now_ns=0)
    s.add_frame(1000 * MS, {"stop": 0}, received_ns=1050 * MS)
    cell.stream(0, 1300 * MS, 0)
    assert s.complete(s.ready(0.1)[0]).ok
    assert seen and set(seen) == {1050 * MS}


def test_capture_pose_age_counts_from_the_image_stamp_not_its_late_arrival():
    """A camera that delivers its pair late (a slow renderer under load, a slow link) must not
    make the robot poses at the image's own stamp stale: they may have been received up to
    max_pose_age_s before the stamp; older ones are refused."""
    s = 1_000_000_000
    req = CaptureRequest(0, None, 0.0, frame_stamp_ns=10 * s, frame_received_ns=12 * s)
    rule = receive_age_rule(req, int(12.1 * s), 1.0)
    assert rule["now_ns"] == int(12.1 * s)
    oldest_ok = rule["now_ns"] - rule["max_age_ns"]
    assert oldest_ok == 9 * s                    # 1 s before the image stamp
    assert 9.5 * s >= oldest_ok > 8.5 * s        # a pose at 9.5 s counts, one at 8.5 s not


def test_a_pose_that_only_rotates_or_only_moves_is_new():
    """Duplicate means close in position *and* rotation: a pure tilt at the same flange
    position, or a pure shift at the same orientation, is a new pose."""
    cell = Cell()
    s = cell.session
    T0 = cell.pose(0)
    tilted = T0 @ from_rotvec([0.0, 0.0, np.radians(10.0)], [0.0, 0.0, 0.0])   # same position
    shifted = T0.copy()
    shifted[0, 3] += 0.02                                                        # same rotation
    t = 1000 * MS
    for T in (T0, tilted, shifted, T0 @ from_rotvec([0, 0, np.radians(0.3)], [0.001, 0, 0])):
        s.request_capture(0.0)
        s.add_frame(t, {"stop": 0})
        for k in range(-80, 81):
            cell.poses.add(t + k * 4 * MS, T)
        out = s.complete(s.ready(0.1)[0])
        t += 2000 * MS
    assert [r.reason for r in [out]] == ["duplicate"]       # the last: 1 mm and 0.3 deg away
    assert len(s.records) == 3
