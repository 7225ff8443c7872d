"""Messages of a live hand-eye calibration: eye_in_hand_interfaces, next poses, their markers.

The ``hand_eye`` node's calibration mode (:mod:`eye_in_hand.nodes.hand_eye_calibration`)
publishes and answers with these, built from the ROS-free
:class:`eye_in_hand.core.handeye.session.CalibrationSession`'s values:
``CalibrationStatus`` (``~/calibration_status``, ``GetStatus``), ``HandEyeSample``
(``Capture``, ``ListSamples``), the ``Compute`` response, the suggested next flange poses
(``geometry_msgs/PoseArray``, ``~/next_poses``) and their ``visualization_msgs/MarkerArray``
(``~/next_pose_markers``: the board where the estimate puts it, an arrow and a rank per pose).

``eye_in_hand_interfaces`` is built into the venv by ``tools/build_interfaces.py`` (a colcon
package on a ROS install); without it :func:`have_interfaces` is False and only the
std_srvs/Trigger services are offered.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseArray, TransformStamped

from eye_in_hand.ros.geometry import matrix_to_pose, matrix_to_transform
from eye_in_hand.ros.markers import marker_classes
from eye_in_hand.ros.stamps import ns_to_stamp

iface_msg: Any
iface_srv: Any
try:  # built into the venv by tools/build_interfaces.py; a colcon package on a ROS install
    from eye_in_hand_interfaces import msg as iface_msg
    from eye_in_hand_interfaces import srv as iface_srv
except ImportError:  # pragma: no cover - the Trigger services remain
    iface_msg = iface_srv = None

__all__ = ["iface_msg", "iface_srv", "have_interfaces", "pose_array", "transform_message",
           "next_pose_markers", "sample_message", "status_message", "fill_compute_response"]


def have_interfaces() -> bool:
    """Whether eye_in_hand_interfaces is importable (the typed services exist)."""
    return iface_srv is not None


def _nan(v: float | None) -> float:
    return float("nan") if v is None else float(v)


def _cov36(cov: np.ndarray | None) -> list[float]:
    return [0.0] * 36 if cov is None else [float(v) for v in np.asarray(cov).ravel()]


def _std_from_cov(cov: np.ndarray | None) -> tuple[float, float]:
    if cov is None:
        return float("nan"), float("nan")
    c = np.asarray(cov)
    return (1000.0 * math.sqrt(max(float(np.trace(c[:3, :3])), 0.0)),
            math.degrees(math.sqrt(max(float(np.trace(c[3:, 3:])), 0.0))))


def pose_array(poses: Sequence[np.ndarray], stamp: Any, frame_id: str) -> PoseArray:
    """``geometry_msgs/PoseArray`` of 4x4 poses (``stamp``: a ``builtin_interfaces/Time``)."""
    msg = PoseArray()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.poses = [matrix_to_pose(T) for T in poses]
    return msg


def transform_message(X: np.ndarray, stamp: Any, parent: str, child: str) -> TransformStamped:
    """``geometry_msgs/TransformStamped`` ``parent -> child`` of the 4x4 ``X``."""
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = parent
    msg.child_frame_id = child
    msg.transform = matrix_to_transform(X)
    return msg


def next_pose_markers(poses: PoseArray, board: Any, board_pose: np.ndarray | None,
                      board_frame: str) -> Any:
    """``visualization_msgs/MarkerArray`` of the suggested poses: DELETEALL; the board (a
    grey plate at ``board_pose``, the board's origin in ``board_frame``, when there is an
    estimate); per pose, best first, an arrow and its rank."""
    Marker, MarkerArray = marker_classes()
    markers = [Marker(header=poses.header, action=Marker.DELETEALL)]
    if board_pose is not None:   # the board where the estimate puts it (base or flange frame)
        b = board
        w, h = (b.cols + 1) * b.square, (b.rows + 1) * b.square
        centre = np.eye(4)
        centre[:3, 3] = [(b.cols - 1) * b.square / 2, (b.rows - 1) * b.square / 2, 0.002]
        m = Marker(header=poses.header, ns="board", id=0, type=Marker.CUBE,
                   action=Marker.ADD, pose=matrix_to_pose(board_pose @ centre))
        m.header.frame_id = board_frame
        m.scale.x, m.scale.y, m.scale.z = w, h, 0.004
        m.color.r = m.color.g = m.color.b = 0.85
        m.color.a = 0.8
        markers.append(m)
    for k, pose in enumerate(poses.poses):
        m = Marker(header=poses.header, ns="next_pose", id=k, type=Marker.ARROW,
                   action=Marker.ADD, pose=pose)
        m.scale.x, m.scale.y, m.scale.z = 0.1, 0.01, 0.01
        m.color.r, m.color.g, m.color.b, m.color.a = 0.1, 0.9 - 0.25 * k, 0.2, 1.0
        markers.append(m)
        t = Marker(header=poses.header, ns="next_pose_rank", id=k, type=Marker.TEXT_VIEW_FACING,
                   action=Marker.ADD, pose=pose, text=str(k + 1))
        t.scale.z = 0.04
        t.color.r = t.color.g = t.color.b = t.color.a = 1.0
        markers.append(t)
    return MarkerArray(markers=markers)


def sample_message(index: int, record: Any) -> Any:
    """``eye_in_hand_interfaces/HandEyeSample`` of a session's
    :class:`~eye_in_hand.core.handeye.session.SampleRecord`."""
    r = record
    return iface_msg.HandEyeSample(
        index=index, name=r.sample.name, stamp=ns_to_stamp(r.stamp_ns),
        robot_pose=matrix_to_pose(r.sample.base_T_ee),
        board_pose=matrix_to_pose(r.sample.cam_T_board), corners=r.corners,
        reprojection_error_px=float(r.reprojection_px))


def status_message(st: Any, stamp: Any, loaded: tuple[np.ndarray, np.ndarray | None, str]
                   | None, next_poses: PoseArray) -> Any:
    """``eye_in_hand_interfaces/CalibrationStatus`` of a session's
    :class:`~eye_in_hand.core.handeye.session.SessionStatus`.

    Args:
        st: the status.
        stamp: its ``builtin_interfaces/Time``.
        loaded: (X, covariance, method) of a loaded calibration, shown when the status has
            no estimate of its own.
        next_poses: the suggested next flange poses.
    """
    msg = iface_msg.CalibrationStatus(
        setup=st.setup, samples=st.samples, skipped=st.skipped, min_samples=st.min_samples,
        rotation_spread_deg=float(st.rotation_spread_deg),
        axis_spread_deg=float(st.axis_spread_deg), axis_diversity=float(st.axis_diversity),
        good_enough=st.good_enough, problems=list(st.problems),
        std_mm=float(st.std_mm), std_deg=float(st.std_deg))
    msg.stamp = stamp
    est = None
    if st.result is not None:
        est = (st.result.X, st.result.covariance, st.result.selected)
    elif loaded is not None:
        est = loaded
        msg.std_mm, msg.std_deg = _std_from_cov(loaded[1])
    if est is not None:
        msg.has_estimate = True
        msg.estimate = matrix_to_transform(est[0])
        msg.covariance = _cov36(est[1])
        msg.method = est[2]
    msg.next_poses = next_poses
    return msg


def fill_compute_response(response: Any, res: Any, transform: TransformStamped) -> Any:
    """Fill a successful ``Compute`` response from a
    :class:`~eye_in_hand.core.handeye.HandEyeResult` (``transform``: its X as a message)."""
    sel = res.methods[res.selected]
    response.success = True
    response.message = (f"{res.selected} from {len(res.sample_names)} samples, 1-sigma "
                        f"{sel.std_mm:.3f} mm / {sel.std_deg:.4f} deg")
    response.transform = transform
    response.covariance = _cov36(res.covariance)
    response.std_mm, response.std_deg = float(sel.std_mm), float(sel.std_deg)
    response.selected_method = res.selected
    response.selection_reason = res.selection_reason
    scores = []
    for name, mr in res.methods.items():
        ho = mr.held_out.summary() if mr.held_out is not None else {}
        scores.append(iface_msg.MethodScore(
            method=name, score=_nan(res.selection_scores.get(name)),
            held_out_px=_nan(ho.get("px_rms")), held_out_mm=_nan(ho.get("mm_rms")),
            std_mm=float(mr.std_mm), std_deg=float(mr.std_deg)))
    response.scores = scores
    response.rejected_samples = [f"{r.name}: {r.reason}" for r in res.rejected]
    response.warnings = list(res.warnings)
    return response
