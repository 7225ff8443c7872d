"""The ``hand_eye`` node's robot pose side: the localizers and the robot pose input.

Parts of :class:`eye_in_hand.nodes.hand_eye.HandEyeNode`, built with explicit arguments:
:func:`build_localizers` makes the :class:`~eye_in_hand.core.localization.Localizer` (robot
pose noise from the parameters, raised to ``hand_eye.yaml``'s, and its robot pose correction)
and, eye-to-hand, the fixed camera's
:class:`~eye_in_hand.core.eye_to_hand.EyeToHandLocalizer`; :class:`RobotPoseInput` feeds the
node's :class:`~eye_in_hand.core.pipeline.LocalizationPipeline` from ``ee_pose``
(PoseStamped), ``joint_states`` (JointState, through the pipeline's kinematics) or ``/tf`` +
``/tf_static`` (:class:`~eye_in_hand.nodes.hand_eye_tf.TfInput`), and clears the pose buffer
when the stream stopped or time jumped back.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState

from eye_in_hand.core.eye_to_hand import EyeToHandLocalizer
from eye_in_hand.core.localization import Localizer, robot_pose_sigmas
from eye_in_hand.core.pipeline import LocalizationPipeline, localizer_config
from eye_in_hand.errors import ConversionError, EyeInHandError, InputError
from eye_in_hand.io.bags.decoding import jazzy_decoder
from eye_in_hand.io.cdr import pose_stamped_from_cdr
from eye_in_hand.nodes.hand_eye_tf import TfInput
from eye_in_hand.ros.decoded import decode_each, decoded_subscription, undecodable
from eye_in_hand.ros.executor import (
    is_passive,
    reception_times_known,
    set_passive,
    take_queued,
)
from eye_in_hand.ros.geometry import pose_stamped_fields, pose_values_to_matrix
from eye_in_hand.ros.qos import ROBOT_POSE_QOS
from eye_in_hand.ros.stamps import header_stamp_ns, sec_nanosec_to_ns

__all__ = ["build_localizers", "RobotPoseInput", "ee_pose_decoder", "fields_decoder", "PoseFields"]


def build_localizers(config: Any, calibration: Any
                     ) -> tuple[Localizer, EyeToHandLocalizer | None]:
    """The localizer of the robot poses and, eye-to-hand, the fixed camera's.

    Args:
        config: the node's configuration (pose rules, ``pose_buffer_size``, robot sigmas).
        calibration: the loaded ``hand_eye.yaml`` (:class:`eye_in_hand.io.config.
            HandEyeCalibration`), or None (calibration mode: X is what is being estimated).

    Returns:
        The :class:`Localizer` (eye-in-hand: ``ee_T_cam``, its covariance and robot pose
        correction; otherwise the identity, an empty pose buffer for the calibration mode) and
        the :class:`EyeToHandLocalizer` of ``base_T_cam`` (a calibration with ``setup:
        eye_to_hand``: the camera does not move with the arm; else None): the same code as
        ``process``.
    """
    cfg = config
    eye_to_hand = calibration is not None and calibration.setup == "eye_to_hand"
    ee_T_cam, cov = np.eye(4), None
    if calibration is not None and not eye_to_hand:
        ee_T_cam, cov = calibration.transform, calibration.covariance
    # robot pose noise: the arm's stated accuracy (robot_sigma_* parameters), raised to
    # hand_eye.yaml's robot_pose_noise (estimated while calibrating) where that is larger
    sig_pos, sig_rot = robot_pose_sigmas(
        cfg.robot_sigma_pos_m, cfg.robot_sigma_rot_rad,
        None if calibration is None else calibration.robot_pose_noise)
    localizer = Localizer(ee_T_cam, cov, localizer_config(
        max_pose_gap_s=cfg.max_pose_gap_s, max_pose_age_s=cfg.max_pose_age_s,
        pose_jump_back_s=cfg.pose_jump_back_s, buffer_size=cfg.pose_buffer_size,
        robot_sigma_pos_m=sig_pos, robot_sigma_rot_rad=sig_rot),
        pose_correction=(None if calibration is None or eye_to_hand
                         else calibration.robot_pose_correction))
    fixed = None
    if eye_to_hand:
        fixed = EyeToHandLocalizer(calibration.transform, calibration.covariance)
    return localizer, fixed


#: an ``ee_pose`` as :func:`ee_pose_decoder` gives it: ``(sec, nanosec, frame_id, (x, y, z,
#: qx, qy, qz, qw))``
PoseFields = tuple[int, int, str, tuple[float, ...]]


def fields_decoder(direct: Callable[[bytes], Any], from_message: Callable[[Any], Any]
                   ) -> Callable[[str], Callable[[bytes], Any]]:
    """``decoder_for(msgtype)`` of a :func:`eye_in_hand.ros.decoded.decoded_subscription`
    whose callback takes a message's fields: little-endian CDR bytes read directly by
    ``direct`` (``eye_in_hand.io.cdr``'s readers, 1-9 us), other encodings through the
    generic decoder and ``from_message`` (the same fields from the message object). The
    values are checked where they are taken; malformed bytes raise (the subscription reports
    them)."""
    def decoder_for(msgtype: str) -> Callable[[bytes], Any]:
        generic = jazzy_decoder(msgtype)

        def decode(raw: bytes) -> Any:
            fields = direct(raw)
            return fields if fields is not None else from_message(generic(raw))

        return decode

    return decoder_for


#: ``decode(raw)`` of ``ee_pose`` (``geometry_msgs/msg/PoseStamped``) bytes into its fields
#: (:data:`PoseFields`), checked where the pose is taken (``pose_values_to_matrix``, with the
#: errors of ``pose_to_matrix``)
ee_pose_decoder = fields_decoder(pose_stamped_from_cdr, pose_stamped_fields)


class RobotPoseInput:
    """The robot pose in: ``ee_pose``, ``joint_states`` or ``/tf`` (``robot_pose_source``).

    Args:
        node: the rclpy node (subscriptions, log).
        config: the node's configuration (``base_frame``, ``max_pose_age_s``,
            ``stale_after_s``; :class:`~eye_in_hand.nodes.hand_eye_tf.TfInput`'s).
        pipeline: the node's pipeline, which the poses go into (``add_pose``,
            ``add_joint_state``; ``pose_arrived`` when the TF chain reached a newer stamp).
        localizer: the pipeline's :class:`Localizer` (its ``poses``: the buffer cleared by
            :meth:`expire`, replaced by the TF view with ``/tf``).
        diag: the node's diagnostics (counter ``robot_poses``, ``pose_buffer_resets.*``).
        now_ns: the node's clock (sim time under ``use_sim_time``): the receive times.
        after_pose: called after each robot pose (the node drains the pipeline or answers
            the captures waiting for it).
        source: ``ee_pose``, ``joint_states`` or ``tf``; None: no robot pose is subscribed
            (a fixed camera localizes without one).
    """

    def __init__(self, node: Any, config: Any, pipeline: LocalizationPipeline,
                 localizer: Localizer, diag: Any, now_ns: Callable[[], int],
                 after_pose: Callable[[], None], source: str | None) -> None:
        self._log = node.get_logger()
        self._config = config
        self.pipeline = pipeline
        self._localizer = localizer
        self.diag = diag
        self._now_ns = now_ns
        self._after = after_pose
        #: the TF input (``robot_pose_source: tf``), else None
        self.tf: TfInput | None = None
        #: the ``ee_pose`` or ``joint_states`` subscription, its message handler
        self._sub: Any = None
        self._take: Callable[[Any, int], bool] = self._take_ee_pose
        self._bad_cause = "bad_ee_pose"        # the diagnostics cause of a refused pose
        #: poses taken when needed (:meth:`take_when_needed`), not as each arrives
        self.lazy = False
        self._on_system_clock: Callable[[], bool] = lambda: True
        if source == "ee_pose":
            self._sub = decoded_subscription(node, PoseStamped, "ee_pose", self._on_ee_pose,
                                             ROBOT_POSE_QOS, decoder_for=ee_pose_decoder,
                                             on_bad=self._undecodable)
        elif source == "tf":
            self.tf = TfInput(node, config, localizer, diag, now_ns, self._after_tf_pose)
        elif source == "joint_states":
            self._sub = decoded_subscription(node, JointState, "joint_states",
                                             self._on_joint_state, ROBOT_POSE_QOS,
                                             decoder_for=jazzy_decoder,
                                             on_bad=self._undecodable)
            self._take = self._take_joint_state
            self._bad_cause = "bad_joint_states"
        diag.declare_counter("robot_poses")
        if source is not None:
            diag.stale_after("robot_poses", config.stale_after_s)

    # -- taking poses when they are needed ---------------------------------------------------
    def take_when_needed(self, on_system_clock: Callable[[], bool]) -> bool:
        """Take ``ee_pose`` / ``joint_states`` messages when a point or a frame needs them
        (:meth:`poll`) instead of waking the node for each one: the subscription becomes
        passive (:func:`eye_in_hand.ros.executor.set_passive`) and each pose keeps its
        reception time from the middleware (system clock: only for a node on it, not on
        ``use_sim_time``). The same poses reach the pipeline, in order and before anything
        that needs them; their receive times are the middleware's (a few tens of us before a
        callback would read the clock). ``on_system_clock``: whether the node's clock is still the
        system clock (``use_sim_time`` switched on at run time ends the lazy mode: from then
        on every pose is taken on arrival, its receive time on ``/clock``). Returns False for
        ``/tf``, no pose source, or a middleware whose reception times are not known to be
        stamped at reception (:func:`~eye_in_hand.ros.executor.reception_times_known`):
        every pose is then taken as it arrives."""
        if self._sub is None or not reception_times_known():
            return False
        self._on_system_clock = on_system_clock
        self.lazy = True
        set_passive(self._sub, True)
        return True

    def wake_for_poses(self, wake: bool) -> None:
        """While a point or a frame waits for a newer pose: take each pose as it arrives
        (``wake``), so that the wait ends with it; passive again when nothing waits."""
        if self.lazy:
            set_passive(self._sub, not wake)

    def poll(self) -> None:
        """Take the poses queued since the last take into the pipeline (lazy only), then
        what follows new poses, once: the pipeline's drain."""
        if not self.lazy or not is_passive(self._sub):
            # active (a point waits): the executor delivers the poses in order with the other
            # topics; a pull now could take poses newer than ones it has taken but not yet
            # delivered, and bracket a point across them
            return
        queued = decode_each(self._sub, take_queued(self._sub), self._undecodable)
        if not self._on_system_clock():
            # use_sim_time switched on: receive ages are on /clock now, which the middleware's
            # reception times are not; these poses get the node's clock, later ones their
            # callbacks
            self.lazy = False
            set_passive(self._sub, False)
            queued = [(msg, self._now_ns()) for msg, _ in queued]
        else:
            now = self._now_ns()     # a reception time of 0 or in the future: the take's
            queued = [(msg, t if 0 < t <= now else now) for msg, t in queued]
        taken = 0
        for msg, received_ns in queued:
            if self._take(msg, received_ns):
                taken += 1
        if taken:
            self.diag.count("robot_poses", taken)
            self._after()

    # -- the messages ---------------------------------------------------------------------------
    def _undecodable(self, topic: str, exc: Exception) -> None:
        """A robot pose whose bytes do not decode: reported, not used."""
        self.diag.report(self._bad_cause, undecodable(topic, exc))

    def _on_ee_pose(self, fields: PoseFields) -> None:
        if self._take_ee_pose(fields, self._now_ns()):
            self._after_pose()

    def _on_joint_state(self, msg: JointState) -> None:
        if self._take_joint_state(msg, self._now_ns()):
            self._after_pose()

    def _take_ee_pose(self, fields: PoseFields, received_ns: int) -> bool:
        """One ``ee_pose`` (its fields, :func:`ee_pose_decoder`) into the pipeline; False
        (reported) when it is refused."""
        sec, nanosec, frame, values = fields
        try:
            stamp = sec_nanosec_to_ns(sec, nanosec, "header.stamp")
            if frame and frame.lstrip("/") != self._config.base_frame:
                self.diag.report("ee_pose_frame", f"ee_pose in frame {frame!r}, expected "
                                 f"{self._config.base_frame!r}: ignored")
                return False
            self._pose_added(stamp, self.pipeline.add_pose(stamp, pose_values_to_matrix(values),
                                                           received_ns=received_ns,
                                                           checked=True))
        except (ConversionError, InputError) as exc:
            self.diag.report("bad_ee_pose", f"ee_pose: {exc}")
            return False
        return True

    def _take_joint_state(self, msg: JointState, received_ns: int) -> bool:
        """One ``joint_states`` message into the pipeline; False (reported) when refused."""
        try:
            stamp = header_stamp_ns(msg)
            self._pose_added(stamp, self.pipeline.add_joint_state(
                stamp, msg.name, msg.position, received_ns=received_ns))
        except (ConversionError, InputError, EyeInHandError) as exc:
            self.diag.report("bad_joint_states", f"joint_states: {exc}")
            return False
        return True

    def _pose_added(self, stamp: int, jumped: bool) -> None:
        """A robot pose went into the pipeline (with its receive time); ``jumped``: a time
        jump back cleared the pose buffer first."""
        if jumped:
            self.diag.count("pose_buffer_resets.time_jump")
            self._log.info(f"robot pose time jumped back (stamp {stamp} ns): pose "
                           "buffer cleared, earlier poses are never used again")

    def _after_tf_pose(self) -> None:
        self.pipeline.pose_arrived()     # the TF view in the localizer reached a newer stamp
        self._after_pose()

    def _after_pose(self) -> None:
        self.diag.count("robot_poses")
        self._after()

    def expire(self) -> None:
        """Clear the pose buffer when the stream stopped or the clock jumped back (the poses
        queued so far taken first)."""
        self.poll()
        cause = self._localizer.poses.expire(self._now_ns(),
                                             int(self._config.max_pose_age_s * 1e9))
        if cause is not None:
            self.diag.count(f"pose_buffer_resets.{cause}")
            self._log.info(f"robot pose buffer cleared ({cause.replace('_', ' ')})")
