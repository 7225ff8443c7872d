"""LocalizationPipeline without rclpy: pose waiting, FIFO, expiry, staleness, eye-to-hand,
frames of targets, joint states; the rules the hand_eye node and `process` share."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from eye_in_hand.core.eye_to_hand import EyeToHandLocalizer
from eye_in_hand.core.kinematics import DHChain
from eye_in_hand.core.localization import Localizer
from eye_in_hand.core.pipeline import (
    LocalizationPipeline,
    PipelineRules,
    localizer_config,
)
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import InputError

MS = 1_000_000
T0 = 1_700_000_000_000_000_000
EE_T_CAM = from_rotvec([0.0, 0.0, 0.1], [0.01, 0.02, 0.05])
P_CAM = np.array([0.02, -0.01, 0.4])
COV = np.diag([1e-6, 2e-6, 4e-6])


class Clock:
    """A wait clock the test moves by hand (s)."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Sink:
    """Records what the pipeline emits, in order."""

    def __init__(self) -> None:
        self.out: list[tuple] = []

    def point_located(self, item, p, cov):
        self.out.append(("ok", item.stamp_ns, p, cov))

    def point_refused(self, item, reason, detail):
        self.out.append(("refused", item.stamp_ns, reason, detail))

    def target_located(self, frame, target, p, cov):
        self.out.append(("target_ok", frame.stamp_ns, target.id, p))

    def target_refused(self, frame, target, reason, detail):
        self.out.append(("target_refused", frame.stamp_ns, target.id, reason))

    def frame_done(self, frame):
        self.out.append(("frame", frame.stamp_ns))

    def orphan_points(self, n):
        self.out.append(("orphans", n))


@dataclass
class Target:
    id: str
    point_cam: np.ndarray | None = None
    cov_cam: np.ndarray | None = None


def _pose(t_ns: int) -> np.ndarray:
    s = (t_ns - T0) / 1e9
    return from_rotvec([0.1 * s, 0.0, 0.0], [0.4 + 0.1 * s, 0.0, 0.3])


def _pipeline(rules: PipelineRules | None = None, *, max_age_s: float | None = 1.0,
              eye_to_hand: bool = False, cov_expected=None, kinematics=None):
    clock, sink = Clock(), Sink()
    if eye_to_hand:
        loc: Localizer | EyeToHandLocalizer = EyeToHandLocalizer(EE_T_CAM)
    else:
        loc = Localizer(EE_T_CAM, None, localizer_config(
            max_pose_gap_s=0.05, max_pose_age_s=max_age_s, pose_jump_back_s=1.0,
            buffer_size=100, robot_sigma_pos_m=0.0, robot_sigma_rot_rad=0.0))
    pipe = LocalizationPipeline(loc, rules or PipelineRules(), wait_clock=clock, points=sink,
                                frames=sink, cov_expected=cov_expected, kinematics=kinematics)
    return pipe, clock, sink


def _expected(stamp: int) -> np.ndarray:
    return (_pose(stamp) @ EE_T_CAM @ np.r_[P_CAM, 1.0])[:3]


def test_a_point_waits_for_a_pose_at_or_after_its_stamp():
    pipe, _, sink = _pipeline()
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_point(T0 + 5 * MS, P_CAM, COV, received_ns=T0 + 6 * MS)
    assert sink.out == [] and len(pipe.points) == 1       # no pose after the stamp yet
    pipe.add_pose(T0 + 10 * MS, _pose(T0 + 10 * MS), received_ns=T0 + 10 * MS)
    assert sink.out == []                                  # added, not yet drained
    pipe.drain()
    assert [o[:2] for o in sink.out] == [("ok", T0 + 5 * MS)] and not pipe.points
    # interpolated at the image stamp
    np.testing.assert_allclose(sink.out[0][2], _expected(T0 + 5 * MS), atol=2e-4)


def test_a_point_that_waited_too_long_is_refused_at_the_check():
    pipe, clock, sink = _pipeline(PipelineRules(max_pose_wait_s=0.2))
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_point(T0 + 5 * MS, P_CAM, COV, received_ns=T0)
    clock.t += 0.1
    assert pipe.tick() and sink.out == []                  # within its wait
    clock.t += 0.2
    assert pipe.tick() and sink.out == []   # ran out: one more check without a pose first
    clock.t += 0.02
    assert not pipe.tick()                                  # refused: nothing waits now
    assert sink.out[0][:3] == ("refused", T0 + 5 * MS, "no_newer_pose")
    assert pipe.refused == {"no_newer_pose": 1}


def test_a_pose_arriving_between_checks_keeps_the_point_waiting():
    pipe, clock, sink = _pipeline(PipelineRules(max_pose_wait_s=0.2))
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_point(T0 + 5 * MS, P_CAM, COV, received_ns=T0)
    clock.t += 0.3
    pipe.tick()
    pipe.add_pose(T0 + 1 * MS, _pose(T0 + 1 * MS), received_ns=T0)   # the executor caught up
    clock.t += 0.02
    assert pipe.tick() and sink.out == []


def test_output_is_fifo_in_arrival_order():
    pipe, _, sink = _pipeline()
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_point(T0 + 20 * MS, P_CAM, COV, received_ns=T0)   # waits
    pipe.add_point(T0 - 10 * MS, P_CAM, COV, received_ns=T0)   # could go, waits behind it
    pipe.add_point(T0 + 10 * MS, P_CAM, COV, received_ns=T0)
    assert sink.out == [] and len(pipe.points) == 3
    pipe.add_pose(T0 + 30 * MS, _pose(T0 + 30 * MS), received_ns=T0)
    pipe.drain()
    assert [o[1] for o in sink.out] == [T0 + 20 * MS, T0 - 10 * MS, T0 + 10 * MS]
    assert [o[0] for o in sink.out] == ["ok", "refused", "ok"]     # before the buffer
    assert sink.out[1][2] == "before_buffer"


def test_a_stale_pose_is_refused():
    pipe, _, sink = _pipeline(max_age_s=0.5)
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_pose(T0 + 10 * MS, _pose(T0 + 10 * MS), received_ns=T0)
    # the point arrives 2 s after the poses were received (on the age clock)
    pipe.add_point(T0 + 5 * MS, P_CAM, COV, received_ns=T0 + 2_000 * MS)
    assert sink.out[0][:3] == ("refused", T0 + 5 * MS, "stale_pose")


def test_poses_taken_only_when_needed_are_pulled_before_a_point_a_frame_and_a_check():
    """A pose source that is not fed on arrival (hand_eye's lazy ee_pose / joint_states) is
    pulled before a point or a frame is queued, so that it is judged on the poses received so
    far (not refused as stale or kept waiting on an old buffer), and at each check."""
    pipe, _, sink = _pipeline(max_age_s=0.5)
    pipe.add_pose(T0, _pose(T0), received_ns=T0 + 1_980 * MS)
    pending = [(T0 + 10 * MS, T0 + 1_990 * MS)]         # received just before the point
    pulls: list[int] = []

    def pull() -> None:
        pulls.append(len(sink.out))
        while pending:
            stamp, received = pending.pop(0)
            pipe.add_pose(stamp, _pose(stamp), received_ns=received)

    pipe.pull_poses = pull
    pipe.add_point(T0 + 5 * MS, P_CAM, COV, received_ns=T0 + 2_000 * MS)
    assert [o[:2] for o in sink.out] == [("ok", T0 + 5 * MS)] and pulls == [0]
    np.testing.assert_allclose(sink.out[0][2], _expected(T0 + 5 * MS), atol=2e-4)
    pending.append((T0 + 30 * MS, T0 + 2_010 * MS))
    pipe.add_frame(T0 + 20 * MS, [Target("a", P_CAM, COV)], received_ns=T0 + 2_020 * MS,
                   carried=True)
    assert [o[:3] for o in sink.out[1:]] == [("target_ok", T0 + 20 * MS, "a"),
                                             ("frame", T0 + 20 * MS)]
    pipe.add_point(T0 + 40 * MS, P_CAM, COV, received_ns=T0 + 2_040 * MS)   # waits
    pending.append((T0 + 50 * MS, T0 + 2_045 * MS))
    assert not pipe.tick() and sink.out[-1][:2] == ("ok", T0 + 40 * MS)
    assert len(pulls) == 4


def test_eye_to_hand_needs_no_pose():
    pipe, _, sink = _pipeline(eye_to_hand=True)
    assert not pipe.needs_pose and pipe.newest_pose_ns is None
    pipe.add_point(T0, P_CAM, COV)
    assert [o[:2] for o in sink.out] == [("ok", T0)]
    np.testing.assert_allclose(sink.out[0][2], (EE_T_CAM @ np.r_[P_CAM, 1.0])[:3])
    with pytest.raises(InputError):
        pipe.add_pose(T0, _pose(T0))


def test_a_full_queue_refuses_the_oldest():
    pipe, _, sink = _pipeline(PipelineRules(max_waiting_points=2))
    for k in range(3):
        pipe.add_point(T0 + k * MS, P_CAM, COV)              # no pose at all: all wait
    assert sink.out == [("refused", T0, "pending_overflow", sink.out[0][3])]
    assert [p.stamp_ns for p in pipe.points] == [T0 + MS, T0 + 2 * MS]


def test_a_point_waits_for_its_covariance_when_one_is_expected():
    pipe, _, sink = _pipeline(cov_expected=lambda: True)
    pipe.add_pose(T0 + 10 * MS, _pose(T0 + 10 * MS), received_ns=T0)
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_point(T0 + 5 * MS, P_CAM, None, received_ns=T0)
    assert sink.out == []
    pipe.add_point_cov(T0 + 5 * MS, COV)
    assert [o[:2] for o in sink.out] == [("ok", T0 + 5 * MS)]
    # a covariance that comes before its point is kept for it
    pipe.add_point_cov(T0 + 7 * MS, COV)
    pipe.add_point(T0 + 7 * MS, P_CAM, None, received_ns=T0)
    assert [o[:2] for o in sink.out][-1] == ("ok", T0 + 7 * MS)
    assert not np.allclose(sink.out[-1][3], 0.0)


def test_flush_resolves_every_waiting_item():
    pipe, _, sink = _pipeline(PipelineRules(max_pose_wait_s=None))
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_point(T0 + 5 * MS, P_CAM, COV, received_ns=T0)
    pipe.tick()
    assert sink.out == []                  # no wait clock: waits until a pose or the end
    pipe.flush()
    assert sink.out[0][:3] == ("refused", T0 + 5 * MS, "no_newer_pose")


def test_a_frame_waits_for_its_points_then_refuses_the_missing_ones():
    pipe, clock, sink = _pipeline(PipelineRules(max_target_wait_s=0.2))
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    pipe.add_pose(T0 + 10 * MS, _pose(T0 + 10 * MS), received_ns=T0)
    pipe.add_frame(T0 + 5 * MS, [Target("a"), Target("b")], received_ns=T0)
    pipe.add_target_point("a", T0 + 5 * MS, P_CAM, COV)
    pipe.drain()
    assert sink.out == []                    # b's point is missing
    clock.t += 0.3
    assert pipe.tick()                       # the frame still waits: the check goes on
    clock.t += 0.02
    assert not pipe.tick()
    assert sink.out == [("target_ok", T0 + 5 * MS, "a", sink.out[0][3]),
                        ("target_refused", T0 + 5 * MS, "b", "no_point"),
                        ("frame", T0 + 5 * MS)]


def test_a_frame_with_carried_points_waits_for_its_pose_only():
    pipe, _, sink = _pipeline()
    pipe.add_pose(T0, _pose(T0), received_ns=T0)
    frame_targets = [Target("a", P_CAM, COV), Target("b", P_CAM + 0.01, None)]
    pipe.add_frame(T0 + 5 * MS, frame_targets, received_ns=T0, carried=True, tag="F")
    assert sink.out == [] and pipe.frames[0].tag == "F" and pipe.targets_waiting == 2
    pipe.add_pose(T0 + 10 * MS, _pose(T0 + 10 * MS), received_ns=T0)
    pipe.drain()
    assert [o[:3] for o in sink.out] == [("target_ok", T0 + 5 * MS, "a"),
                                         ("target_ok", T0 + 5 * MS, "b"),
                                         ("frame", T0 + 5 * MS)]
    np.testing.assert_allclose(sink.out[0][3], _expected(T0 + 5 * MS), atol=2e-4)


def test_unlisted_target_points_are_dropped_as_orphans():
    pipe, _, sink = _pipeline(eye_to_hand=True)
    pipe.add_target_point("x", T0, P_CAM, COV)          # no frame lists it
    pipe.add_target_point("a", T0 + MS, P_CAM, COV)
    pipe.add_frame(T0 + MS, [Target("a")])
    assert ("orphans", 1) in sink.out and ("frame", T0 + MS) in sink.out


def test_joint_states_through_the_chain():
    chain = DHChain.ur5e()
    pipe, _, sink = _pipeline(kinematics=chain)
    names = list(reversed(chain.joint_names)) + ["gripper"]
    q = np.linspace(0.1, 0.6, len(chain.joint_names))
    pipe.add_joint_state(T0, names, list(q[::-1]) + [0.0], received_ns=T0)
    assert pipe.newest_pose_ns == T0
    np.testing.assert_allclose(pipe.localizer.poses.lookup(T0, 1), chain.fk(q))
    with pytest.raises(InputError):
        pipe.add_joint_state(T0 + MS, ["shoulder_pan_joint"], [0.0])


def test_rules_are_checked():
    with pytest.raises(InputError):
        PipelineRules(max_pose_wait_s=-1.0)
    with pytest.raises(InputError):
        PipelineRules(max_waiting_frames=0)
