"""A live calibration driven without ROS, as the ``hand_eye`` node's calibration mode drives it.

The session (:mod:`eye_in_hand.core.handeye.session`) gets a stereo rig's images one by one
(opaque tokens: the board observation of each still pose comes from a synthetic problem) and
the robot poses a driver streams; a capture is answered once the poses cover its stillness
window, a capture while the robot moves is refused, and the samples are computed and saved
(:func:`eye_in_hand.report.handeye.save_outputs`, what ``hand_eye/save`` writes). No rclpy.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from eye_in_hand.core.handeye.observe import Observation
from eye_in_hand.core.handeye.samples import HandEyeSample
from eye_in_hand.core.handeye.session import (
    FRAMES_KEPT,
    CalibrationSession,
    SessionConfig,
    receive_age_rule,
)
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.sync import PoseBuffer
from eye_in_hand.io.atomic import OutputExistsError
from eye_in_hand.io.config import load_hand_eye
from eye_in_hand.report.handeye import save_outputs

MS = 1_000_000
STOPS = 8


class LiveCell:
    """A stereo camera and a robot driver feeding one session; stop k shows problem pose k."""

    def __init__(self) -> None:
        self.problem = make_problem(STOPS, seed=4, noise_px=0.2, stereo=True)
        self.poses = PoseBuffer(100_000)
        self.now_ns = 0
        self.session = CalibrationSession(
            SessionConfig(min_samples=6, target_std_mm=5.0, target_std_deg=0.5), board=None,
            views=self.problem.views, poses=self.poses, decode=lambda frame: frame,
            observe=self.observe,
            pose_kwargs=lambda req: receive_age_rule(req, self.now_ns, 1.0))

    def observe(self, name, images, base_T_ee, board, views):
        assert set(images) == {"left", "right"}
        s = self.problem.samples[images["left"]]
        return Observation(HandEyeSample(name, base_T_ee, s.cam_T_board, s.observations))

    def drive(self, t0_ns: int, t1_ns: int, stop: int, speed_m_s: float = 0.0) -> None:
        """Robot poses at 250 Hz from t0 to t1 at stop ``stop``, moving along x at
        ``speed_m_s``; each received when stamped."""
        for t in range(t0_ns, t1_ns + 1, 4 * MS):
            T = self.problem.samples[stop].base_T_ee.copy()
            T[0, 3] += speed_m_s * (t - t0_ns) / 1e9
            self.now_ns = t
            self.poses.add(t, T, received_ns=t)

    def capture(self, t_ns: int, stop: int, speed_m_s: float = 0.0):
        """Ask at ``t_ns``; the pair of the stop comes 100 ms later, its images one by one;
        the robot pose streams on for 300 ms after it."""
        s = self.session
        self.drive(t_ns - 500 * MS, t_ns, stop, speed_m_s)
        req = s.request_capture(now_s=t_ns / 1e9, now_ns=t_ns)
        stamp = t_ns + 100 * MS
        assert s.add_image("left", stamp, stop, received_ns=stamp) is None
        assert req.frame_stamp_ns is None                    # half a pair is no frame
        assert s.add_image("right", stamp, stop, received_ns=stamp) == {"left": stop,
                                                                        "right": stop}
        assert req.frame_stamp_ns == stamp
        assert s.ready(t_ns / 1e9) == []                     # the stillness window not covered
        self.drive(t_ns + 4 * MS, stamp + 300 * MS, stop, speed_m_s)
        (ready,) = s.ready(t_ns / 1e9 + 0.5)
        assert ready is req
        return s.complete(ready)


def test_capture_refuse_while_moving_compute_and_save(tmp_path):
    cell = LiveCell()
    s = cell.session
    out = cell.capture(1000 * MS, 0)
    assert out.ok and out.index == 0 and out.record.sample.name == "sample_000"
    # the arm still moves (5 mm/s) at stop 1: refused, and the reason is kept
    out = cell.capture(3000 * MS, 1, speed_m_s=0.005)
    assert not out.ok and out.reason == "moving" and "wait until it stops" in out.message
    assert [r.split(":")[0] for _, r in s.skipped] == ["moving"]
    for k in range(1, STOPS):
        out = cell.capture((5 + 2 * k) * 1000 * MS, k)
        assert out.ok, out.message
    assert [r.sample.name for r in s.records] == [f"sample_{k:03d}" for k in range(STOPS)]

    result = s.compute()
    assert s.result is result
    err_mm = 1000 * np.linalg.norm(result.X[:3, 3] - cell.problem.X[:3, 3])
    assert err_mm < 2.0, err_mm
    status = s.status()
    assert status.samples == STOPS and status.good_enough, status.problems

    folder = tmp_path / "hand_eye_calibration"
    kw = dict(setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
              source="a test")
    files = save_outputs(folder, result, s.samples, s.skipped, **kw)
    assert sorted(p.name for p in files) == ["hand_eye.yaml", "report.html", "report.json"]
    assert all(p.parent == folder and p.is_file() for p in files)
    saved = load_hand_eye(folder / "hand_eye.yaml")
    np.testing.assert_allclose(saved.transform, result.X, atol=1e-9)
    assert saved.sample_count == STOPS and saved.parent_frame == "tool0"
    report = json.loads((folder / "report.json").read_text())
    assert report["input"] == {"source": "a test", "count": STOPS + 1}
    assert [r["reason"].split(":")[0] for r in report["skipped"]] == ["moving"]
    # a folder that exists is replaced only when asked to, and then whole
    with pytest.raises(OutputExistsError, match="exists already"):
        save_outputs(folder, result, s.samples, s.skipped, **kw)
    save_outputs(folder, result, s.samples, [], overwrite=True, **kw)
    assert json.loads((folder / "report.json").read_text())["skipped"] == []


def test_incomplete_frames_are_kept_for_their_other_image_up_to_a_limit():
    """The images of one stamp make a frame once every view's is in; of the incomplete ones
    only the newest FRAMES_KEPT wait (a camera whose other image never comes)."""
    s = LiveCell().session
    for k in range(FRAMES_KEPT + 1):
        assert s.add_image("left", k, k) is None
    last = FRAMES_KEPT
    assert s.add_image("right", last, last) == {"left": last, "right": last}
    assert s.add_image("right", 1, 1) == {"left": 1, "right": 1}   # one of the newest kept
    assert s.add_image("right", 0, 0) is None                      # the oldest was dropped
    assert s.add_image("left", 0, 0) == {"right": 0, "left": 0}


def test_the_session_and_the_save_need_no_ros():
    code = ("import sys\n"
            "import eye_in_hand.core.handeye.session, eye_in_hand.report.handeye\n"
            "assert not [m for m in sys.modules if m.split('.')[0] in "
            "('rclpy', 'sensor_msgs', 'geometry_msgs')], 'ROS loaded'\n")
    subprocess.run([sys.executable, "-c", code], check=True)
