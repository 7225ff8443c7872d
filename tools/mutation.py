"""Mutation testing: plant known bugs in core/, io/, nodes/ and the offline path, one at a time.

Each mutant is a small, realistic bug (a frame left unrotated, a tie rule flipped, a sort
removed, a term dropped, a standard error taken for a standard deviation): one exact text
replacement of (usually) one line in one source file. :data:`TESTS` maps every mutated module
to its own test files, once; a mutant runs only those (``pytest -x``), so the whole table
stays fast. A mutant is *caught* when the tests fail, *survives* when they pass, and is
*stale* when its text is no longer (once) in the file: the code moved on, so update the
mutant's text (keep it to the one line the bug is on, so re-anchoring stays easy).

Mutants are planted in private copies of the source tree (one per worker, under a temporary
directory, put first on the tests' import path), never in the working tree: a run can be
interrupted or run beside an editor. ``-j`` runs mutants on that many workers (default 2).

Usage::

    make mutation                          # every mutant, 2 workers
    .venv/bin/python tools/mutation.py -k select -v
    .venv/bin/python tools/mutation.py --list   # the table and stale mutants, no tests run
    .venv/bin/python tools/mutation.py --baseline   # each module's tests pass unmutated

Prints one line per mutant, the score (caught / live mutants) and the wall time. Exit status
1 when a mutant survives or is stale, so CI (``.ci/run``) insists on a full score.

The habit: a new module, or a new rule in an old one, lands in the same commit as its
planted-bug entries here (and its module's row of :data:`TESTS`); see docs/development.md.
"""
from __future__ import annotations

import argparse
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PKG = "eye_in_hand/"

#: Each mutated module (path under eye_in_hand/) and its own tests: the only tests its
#: mutants run. Cheapest and most direct tests first (``-x`` stops at the first failure).
TESTS: dict[str, tuple[str, ...]] = {
    "core/transforms.py": ("test/core/test_transforms.py", "test/core/test_quat_scipy.py",
                           "test/core/test_sync.py"),
    "core/camera.py": ("test/core/test_camera.py", "test/core/test_hot_path_bits.py"),
    "core/assignment.py": ("test/core/test_assignment.py",),
    "core/kinematics.py": ("test/core/test_kinematics.py",),
    "core/sync.py": ("test/core/test_heldout_rules.py", "test/core/test_sync_rules.py",
                     "test/core/test_sync.py"),
    "core/tf.py": ("test/core/test_heldout_rules.py", "test/core/test_tf_staleness.py",
                   "test/core/test_tf.py"),
    "core/triangulation.py": ("test/core/test_hot_path_bits.py",
                              "test/core/test_triangulation_covariance.py",
                              "test/core/test_triangulation.py"),
    "core/detection.py": ("test/core/test_heldout_rules.py",
                          "test/core/test_hot_path_bits.py",
                          "test/core/test_center_sigma_edge.py",
                          "test/core/test_center_sigma_blur_law.py",
                          "test/core/test_detection_minor_axis.py",
                          "test/core/test_detection.py"),
    "core/locator.py": ("test/core/test_heldout_rules.py", "test/core/test_locator_blobs.py",
                        "test/core/test_locator.py"),
    "core/localization.py": ("test/core/test_localization_sources.py",
                             "test/core/test_localization.py",
                             "test/core/test_localization_robot_error.py",
                             "test/core/test_pose_correction.py"),
    "core/pose_correction.py": ("test/core/test_pose_correction.py",
                                "test/core/test_handeye_systematic.py"),
    "core/eye_to_hand.py": ("test/core/test_eye_to_hand.py",),
    "core/pipeline.py": ("test/core/test_pipeline.py", "test/nodes/test_hand_eye.py"),
    "core/distances.py": ("test/core/test_heldout_rules.py", "test/core/test_distances.py"),
    "core/handeye/solvers.py": ("test/core/test_handeye_solvers.py",),
    "core/handeye/average.py": ("test/core/test_handeye_heldout_rules.py",
                                "test/core/test_handeye_average.py"),
    "core/handeye/refine.py": ("test/core/test_handeye_refine_rules.py",
                               "test/core/test_handeye_refine.py"),
    "core/handeye/eiv.py": ("test/core/test_handeye_eiv_rules.py",
                            "test/core/test_handeye_heldout_rules.py",
                            "test/core/test_handeye_eiv.py"),
    "core/handeye/select.py": ("test/core/test_handeye_heldout_rules.py",
                               "test/core/test_handeye_select_rules.py",
                               "test/core/test_handeye_held_out_noise.py",
                               "test/core/test_handeye_eiv.py"),
    "core/handeye/calibrate.py": ("test/core/test_handeye_calibrate_rules.py",
                                  "test/core/test_handeye_held_out_noise.py",
                                  "test/core/test_handeye_refine.py",
                                  "test/core/test_handeye_eiv.py",
                                  "test/core/test_handeye_systematic.py"),
    "core/handeye/session.py": ("test/core/test_handeye_session.py",
                                "test/core/handeye/test_session_flow.py"),
    "core/handeye/systematic.py": ("test/core/test_handeye_heldout_rules.py",
                                   "test/core/test_handeye_systematic.py"),
    "core/handeye/budget.py": ("test/core/test_handeye_heldout_rules.py",
                               "test/core/test_handeye_systematic.py"),
    "core/calibration/detection.py": ("test/core/test_heldout_rules.py",
                                      "test/core/test_calibration_opencv_data.py",
                                      "test/core/test_calibration_board.py"),
    "core/handeye/plan.py": ("test/core/test_handeye_heldout_rules.py",
                             "test/core/test_handeye_plan.py"),
    "io/bag_samples.py": (
        "test/commands/test_calibrate_handeye_bag.py::"
        "test_bag_stops_rotation_window_and_middle_image",
        "test/commands/test_calibrate_handeye_bag.py::test_a_slow_drift_is_not_one_stop",
        "test/commands/test_calibrate_handeye_bag.py"),
    "io/bags/reading.py": ("test/io/test_mcap_recovery_order.py", "test/io/test_bags.py"),
    "io/bags/storage_mcap.py": ("test/io/test_storage_formats.py",
                                "test/io/test_chunk_table.py"),
    "io/bags/chunk_table.py": ("test/io/test_chunk_table.py",),
    "io/bags/writing.py": ("test/io/test_bags.py",),
    "io/bags/mcap_records.py": ("test/io/test_mcap_recovery_order.py",
                                "test/io/test_mcap_chunks.py"),
    "io/pages.py": ("test/io/test_pages.py",),
    "io/spill.py": ("test/io/test_spill.py",),
    "io/results.py": ("test/io/test_results.py",),
    "io/bags/mcap_tasks.py": ("test/io/test_mcap_tasks.py",),
    "io/bags/mcap_chunks.py": ("test/io/test_mcap_recovery_order.py",
                               "test/io/test_mcap_chunks.py"),
    "io/cdr.py": ("test/io/test_cdr.py",),
    "io/atomic.py": ("test/io/test_atomic.py",),
    "io/config.py": ("test/io/test_config_handeye.py", "test/core/test_pose_correction.py"),
    "io/datasets.py": ("test/io/test_datasets_handeye.py",),
    "ros/bag_queues.py": ("test/ros/test_bag_queues.py",),
    "nodes/bag_player_pacing.py": ("test/commands/test_play.py",),
    "nodes/bag_player_topics.py": ("test/commands/test_play_tf.py",),
    "ros/qos.py": ("test/commands/test_record_definitions.py::"
                   "test_subscription_qos_matches_every_publisher",
                   "test/commands/test_play.py::test_playback_qos_follows_the_recording"),
    "io/frame_sources.py": (
        "test/nodes/test_stereo_capture.py::test_video_source_splits_side_by_side_frames",
        "test/nodes/test_stereo_capture.py"),
    "sim/frame_source.py": (
        "test/nodes/test_stereo_capture.py::"
        "test_followed_pair_carries_the_stamp_of_the_joint_state_it_shows",
        "test/nodes/test_stereo_capture.py"),
    "nodes/hand_eye.py": ("test/nodes/test_hand_eye.py", "test/nodes/test_localize.py",
                          "test/nodes/test_every_target.py"),
    "nodes/hand_eye_poses.py": ("test/nodes/test_hand_eye.py", "test/nodes/test_localize.py",
                                "test/nodes/test_every_target.py"),
    "nodes/hand_eye_first_target.py": ("test/nodes/test_hand_eye.py",
                                       "test/nodes/test_localize.py",
                                       "test/nodes/test_every_target.py"),
    "nodes/detect_triangulate.py": ("test/nodes/test_detect_triangulate.py",),
    "nodes/localize.py": ("test/nodes/test_localize.py",),
    "ros/queues.py": ("test/ros/test_queues.py",),
    "ros/publishers.py": ("test/ros/test_publishers.py",),
    "ros/executor.py": ("test/ros/test_executor.py",),
    "memory.py": ("test/test_memory.py",),
    "threads.py": ("test/test_blas_threads.py",),
    "ros/outputs_cdr.py": ("test/ros/test_outputs_cdr.py",),
    "ros/outputs.py": ("test/ros/test_outputs_cdr.py", "test/ros/test_outputs.py"),
    "ros/decoded.py": ("test/ros/test_decoded.py",
                       "test/nodes/test_hand_eye.py::"
                       "test_bad_points_are_counted_and_node_keeps_running"),
    "ros/node_main.py": ("test/test_entry_guards.py::test_every_node_main_prepares_its_process",),
    "nodes/hand_eye_targets.py": ("test/nodes/test_localize.py",
                                  "test/nodes/test_every_target.py"),
    "offline.py": ("test/test_offline.py",
                   "test/test_tf_robot_bag.py::test_live_replay_with_tf_gives_the_offline_numbers",
                   "test/commands/test_process_targets.py",
                   "test/commands/test_process_multi_world.py"),
    "workers.py": ("test/test_workers.py",),
    "nodes/parameters.py": ("test/test_param_files.py",),
}


@dataclass(frozen=True)
class Mutant:
    name: str
    module: str        # path under eye_in_hand/, a key of TESTS
    old: str           # exact text, must occur exactly once
    new: str
    what: str

    @property
    def path(self) -> str:
        return PKG + self.module

    @property
    def tests(self) -> tuple[str, ...]:
        return TESTS[self.module]


M = Mutant

MUTANTS: tuple[Mutant, ...] = (
    # -- core/transforms.py
    M("slerp-shorter-arc", "core/transforms.py",
      "    if sum(a * b for a, b in zip(q0, q1, strict=True)) < 0.0:\n", "    if False:\n",
      "pose interpolation takes the longer arc when quaternion signs differ"),
    M("lerp-weights", "core/transforms.py",
      "    out[:3, 3] = (1.0 - s) * A[:3, 3] + s * B[:3, 3]\n",
      "    out[:3, 3] = s * A[:3, 3] + (1.0 - s) * B[:3, 3]\n",
      "translation interpolation weights swapped"),
    # -- core/camera.py, core/kinematics.py
    M("camera-behind", "core/camera.py",
      "        ok = pts[:, 2] > 0\n", "        ok = pts[:, 2] != 0\n",
      "points behind the camera projected (mirrored) instead of NaN"),
    M("camera-rectify-rotation", "core/camera.py",
      "cv2.undistortPoints(pts, self.K, self.dist, None, self.R, self.P[:3, :3],",
      "cv2.undistortPoints(pts, self.K, self.dist, None, None, self.P[:3, :3],",
      "rectified pixels without the rectification rotation"),
    M("camera-direction-undistorted", "core/camera.py",
      "        img, _ = cv2.projectPoints(np.array([[[x, y, 1.0]]]), _NO_MOTION, _NO_MOTION, self.K,\n"
      "                                   self.dist)\n",
      "        img, _ = cv2.projectPoints(np.array([[[x, y, 1.0]]]), _NO_MOTION, _NO_MOTION, self.K,\n"
      "                                   None)\n",
      "one direction projected without the lens distortion"),
    M("kinematics-dh-alpha", "core/kinematics.py",
      "        [st, ct * ca, -ct * sa, a * st],\n", "        [st, ct * ca, ct * sa, a * st],\n",
      "the DH link twist's sign flipped in one entry"),
    # -- core/sync.py
    M("sync-tie-rule", "core/sync.py",
      "            if gap <= abs(a2 - b):\n", "            if gap < abs(a2 - b):\n",
      "stereo pairing tie goes to the later frame"),
    M("sync-repeated-stamp", "core/sync.py",
      "if last_side is not None and stamp <= last_side:",
      "if last_side is not None and stamp < last_side:",
      "a repeated stamp on one side is queued instead of dropped"),
    M("pose-receive-age", "core/sync.py",
      "        if now - oldest > max_age_ns:\n", "        if False:\n",
      "a robot pose received long ago is used (stale pose)"),
    M("pose-gap-limit", "core/sync.py",
      "        if s1 - s0 > gap_limit:\n", "        if s1 - s0 > 2 * gap_limit:\n",
      "robot poses bracketing an image stamp accepted across twice the gap limit"),
    # -- core/tf.py
    M("tf-receive-age", "core/tf.py",
      "        self._receipts.check_age(stamp_ns, now_ns, max_age_ns)\n", "",
      "the TF robot pose skips the receive-age rule"),
    M("tf-interpolation", "core/tf.py",
      "        return self.history.lookup(stamp_ns, max_gap_ns)\n",
      "        return self.history.lookup(self.history.newest_ns, max_gap_ns)\n",
      "a TF edge answers with its newest sample instead of interpolating at the stamp"),
    M("tf-newest-target-side", "core/tf.py",
      "        for child in up_t[:-1] + up_s[:-1]:\n"
      "            n = self._edges[child].newest_ns()",
      "        for child in up_s[:-1]:\n            n = self._edges[child].newest_ns()",
      "newest_ns ignores the dynamic edges on the target frame's side of the chain"),
    M("tf-oldest", "core/tf.py",
      "                oldest = max(oldest, o)\n", "                oldest = min(oldest, o)\n",
      "oldest_ns of a chain is its oldest edge's instead of the latest start"),
    # -- core/triangulation.py
    M("triangulation-frame", "core/triangulation.py",
      "    cov = R1.T @ cov_rect @ R1\n", "    cov = cov_rect\n",
      "covariance left in the rectified frame instead of the left optical frame"),
    M("triangulation-rectification-jacobian", "core/triangulation.py",
      "    return out[0], out[1], J\n", "    return out[0], out[1], np.eye(4)\n",
      "pixel noise not propagated through the rectification"),
    M("triangulation-dlt-row-scale", "core/triangulation.py",
      "    w = np.array([P1[2] @ h, P1[2] @ h, P2[2] @ h, P2[2] @ h]) * scale\n",
      "    w = np.array([P1[2] @ h, P1[2] @ h, P2[2] @ h, P2[2] @ h])\n",
      "the DLT Jacobian ignores the unit-norm row scaling"),
    M("triangulation-parallax-row", "core/triangulation.py",
      "np.array([0.0, 0.5 * Z / fy, 0.0, 0.5 * Z / fy])",
      "np.array([0.0, Z / fy, 0.0, 0.0])",
      "the parallax Y uses the left row only in its Jacobian (the point averages both rows)"),
    M("triangulation-row-norms", "core/triangulation.py",
      "    scale = 1.0 / np.sqrt(np.add.reduce(A * A, axis=1))\n",
      "    scale = 1.0 / np.sqrt(np.add.reduce(A * A, axis=0))\n",
      "the DLT rows scaled by the norms of A's columns instead of its rows"),
    # -- core/detection.py
    M("detection-edge-mean-count", "core/detection.py",
      "    res = res - np.add.reduce(res) / n\n", "    res = res - np.add.reduce(res) / (n - 1)\n",
      "the contour residuals' mean taken over one point fewer"),
    M("detection-edge-profile-step", "core/detection.py",
      "    pts = contour[(np.arange(m) * (n / m)).astype(int)]\n",
      "    pts = contour[(np.arange(m) * (n // m)).astype(int)]\n",
      "the edge profiles spaced by a whole number of points (bunched at the contour's start)"),
    M("detection-one-component-of-several", "core/detection.py",
      "    if len(contours) > 1 and int(np.count_nonzero(hierarchy[0, :, 3] < 0)) > 1:\n",
      "    if False:\n",
      "a ROI with several blobs is taken as one (the labelling skipped)"),
    M("detection-half-pixel", "core/detection.py",
      "    minor = 2.0 * math.sqrt(max(lam_min, 0.0)) + 0.5\n",
      "    minor = 2.0 * math.sqrt(max(lam_min, 0.0))\n",
      "half-pixel edge term of the silhouette's minor axis dropped"),
    M("detection-shade-blur-law", "core/detection.py",
      "        shade = shade * (1.0 + SHADE_BLUR_GAIN * blur * blur)\n",
      "        shade = shade * (1.0 + SHADE_BLUR_GAIN * blur)\n",
      "the shading term of the centre sigma grows with the blur b instead of b^2"),
    M("detection-cut-blur-law", "core/detection.py",
      "cut = CUT_SIGMA_PX * (1.0 + CUT_BLUR_GAIN * blur)",
      "cut = CUT_SIGMA_PX * (1.0 + CUT_BLUR_GAIN * blur * blur)",
      "the threshold-cut term grows with b^2 instead of b"),
    M("detection-blur-floor", "core/detection.py",
      "max(width * width - BLUR_W0_PX ** 2, 0.0)", "max(width * width, 0.0)",
      "the unblurred edge width is not subtracted from the blur estimate"),
    M("detection-edge-tau", "core/detection.py",
      "            tau += 2.0 * float(ac[k])\n", "            tau += float(ac[k])\n",
      "the edge term's correlation time counts each lag once, not on both sides"),
    M("detection-edge-variance", "core/detection.py",
      "    sigma_edge2 = var * 2.0 * tau / n\n", "    sigma_edge2 = var * tau / n\n",
      "the edge term s sqrt(2 tau / N) without its factor 2"),
    # -- core/locator.py
    M("locator-missed-reset", "core/locator.py",
      "                loc.point_m, a.xl[i], a.xr[j], 0\n",
      "                loc.point_m, a.xl[i], a.xr[j], tr.missed\n",
      "a re-seen blob keeps its missed count (separate single misses retire its id)"),
    M("locator-retire", "core/locator.py",
      "            if tr.missed > cfg.track_max_missed:\n",
      "            if tr.missed >= cfg.track_max_missed:\n",
      "a blob's id retires one frame before tracking.max_missed misses"),
    M("locator-shared-shading", "core/locator.py",
      "        S = np.diag([e[0], e[0], e[1], e[1]]) + np.outer(v, v)\n",
      "        S = np.diag([e[0], e[0], e[1], e[1]]) + np.diag(v * v)\n",
      "the shading shift treated as independent in the two images, not shared"),
    M("locator-epipolar-sign", "core/locator.py",
      "        gap = abs(xl[self._row] - xr[self._row])\n",
      "        gap = xl[self._row] - xr[self._row]\n",
      "a right candidate below the left one's row passes the epipolar gate at any distance"),
    M("locator-near-sphere-no-cov", "core/locator.py",
      "                pt = self._point(left_px, right_px, xl, xr, pix)\n",
      "                pass\n",
      "a sphere too close to refine keeps the first pass, computed without its covariance"),
    M("triangulation-bare-skips-gate", "core/triangulation.py",
      "    if max_residual_px is not None and residual > max_residual_px:\n",
      "    if cov_rect is not None and max_residual_px is not None \\\n"
      "            and residual > max_residual_px:\n",
      "a point asked for without its covariance skips the residual gate"),
    M("triangulation-parallel-rays", "core/triangulation.py",
      "    if covariance and J is None:\n", "    if False:\n",
      "a pair whose rays are parallel to machine precision returns a NaN covariance"),
    M("locator-track-gate", "core/locator.py",
      "                if dist <= cfg.track_gate_m:\n",
      "                if dist <= 3 * cfg.track_gate_m:\n",
      "a blob keeps its id over steps of three times tracking.gate_m"),
    # -- core/localization.py
    M("localization-cov-sylvester", "core/localization.py",
      "    return a00 > 0.0 and m2 > 0.0 and det > 0.0\n",
      "    return a00 > 0.0 and m2 > 0.0\n",
      "an indefinite point covariance passes when its leading 2x2 block is definite"),
    M("transform-det-sign", "core/transforms.py",
      "           + r0[2] * (r1[0] * r2[1] - r1[1] * r2[0]))\n",
      "           - r0[2] * (r1[0] * r2[1] - r1[1] * r2[0]))\n",
      "the rotation check's determinant has a wrong cofactor sign"),
    M("localization-handeye-jacobian", "core/localization.py",
      "J = Rb @ np.hstack([np.eye(3), -_skew(q)])", "J = Rb @ np.hstack([np.eye(3), _skew(q)])",
      "sign of the hand-eye rotation term in the base-frame covariance"),
    M("localization-robot-rotation", "core/localization.py",
      "        cov += robot_sigma_rot_rad ** 2 * (J @ J.T)\n", "        pass\n",
      "robot rotation uncertainty left out of the base-frame covariance"),
    M("localization-robot-position-variance", "core/localization.py",
      "        cov += robot_sigma_pos_m ** 2 * np.eye(3)\n",
      "        cov += robot_sigma_pos_m * np.eye(3)\n",
      "the robot position sigma added as a variance unsquared"),
    M("localization-stated-floor", "core/localization.py",
      '        pos = max(pos, float(estimated["translation_sigma_m"]))\n',
      '        pos = float(estimated["translation_sigma_m"])\n',
      "the calibration's estimate replaces the arm's stated accuracy instead of raising it"),
    # -- core/eye_to_hand.py
    M("eye-to-hand-arguments", "core/eye_to_hand.py",
      "target_in_base(_IDENTITY, self.base_T_cam, point_cam,",
      "target_in_base(self.base_T_cam, _IDENTITY, point_cam,",
      "the camera mount passed as the robot pose (mount covariance rotated by it)"),
    M("eye-to-hand-mount-covariance", "core/eye_to_hand.py",
      "                                cov_hand_eye=self.cov_hand_eye)\n",
      "                                cov_hand_eye=None)\n",
      "the camera mount's covariance left out of located targets"),
    # -- core/distances.py
    M("distances-std-ddof", "core/distances.py",
      "            std = float(d[ok].std(ddof=1)) if n >= 2 else math.nan\n",
      "            std = float(d[ok].std()) if n >= 2 else math.nan\n",
      "the distance scatter as a population (ddof 0) instead of a sample standard deviation"),
    M("distances-known-sign", "core/distances.py",
      "            err = 1000.0 * (p.mean_m - m) if p.frames else math.nan\n",
      "            err = 1000.0 * (m - p.mean_m) if p.frames else math.nan\n",
      "the error against a known distance has its sign flipped"),
    M("distances-rms", "core/distances.py",
      "1000.0 * float(np.sqrt(np.mean(e ** 2))) if e.size else math.nan,",
      "1000.0 * float(np.mean(e)) if e.size else math.nan,",
      "a target's position error against the truth as a mean, not the documented RMS"),
    M("distances-truth-frames", "core/distances.py",
      "truth_m=float(dt[both].mean()),", "truth_m=float(np.nanmean(dt)),",
      "a pair's true distance averaged over all frames, not those where both were located"),
    # -- core/handeye/solvers.py
    M("handeye-translation", "core/handeye/solvers.py",
      "    rhs = (m.B[:, :3, 3] @ R.T - m.A[:, :3, 3]).reshape(3 * K)\n",
      "    rhs = (m.B[:, :3, 3] @ R - m.A[:, :3, 3]).reshape(3 * K)\n",
      "hand-eye translation solved with the transposed rotation"),
    M("handeye-motion-order", "core/handeye/solvers.py",
      "    A = invert_many(G[jj]) @ G[ii]\n", "    A = G[jj] @ invert_many(G[ii])\n",
      "robot motions taken in the base frame instead of the flange frame"),
    M("handeye-park-transpose", "core/handeye/solvers.py",
      "    H = a.T @ b  # sum a b^T = M^T\n", "    H = b.T @ a\n",
      "Park-Martin returns the transposed rotation"),
    M("handeye-eye-to-hand-poses", "core/handeye/solvers.py",
      "        return invert_many(np.asarray(base_T_ee, dtype=np.float64))\n",
      "        return np.array(base_T_ee, dtype=np.float64)\n",
      "eye-to-hand robot poses not inverted"),
    # -- core/handeye/average.py
    M("average-axes-as-lines", "core/handeye/average.py",
      '    cos = np.abs(np.einsum("ki,ki->k", axis[pp], axis[qq]))\n',
      '    cos = np.einsum("ki,ki->k", axis[pp], axis[qq])\n',
      "anti-parallel rotation axes count as far apart (axes compared as vectors, not lines)"),
    M("average-small-rotation", "core/handeye/average.py",
      "    small = ~(big[pp] & big[qq])\n", "    small = ~(big[pp] | big[qq])\n",
      "a pair of motions is used when only one of its rotations is large enough"),
    M("average-pair-translation", "core/handeye/average.py",
      '    rhs_p = np.einsum("kij,kj->ki", R, m.B[p, :3, 3]) - m.A[p, :3, 3]\n',
      '    rhs_p = np.einsum("kji,kj->ki", R, m.B[p, :3, 3]) - m.A[p, :3, 3]\n',
      "the per-pair translation uses the transposed rotation for the first motion"),
    M("average-spread-units", "core/handeye/average.py",
      "    trans_dev = 1000.0 * np.linalg.norm(Xs[:, :3, 3] - t, axis=1)\n",
      "    trans_dev = np.linalg.norm(Xs[:, :3, 3] - t, axis=1)\n",
      "the per-pair translation spread reported in metres as millimetres"),
    M("average-mean-translation", "core/handeye/average.py",
      "    t = Xs[:, :3, 3].mean(axis=0)\n", "    t = np.median(Xs[:, :3, 3], axis=0)\n",
      "the averaged translation is the per-pair median, not the documented mean"),
    M("average-reflection", "core/handeye/average.py",
      "    D = np.diag([1.0, 1.0, 1.0 if np.linalg.det(U @ Vt) > 0 else -1.0])\n",
      "    D = np.eye(3)\n",
      "the chordal mean returns a reflection when the summed rotations have det < 0"),
    # -- core/handeye/refine.py
    M("refine-residual-variance", "core/handeye/refine.py",
      "    s2 = 2.0 * float(res.cost) / dof\n", "    s2 = float(res.cost) / dof\n",
      "the residual variance from the cost without its factor 2 (covariance halved)"),
    M("refine-perturbation-side", "core/handeye/refine.py",
      "    T[:3, :3] = Rotation.from_rotvec(p[3:6]).as_matrix() @ T0[:3, :3]\n",
      "    T[:3, :3] = T0[:3, :3] @ Rotation.from_rotvec(p[3:6]).as_matrix()\n",
      "the rotation perturbation on the right (child frame), not the documented left"),
    M("refine-tangential", "core/handeye/refine.py",
      "    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)\n",
      "    xd = x * radial + p1 * x * y + p2 * (r2 + 2 * x * x)\n",
      "the tangential distortion term of x halved"),
    M("refine-covariance-block", "core/handeye/refine.py",
      'cov[:6, :6], cov,\n                            sigma, float(res.cost), int(res.nfev), '
      '"reprojection")',
      'cov[6:, 6:], cov,\n                            sigma, float(res.cost), int(res.nfev), '
      '"reprojection")',
      "the reprojection refinement reports the board's covariance as X's"),
    M("refine-pose-scales", "core/handeye/refine.py",
      "        return np.concatenate([r / sr, t / st], axis=1).ravel()\n",
      "        return np.concatenate([r / st, t / sr], axis=1).ravel()\n",
      "pose-space residuals divided by each other's noise scale"),
    # -- core/handeye/eiv.py
    M("eiv-redundancy", "core/handeye/eiv.py",
      "        r_g = float(rows.sum() - h[rows].sum())\n",
      "        r_g = float(rows.sum())\n",
      "noise levels from the residuals over their row count, not their redundancy"),
    M("eiv-correction-side", "core/handeye/eiv.py",
      "    return bte @ D\n", "    return D @ bte\n",
      "robot-pose corrections applied in the base frame instead of the flange frame"),
    M("eiv-covariance-block", "core/handeye/eiv.py",
      "    return EivResult(X=X, Y=Y, covariance=cov[:6, :6], covariance_full=cov,\n",
      "    return EivResult(X=X, Y=Y, covariance=cov[6:, 6:], covariance_full=cov,\n",
      "the errors-in-variables result reports the board's covariance as X's"),
    M("eiv-hat-cross-term", "core/handeye/eiv.py",
      '              + 2.0 * np.einsum("ki,kij,kj->k", Jg, Cgu[k], Ju)\n',
      '              + np.einsum("ki,kij,kj->k", Jg, Cgu[k], Ju)\n',
      "the hat matrix's cross term counted once instead of twice"),
    # -- core/handeye/session.py
    M("session-window-one-side", "core/handeye/session.py",
      "        for f in np.linspace(-1.0, 1.0, 9):\n",
      "        for f in np.linspace(0.0, 1.0, 5):\n",
      "stillness checked only after the image stamp, not on both sides of it"),
    M("session-window-not-covered", "core/handeye/session.py",
      "                       and newest >= req.frame_stamp_ns + window)\n",
      "                       and newest >= req.frame_stamp_ns)\n",
      "a capture answered before the robot poses cover its stillness window"),
    M("session-duplicate-either", "core/handeye/session.py",
      "            if d <= cfg.duplicate_translation_m and a <= cfg.duplicate_rotation_rad:\n",
      "            if d <= cfg.duplicate_translation_m or a <= cfg.duplicate_rotation_rad:\n",
      "a pose that only rotates (or only moves) counted as a duplicate"),
    M("session-request-time", "core/handeye/session.py",
      "            after = now_ns if after is None else max(after, now_ns)\n",
      "            after = after\n",
      "a frame exposed before the request (handed in late) taken for it"),
    # -- core/handeye/plan.py
    M("plan-no-schur", "core/handeye/plan.py",
      '        out.append(nm.A_k - np.einsum("kij,klj->kil", BD, nm.B))\n',
      "        out.append(nm.A_k)\n",
      "the robot-pose corrections not marginalised: robot noise left out of the model"),
    M("plan-near-any", "core/handeye/plan.py",
      "    ok &= np.any((dt <= cfg.max_step_m) & (dr <= cfg.max_step_deg), axis=1)\n",
      "    ok &= np.any((dt <= cfg.max_step_m) | (dr <= cfg.max_step_deg), axis=1)\n",
      "a suggestion near a reached pose in position or rotation, not both"),
    M("plan-x-block", "core/handeye/plan.py",
      "        return np.linalg.inv(info)[..., :6, :6]\n",
      "        return np.linalg.inv(info)[..., 6:, 6:]\n",
      "the board pose's covariance scored as X's"),
    # -- core/handeye/systematic.py, core/handeye/budget.py
    M("systematic-correction-side", "core/pose_correction.py",
      "        out: np.ndarray = b @ E\n",
      "        out: np.ndarray = E @ b\n",
      "the systematic correction applied in the base frame instead of the flange frame"),
    M("systematic-is-the-reference", "core/handeye/calibrate.py",
      'reference = "refined" if "refined" in candidates else',
      'reference = "refined_systematic" if "refined_systematic" in candidates else',
      "refined_systematic written unless another beats it (not only when it beats refined)"),
    M("systematic-disagreement-compared", "core/handeye/calibrate.py",
      '        if (name == "refined_systematic") != (selected == "refined_systematic"):\n',
      '        if False:\n',
      "refined_systematic's X (corrected poses) compared with the others' as a disagreement"),
    M("session-half-frame", "core/handeye/session.py",
      "        if len(frame) < len(self.views):\n", "        if not frame:\n",
      "a stereo frame goes to the captures with one of its two images"),
    M("session-age-from-arrival", "core/handeye/session.py",
      "        since = min(since, req.frame_stamp_ns)\n", "        pass\n",
      "a late frame's robot poses are aged from its arrival, not from its stamp"),
    M("session-frame-not-newer", "core/handeye/session.py",
      "(req.after_ns is None or stamp_ns > req.after_ns)",
      "(req.after_ns is None or stamp_ns >= req.after_ns)",
      "a capture binds the frame already seen at its request (newer-than not strict)"),
    M("pose-correction-reference-side", "core/pose_correction.py",
      '    return log_rotations(np.einsum("ji,njk->nik", R_ref, base_T_ee[:, :3, :3]))\n',
      '    return log_rotations(np.einsum("ij,njk->nik", R_ref, base_T_ee[:, :3, :3]))\n',
      "the orientation taken relative to R_ref instead of R_ref^T (the model's input)"),
    M("pose-correction-half-turn-sign", "core/pose_correction.py",
      "            if axis @ v[i] < 0:\n",
      "            if axis @ v[i] > 0:\n",
      "near a half turn the rotation vector's axis points the wrong way"),
    M("pose-correction-rows", "core/pose_correction.py",
      "        return np.concatenate([r @ self.A_t.T, r @ self.A_r.T], axis=1)\n",
      "        return np.concatenate([r @ self.A_t, r @ self.A_r], axis=1)\n",
      "A_r and A_t applied transposed"),
    M("pose-correction-one-pose-exp", "core/pose_correction.py",
      "-a * wx + b * wy * wz, t[1]],\n", "a * wx + b * wy * wz, t[1]],\n",
      "the one-pose path's rotation (Rodrigues) has a wrong sign"),
    M("joint-index-reorder", "core/kinematics.py",
      "        if names != self._names:\n", "        if self._names is None:\n",
      "joint_states read through the first message's index after the names changed order"),
    M("localization-correction-skipped", "core/localization.py",
      "            base_T_ee = self.pose_correction.apply(base_T_ee)\n",
      "            pass\n",
      "the localizer ignores the calibration's robot pose correction"),
    M("config-correction-not-written", "io/config.py",
      "        if c is not None:\n",
      "        if c is not None and False:\n",
      "hand_eye.yaml loses the robot pose correction"),
    M("budget-robot-with-camera", "core/handeye/budget.py",
      '             "robot_mm": float(np.sqrt(max(0.0, r2 - c2))),\n',
      '             "robot_mm": float(np.sqrt(max(0.0, r2))),\n',
      "the robot's part of the error budget counts the camera's part again"),
    # -- core/calibration/detection.py
    M("saddle-step-sign", "core/calibration/detection.py",
      '        step = -np.einsum("nij,nj->ni", Hi, np.stack([d, e], axis=1))\n',
      '        step = np.einsum("nij,nj->ni", Hi, np.stack([d, e], axis=1))\n',
      "the saddle refinement steps away from the stationary point"),
    # -- core/handeye/select.py
    M("select-standard-error", "core/handeye/select.py",
      '    se = float(np.std(d, ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("inf")\n',
      '    se = float(np.std(d, ddof=1)) if d.size > 1 else float("inf")\n',
      "the paired comparison divides by the standard deviation, not the standard error"),
    M("select-margin", "core/handeye/select.py",
      "    if float(np.mean(d)) < -2.0 * se:\n", "    if float(np.mean(d)) < -1.0 * se:\n",
      "another method replaces refined at 1 standard error instead of 2"),
    M("select-lever-arm", "core/handeye/select.py",
      "            p_ee = s.base_T_ee[:3, :3].T @ (p_fixed - s.base_T_ee[:3, 3])\n",
      "            p_ee = s.base_T_ee[:3, :3].T @ p_fixed\n",
      "the flange position dropped from the lever arm of the robot rotation noise"),
    M("select-rotation-term", "core/handeye/select.py",
      "    excess = float(np.mean(m - 2.0 * rotation_sigma_rad ** 2 * np.asarray(lever_sq)\n",
      "    excess = float(np.mean(m - 3.0 * rotation_sigma_rad ** 2 * np.asarray(lever_sq)\n",
      "the rotation noise's share of the held-out scatter counted over 3 axes, not 2"),
    M("select-per-axis", "core/handeye/select.py",
      "    return float(np.sqrt(max(0.0, excess) / 3.0)), float(np.sqrt(np.mean(m)))\n",
      "    return float(np.sqrt(max(0.0, excess))), float(np.sqrt(np.mean(m)))\n",
      "the held-out position sigma as a 3-D norm, not per axis"),
    M("select-measurement-noise", "core/handeye/select.py",
      "                           - (np.asarray(meas) if meas else 0.0)))\n",
      "                           ))\n",
      "the held-out view's own measurement noise counted as robot noise"),
    M("select-pose-score", "core/handeye/select.py",
      "np.hypot(h.mm / ref_mm, h.deg / ref_deg)", "(h.mm / ref_mm + h.deg / ref_deg)",
      "the pose score adds the normalised mm and deg errors instead of combining in quadrature"),
    M("select-held-out-degrees", "core/handeye/select.py",
      "        deg[i] = float(np.degrees(np.linalg.norm(\n",
      "        deg[i] = float((np.linalg.norm(\n",
      "the held-out board rotation error reported in radians as degrees"),
    M("select-centre-variance", "core/handeye/select.py",
      "        cov = px_sigma ** 2 * np.linalg.inv(J.T @ J)\n",
      "        cov = px_sigma * np.linalg.inv(J.T @ J)\n",
      "the centre's measurement covariance scaled by px_sigma, not px_sigma^2"),
    # -- core/handeye/calibrate.py
    M("calibrate-held-out-noise", "core/handeye/calibrate.py",
      "            t = max(t, self.held_out_sigma_m)\n", "            pass\n",
      "hand_eye.yaml's translation noise ignores the held-out position scatter"),
    M("calibrate-outlier-floors", "core/handeye/calibrate.py",
      "        bad = (score > threshold) & ((dmm > floor_mm) | (ddeg > floor_deg))\n",
      "        bad = score > threshold\n",
      "samples within the absolute floors rejected as outliers (relative test only)"),
    M("calibrate-outlier-rotation", "core/handeye/calibrate.py",
      "        score = np.maximum(dmm / med_mm, ddeg / med_deg)\n",
      "        score = dmm / med_mm\n",
      "the outlier score ignores the rotation deviation"),
    M("calibrate-jackknife", "core/handeye/calibrate.py",
      "    f = (n - 1) / n\n", "    f = 1.0 / n\n",
      "the jackknife spread without its (n - 1) / n factor (standard error understated)"),
    M("calibrate-rotation-noise", "core/handeye/calibrate.py",
      '                "rotation_sigma_rad": self.refinement.robot_rotation_sigma_rad}\n',
      '                "rotation_sigma_rad": self.refinement.robot_translation_sigma_m}\n',
      "hand_eye.yaml's rotation noise written from the translation estimate"),
    # -- io/
    M("chunk-record-order", "io/bags/mcap_records.py",
      "    out.sort(key=lambda m: (m[0], m[2]))\n    return out\n", "    return out\n",
      "messages of an MCAP chunk not sorted by time (an indexed file's and one recovered "
      "from an interrupted recording alike)"),
    M("read-end-inclusive", "io/bags/reading.py",
      "    stop = None if end_ns is None else end_ns + 1\n",
      "    stop = None if end_ns is None else end_ns\n",
      "a message stamped exactly end_ns left out of a time window (documented inclusive)"),
    M("write-negative-stamp", "io/bags/writing.py",
      "not isinstance(stamp_ns, int) or stamp_ns < 0:", "not isinstance(stamp_ns, int):",
      "a negative log time written into a bag"),
    M("quat-tolerance-loose", "core/transforms.py",
      "    if not bool(np.all(np.abs(R @ R.T - _EYE3) <= 1e-12 + 1e-5 * _EYE3)):\n",
      "    if not bool(np.all(np.abs(R @ R.T - _EYE3) <= 1e-9 + 1e-5 * _EYE3)):\n",
      "a matrix SciPy would project onto the rotations converted as it stands"),
    M("quat-w-sign", "core/transforms.py",
      "        q[3] = r[k][j] - r[j][k]\n",
      "        q[3] = r[j][k] - r[k][j]\n",
      "the scalar part of the written-out quaternion with the wrong sign"),
    M("assignment-shared-column", "core/assignment.py",
      "        if len(set(cols.tolist())) == n:\n",
      "        if True:\n",
      "two rows given the same cheapest column"),
    M("pages-own-range-only", "io/pages.py",
      "DROP_BLOCK_BYTES = max(mmap.PAGESIZE, 2 * 1024 * 1024)\n",
      "DROP_BLOCK_BYTES = mmap.PAGESIZE\n",
      "only a read range's own pages are released: what the kernel mapped around them stays"),
    M("mcap-chunk-order", "io/bags/mcap_chunks.py",
      "            picked.append((c.message_start_time, c.chunk_start_offset, k))\n",
      "            picked.append((c.chunk_start_offset, c.message_start_time, k))\n",
      "MCAP chunks read in file order instead of time order"),
    M("mcap-chunk-damage-names-another", "io/bags/mcap_chunks.py",
      "            self.damage(self.infos[i], exc)\n",
      "            self.damage(self.infos[max(i - 1, 0)], exc)\n",
      "a chunk that does not decompress is reported under the chunk before it"),
    M("mcap-chunk-infos-listed", "io/bags/mcap_chunks.py",
      "    return (_Picked(index, [k for _t, _o, k in picked]),",
      "    return ([index[k] for _t, _o, k in picked],",
      "reading a bag holds the index's ChunkInfo of every chunk it reads"),
    M("mcap-chunk-records-kept", "io/bags/mcap_chunks.py",
      "                chunks[i - 2] = None              # read: its record goes too\n",
      "                pass\n",
      "every chunk record of the file stays in memory until the whole file is read"),
    M("mcap-task-refs-all-at-once", "io/bags/mcap_tasks.py",
      "    planned = iter_groups((ChunkRef.of(path, chunks[i]) for i in order),\n",
      "    planned = iter_groups([ChunkRef.of(path, chunks[i]) for i in order],\n",
      "a ChunkRef is made for every chunk of the file before the first group is read"),
    M("chunk-table-key-order", "io/bags/chunk_table.py",
      "dict(zip(keys, self.offsets[s:s + len(keys)], strict=True)), mil,\n",
      "dict(sorted(zip(keys, self.offsets[s:s + len(keys)]))), mil,\n",
      "a chunk's message index offsets come back in another key order than the file's"),
    M("chunk-table-cache-shared", "io/bags/storage_mcap.py",
      "    if isinstance(value, ChunkTable):\n        return value.copy()\n",
      "    if isinstance(value, ChunkTable):\n        return value\n",
      "a reader's close empties the chunk index the cache keeps for the next reader"),
    M("pose-forget-bracket", "core/sync.py",
      "        i = bisect.bisect_right(self._stamps, _as_stamp(stamp_ns)) - 1\n",
      "        i = bisect.bisect_right(self._stamps, _as_stamp(stamp_ns))\n",
      "pruning the robot pose buffer drops the pose that brackets the stamp it keeps"),
    M("mcap-cache-keeps-read-chunks", "io/bags/mcap_tasks.py",
      "        _CACHE.read(self.chunk, self.start)     # the view keeps",
      "        (self.chunk, self.start)     # the view keeps",
      "a worker keeps every decompressed chunk until the cache is full, its images read or not"),
    M("pages-heap-trimmed", "io/pages.py",
      "                                                                      int(nbytes)))\n",
      "                                                                      0))\n",
      "a decompression worker gives each freed chunk back to the kernel and faults it in again"),
    M("cdr-height-width", "io/cdr.py",
      "    height, width = _HW.unpack_from(body, pos)\n",
      "    width, height = _HW.unpack_from(body, pos)\n",
      "image height and width swapped when decoding CDR"),
    M("atomic-overwrite-mixes", "io/atomic.py",
      "    elif _exchange(staged, out):\n        _remove(staged)  # now the old folder\n",
      "    elif True:\n        for f in staged.iterdir():\n"
      "            os.replace(f, out / f.name)\n",
      "--overwrite merges the new files into the old folder instead of replacing it whole"),
    M("config-quaternion-norm", "io/config.py",
      "    norm = float(np.linalg.norm(q))\n    if abs(norm - 1.0) > _QUAT_NORM_TOL:\n"
      "        raise _fail(source, f\"'quat_xyzw'",
      "    norm = float(np.linalg.norm(q))\n    if False:\n"
      "        raise _fail(source, f\"'quat_xyzw'",
      "hand_eye.yaml with a non-unit quaternion accepted"),
    M("datasets-quaternion-norm", "io/datasets.py",
      "    if abs(norm - 1.0) > 1e-4:\n", "    if False:\n",
      "a dataset pose with a non-unit quaternion silently normalised"),
    # -- nodes/ and the offline path
    M("recorder-one-message-fits", "ros/bag_queues.py",
      "            if self.closed or (not force and self._items\n",
      "            if self.closed or (not force\n",
      "a single message larger than the write budget is dropped"),
    M("player-rate", "nodes/bag_player_pacing.py",
      "            rate = self.rate\n", "            rate = 1.0\n",
      "bag player ignores --rate"),
    M("player-static-tf-qos", "nodes/bag_player_topics.py",
      "            if name == TF_STATIC_TOPIC:\n", "            if False:\n",
      "a replayed /tf_static is offered as recorded, not latched: a late TF listener misses it"),
    M("player-qos-best-effort", "ros/qos.py",
      '        if rel == {"best_effort"}:\n', "        if False:\n",
      "a best-effort recording is replayed reliable"),
    M("recorder-qos-reliable", "ros/qos.py",
      "    reliable = bool(offers) and all(", "    reliable = True or all(",
      "the recorder asks reliable of a best-effort publisher (and receives nothing)"),
    M("capture-side-by-side-swapped", "io/frame_sources.py",
      "            left, right = img[:, :w // 2], img[:, w // 2:]\n",
      "            left, right = img[:, w // 2:], img[:, :w // 2]\n",
      "the halves of a side-by-side frame published as the other camera"),
    M("capture-follow-stamp", "sim/frame_source.py",
      "        pair = FramePair(frame.left, frame.right, q=q, index=k, stamp_ns=stamp)\n",
      "        pair = FramePair(frame.left, frame.right, q=q, index=k, stamp_ns=None)\n",
      "a pair rendered from a joint state is stamped when published, not with its state's stamp"),
    M("hand-eye-waits-for-pose", "core/pipeline.py",
      "(newest is None or item.stamp_ns > newest):", "newest is None:",
      "a point is located before a robot pose at or after its stamp arrived"),
    M("hand-eye-file-noise", "nodes/hand_eye_poses.py",
      "        None if calibration is None else calibration.robot_pose_noise)\n",
      "        None)\n",
      "the hand_eye node ignores hand_eye.yaml's robot_pose_noise"),
    M("hand-eye-file-correction", "nodes/hand_eye_poses.py",
      "                         else calibration.robot_pose_correction))\n",
      "                         else None))\n",
      "the hand_eye node ignores hand_eye.yaml's robot_pose_correction"),
    M("offline-correction-dropped", "offline.py",
      "        pose_correction=pose_correction)\n",
      "        pose_correction=None)\n",
      "process ignores hand_eye.yaml's robot_pose_correction"),
    M("hand-eye-waits-unarmed", "nodes/hand_eye_first_target.py",
      "        self.pipeline.add_point(stamp, p, cov, received_ns=self._now_ns())\n"
      "        self._arm_waits()\n",
      "        self.pipeline.add_point(stamp, p, cov, received_ns=self._now_ns())\n",
      "a point that waits for its robot pose is never checked again until a pose arrives"),
    M("hand-eye-waits-disarmed-early", "core/pipeline.py",
      "        if self.points or self.frames:\n            return True\n",
      "        if self.points:\n            return True\n",
      "the waits' check stops while a frame of targets still waits"),
    # -- core/pipeline.py: the one pipeline's waiting rules
    M("pipeline-fifo", "core/pipeline.py",
      "        while self.points and self._point_ready(self.points[0], newest, now):\n"
      "            self._locate_point(self.points.popleft())\n",
      "        while self.points and self._point_ready(self.points[-1], newest, now):\n"
      "            self._locate_point(self.points.pop())\n",
      "the newest waiting point goes out first (output out of stamp order)"),
    M("pipeline-pose-wait-expiry", "core/pipeline.py",
      "        if self.waits.pose_wait_over(now - item.arrived):\n            return True\n",
      "",
      "a point waits for its robot pose forever (max_pose_wait_s ignored)"),
    M("pipeline-frame-waits-for-pose", "core/pipeline.py",
      "        return (newest is not None and f.stamp_ns <= newest) \\\n",
      "        return (newest is not None) \\\n",
      "a frame of targets goes out before a robot pose at or after its stamp arrived"),
    M("pipeline-age-at-arrival", "core/pipeline.py",
      "                                        now_ns=item.received_ns)\n",
      "                                        now_ns=None)\n",
      "a point's robot poses are never checked for staleness"),
    M("pipeline-overflow-newest", "core/pipeline.py",
      "            self._refuse_point(self.points.popleft(), \"pending_overflow\",\n",
      "            self._refuse_point(self.points.pop(), \"pending_overflow\",\n",
      "a full queue drops the newest waiting point instead of the oldest"),
    M("pipeline-cov-wait", "core/pipeline.py",
      "        return item.cov is not None or self._cov_expected is None "
      "or not self._cov_expected()\n",
      "        return True\n",
      "a point goes out without the covariance its detector publishes"),
    M("hand-eye-in-process-frame", "nodes/hand_eye_first_target.py",
      '        if self._camera_frame_ok("target/point", frame):\n',
      "        if True:\n",
      "a point handed over in memory skips hand_eye's camera-frame check"),
    M("hand-eye-in-process-cov", "nodes/hand_eye.py",
      "f.frame_id, f.first[0], f.first[1])\n", "f.frame_id, f.first[0], None)\n",
      "the first target's covariance is lost in the in-memory hand-off"),
    M("publishers-report-once", "ros/publishers.py",
      "                if (topic, who) in self._reported:\n                    continue\n",
      "",
      "an incompatible subscriber is reported again at every check"),
    M("publishers-own-profile", "ros/publishers.py",
      "                compat, reason = qos_check_compatible(mine[0], info.qos_profile)\n",
      "                compat, reason = qos_check_compatible(pub.qos_profile, info.qos_profile)\n",
      "the check compares the requested profile (system defaults), flagging every subscriber"),
    M("lean-executor-passive-events", "ros/executor.py",
      "            skip = {id(h) for h in handlers}\n",
      "            skip: set[int] = set()\n",
      "a passive subscription's QoS events stay in the waits: unread messages end every wait"),
    M("lean-executor-passive-waited-on", "ros/executor.py",
      "            passive = tuple(sub for sub in entities.subs if is_passive(sub))\n",
      "            passive: tuple[Any, ...] = ()\n",
      "a passive subscription is waited on: the executor wakes for each of its messages"),
    M("pipeline-no-pull-before-point", "core/pipeline.py",
      "            self.pull_poses()\n        cap = self.rules.max_waiting_points\n",
      "        cap = self.rules.max_waiting_points\n",
      "a point is judged before the poses taken only when needed are pulled"),
    M("hand-eye-lazy-no-wake", "nodes/hand_eye.py",
      "            self.robot_poses.wake_for_poses(True)\n", "",
      "a point waiting for a newer robot pose leaves the pose subscription passive"),
    M("hand-eye-lazy-stays-awake", "nodes/hand_eye.py",
      "            self.robot_poses.wake_for_poses(False)\n", "",
      "the pose subscription stays active after the waits are over: a wake-up per pose again"),
    M("hand-eye-lazy-under-sim-time", "nodes/hand_eye_poses.py",
      "        if not self._on_system_clock():\n", "        if False:\n",
      "use_sim_time switched on at run time: poses keep the middleware's (wall) receive times"),
    M("hand-eye-pull-while-active", "nodes/hand_eye_poses.py",
      "        if not self.lazy or not is_passive(self._sub):\n", "        if not self.lazy:\n",
      "poses pulled while the executor delivers them: newer ones taken ahead of older ones"),
    M("hand-eye-reception-zero", "nodes/hand_eye_poses.py",
      "            queued = [(msg, t if 0 < t <= now else now) for msg, t in queued]\n",
      "            queued = list(queued)\n",
      "a reception time of 0 or from the future kept: every point refused as stale"),
    M("hand-eye-lazy-any-rmw", "nodes/hand_eye_poses.py",
      "        if self._sub is None or not reception_times_known():\n",
      "        if self._sub is None:\n",
      "poses taken when needed on a middleware that does not stamp them at reception"),
    M("hand-eye-pose-batch-counted-once", "nodes/hand_eye_poses.py",
      '            self.diag.count("robot_poses", taken)\n',
      '            self.diag.count("robot_poses")\n',
      "robot poses taken together are counted as one"),
    M("lean-executor-no-drain", "ros/executor.py",
      "        while (one := handle.take_message(msg_type, raw)) is not None:\n"
      "            self._deliver(sub, one)\n",
      "        if (one := handle.take_message(msg_type, raw)) is not None:\n"
      "            self._deliver(sub, one)\n",
      "a ready subscription gives one message per wake-up: a backlog is taken one wake-up each"),
    M("lean-executor-no-events", "ros/executor.py",
      "                self.create_task(waitable.execute(waitable.take_data()))\n",
      "                waitable.take_data()\n",
      "a QoS event (an incompatible publisher) is taken but its callback never runs"),
    M("lean-executor-topic-by-topic", "ros/executor.py",
      "            taken.sort(key=_round_then_arrival)\n", "",
      "queued messages of several topics are delivered topic by topic, not round by round"),
    M("outputs-cdr-pose-unaligned", "ros/outputs_cdr.py",
      "        self.align(8)\n        self.buf += _POSE.pack(",
      "        self.buf += _POSE.pack(",
      "the published poses' doubles are not 8-byte aligned: subscribers read shifted values"),
    M("outputs-cdr-marker-tail-misaligned", "ros/outputs_cdr.py",
      "    w.buf += _MARKER_TAILS[(len(w.buf) - 4) % 4]\n",
      "    w.buf += _MARKER_TAILS[0]\n",
      "a marker's empty fields written without the padding their offset needs"),
    M("outputs-cdr-sphere-lifetime", "ros/outputs_cdr.py",
      "                rgba, (int(life[0]), int(life[1])))\n",
      "                rgba, (0, 0))\n",
      "target/markers' spheres never expire"),
    M("undecodable-point-uncounted", "nodes/hand_eye_first_target.py",
      "        self.diag.count(\"points\")\n        self._refuse(\"bad_point\", undecodable(",
      "        self._refuse(\"bad_point\", undecodable(",
      "an undecodable target/point is refused but not counted as received: the ledger breaks"),
    M("marker-lifetime-unchecked", "ros/outputs.py",
      "    if life // _NS_PER_S > _INT32[1]:\n",
      "    if False:\n",
      "a marker lifetime past a Duration's range fails deep in serialization, not with the "
      "field named"),
    M("decoded-bad-bytes-silent", "ros/decoded.py",
      "            on_bad(name[0], exc)\n            return\n",
      "            return\n",
      "a message whose bytes do not decode is dropped without a report"),
    M("decoded-lazy-raw", "ros/decoded.py",
      "    if decode is None:\n        return taken\n",
      "    if decode is not None:\n        return taken\n",
      "robot poses taken when needed reach the pipeline as undecoded bytes"),
    M("threads-openblas-only", "threads.py",
      "    if any(environ.get(name) for name in BLAS_THREAD_VARS):\n",
      "    if environ.get(\"OPENBLAS_NUM_THREADS\"):\n",
      "a user's OMP_NUM_THREADS or GOTO_NUM_THREADS is overridden with one BLAS thread"),
    M("memory-mmap-only", "memory.py",
      "    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and \\\n"
      "        bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))\n",
      "    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))\n",
      "freed image blocks go back to the kernel: each new one is faulted in again"),
    M("memory-overrides-the-user", "memory.py",
      "    if not sys.platform.startswith(\"linux\") or user_malloc_settings():\n",
      "    if not sys.platform.startswith(\"linux\"):\n",
      "the user's own malloc settings in the environment are overridden"),
    M("node-process-unprepared", "ros/node_main.py",
      "    use_large_data_profile()\n    reuse_large_buffers()\n",
      "    use_large_data_profile()\n",
      "a node process maps and faults in every image afresh"),
    M("lean-executor-rebuild-race", "ros/executor.py",
      "            self._entities = entities if generation == self._generation else None\n",
      "            self._entities = entities\n",
      "a rebuild that raced a new subscription is kept: the subscription is never waited on"),
    M("lean-executor-arrival-only", "ros/executor.py",
      "    return item[0], item[1], item[2]\n", "    return item[1], item[2], item[0]\n",
      "queued messages are delivered in arrival order alone: a burst of lefts overflows the "
      "stereo sync"),
    M("lean-executor-stale-entities", "ros/executor.py",
      "    def wake(self) -> None:\n        self._stale()\n",
      "    def wake(self) -> None:\n",
      "an entity made while spinning is never waited on"),
    M("lean-executor-drops-coroutines", "ros/executor.py",
      "        if inspect.iscoroutine(result):\n            self.create_task(result)\n",
      "        pass\n",
      "an async callback's coroutine is never run"),
    M("lean-executor-async-service", "ros/executor.py",
      "            if inspect.iscoroutine(response):\n",
      "            if False:\n",
      "an async service sends its coroutine as the response"),
    M("localize-expect-targets", "nodes/localize.py",
      "        self.hand_eye.expect_targets(self.detect.target_ids)\n", "",
      "the composed chain's per-target publishers appear only with the first frame"),
    M("hand-eye-target-point-frame", "nodes/hand_eye_targets.py",
      "        if frame and frame.lstrip(\"/\") != self.config.camera_frame:\n"
      "            problem = f\"frame {frame!r}, expected {self.config.camera_frame!r}\"\n",
      "        if False:\n            problem = \"\"\n",
      "a target's point in another camera frame is kept for its frame"),
    M("detect-queue-depth", "ros/queues.py",
      "            dropped = len(self._items) >= self._depth\n",
      "            dropped = len(self._items) > self._depth\n",
      "the pair queue holds one pair more than queue_depth"),
    M("offline-pipeline-no-flush", "offline.py",
      "        self.pipeline.flush()  # end of bag: the last points are resolved (or refused)",
      "        pass  # end of bag: the last points are never resolved",
      "the pairs still waiting for a robot pose at the end of the bag are never resolved"),
    M("offline-pipeline-age", "offline.py",
      "self.pipeline.add_frame(frame.stamp_ns, frame.targets, received_ns=t_arrival,\n",
      "self.pipeline.add_frame(frame.stamp_ns, frame.targets, received_ns=None,\n",
      "process applies no receive-age rule to the robot poses of a pair"),
    M("offline-deferred-workers-never-initialised", "offline.py",
      "            self._procs.initialize(rig, self._config)\n",
      "            pass\n",
      "worker processes started before the rig is read are never initialised with it"),
    M("offline-frames-keep-pickle-views", "offline.py",
      "sys.intern(name), np.array(point), np.array(cov),\n",
      "sys.intern(name), point, cov,\n",
      "every frame kept for the outputs holds its worker's unpickled buffers (2.4 kB more a "
      "target)"),
    M("offline-settles-waiting-frames", "offline.py",
      "            frames.settle(waiting[0].tag if waiting else None)\n",
      "            frames.settle(None)\n",
      "frames still waiting for a robot pose go to the temporary file, and their results are "
      "lost"),
    M("offline-positions-not-gathered", "offline.py",
      "        xyz.extend(point_base.tolist())\n",
      "        xyz.extend(point_base.tolist()[:0])\n",
      "the ground truth is matched without the positions of the frames located"),
    M("offline-ids-not-gathered", "offline.py",
      "            ids.add(t.id)\n",
      "            ids.add(t.name)\n",
      "the ids located under a target name are not gathered for the target order"),
    M("mcap-index-parsed-into-a-list", "io/bags/storage_mcap.py",
      "            self.chunks = ChunkTable.building()  # type: ignore[assignment]\n",
      "            self.chunks = []\n",
      "rosbags parses the whole chunk index into its list before it is made compact"),
    M("chunk-table-append-anywhere", "io/bags/chunk_table.py",
      "        if self._n != len(self._cols):\n",
      "        if False:\n",
      "a cleared chunk table takes chunks again, out of step with its columns"),
    M("mcap-index-digest-head-only", "io/bags/storage_mcap.py",
      "    h.update(_read_range(bio, data_end, size))\n",
      "    h.update(b\"\")\n",
      "a bag rewritten at the same path with the same size and header reads the old index"),
    M("results-truth-table-order", "io/results.py",
      "            order = np.argsort(stamps, kind=\"stable\")\n",
      "            order = np.argsort(-stamps, kind=\"stable\")[::-1]\n",
      "the ground-truth points of one stamp come back in another order than added"),
    M("spill-fixes-not-on-read", "io/spill.py",
      "        for fix in self._fixes:\n",
      "        for fix in self._fixes[:0]:\n",
      "the ground truth matched after the bag was read never reaches the frames in the file"),
    M("spill-settles-past-the-item", "io/spill.py",
      "        spill = min(settled, len(items) - self._keep)",
      "        spill = min(settled + 1, len(items) - self._keep)",
      "the first frame still waiting goes to the temporary file with the settled ones"),
    M("spill-failed-batch-dropped", "io/spill.py",
      "        del items[:written]\n",
      "        del items[:spill]\n",
      "frames whose batch could not be written to the full disk are lost"),
    M("spill-keeps-all-in-memory", "io/spill.py",
      "        if len(items) <= self._keep or self.problem is not None:\n",
      "        if True:\n",
      "a long run keeps every frame in memory"),
    M("bags-rosbags-yaml-shared", "io/bags/reading.py",
      "                return copy.deepcopy(_safe_yaml_of(yaml_class, stream))\n",
      "                return _safe_yaml_of(yaml_class, stream)\n",
      "every opening of a bag gets the same parsed metadata (one reader's change seen by all)"),
    M("bags-rosbags-yaml-every-open", "io/bags/reading.py",
      '            if self.typ == ["safe"] and not self.pure and isinstance(stream, str):\n',
      "            if False:\n",
      "rosbags parses a bag's metadata.yaml again at every opening"),
    M("writing-definition-not-kept", "io/bags/writing.py",
      "            known[msgtype] = hit\n",
      "            pass\n",
      "a type's definition is generated again for every topic of every bag"),
    M("results-built-types-unprepared", "io/results.py",
      "    for msgtype in _BUILT_TYPES:\n        store.get_msgdef(msgtype)\n",
      "    pass\n",
      "the output bag's serializers are generated after the pass, not while the workers run"),
    M("results-writer-private-store", "io/results.py",
      "    with BagWriter(out, storage=storage, typestore=default_typestore()) as writer,",
      "    with BagWriter(out, storage=storage) as writer,",
      "the output bag is written with a new type store: what was prepared is not used"),
    M("mcap-message-record-length", "io/bags/storage_mcap.py",
      "_MESSAGE_FIELDS = 2 + 4 + 8 + 8\n",
      "_MESSAGE_FIELDS = 2 + 4 + 8\n",
      "a message record's length leaves out its publish time"),
    M("workers-stop-tells-none", "workers.py",
      "        for w in self._workers:\n            w.close_input()\n",
      "        pass\n",
      "stopping the pool tells no worker to exit (and tasks can still be sent)"),
    M("offline-counts-out-of-order", "offline.py",
      '        counts["worker_timeouts"] = counts["pairs_relocated"] = 0\n',
      "",
      "summary.json lists the pool's counts after the end-of-bag ones (its bytes change)"),
    M("offline-dead-worker-unnoted", "offline.py",
      "            if not any(f\"worker process {pid} \" in n for n in self.notes):\n",
      "            if False:\n",
      "a worker process that dies between two pairs is not named in the notes"),
    M("offline-workers-leak-on-error", "offline.py",
      "    finally:\n        pool.close()\n    return run.finish",
      "    except BagError:\n        raise\n    pool.close()\n    return run.finish",
      "a bag that fails after the worker processes started leaves them running"),
    M("mcap-index-cache-unchecked", "io/bags/storage_mcap.py",
      "                if hit_size == size and _digest(",
      "                if True or hit_size == size and _digest(",
      "a bag written again under the same name is read with the old file's index"),
    M("mcap-index-cache-shared-lists", "io/bags/storage_mcap.py",
      "                        setattr(self, k, _copied(v))\n",
      "                        setattr(self, k, v)\n",
      "a reader closed clears the kept index that the next opening of the file takes"),
    M("mcap-index-cache-scanned-kept", "io/bags/storage_mcap.py",
      "            if self._scanned:\n                return\n",
      "            pass\n",
      "the index of a file read by scanning its data is kept, checked by its summary alone"),
    M("mcap-index-cache-fifo", "io/bags/storage_mcap.py",
      "                    _INDEX_CACHE.move_to_end(key)      # used last (if it still matches)\n",
      "                    pass\n",
      "the file used last is dropped from the kept indexes first"),
    M("offline-workers-after-rig", "offline.py",
      "            if mappable or in_workers:\n                pool.start_processes()\n"
      "        pool.use_rig(run.load_rig())\n",
      "            pass\n        pool.use_rig(run.load_rig())\n"
      "        if in_workers or (pool.parallel and mappable):\n"
      "            pool.start_processes()\n",
      "the worker processes start only after the rig is read"),
    M("workers-uninitialised-waited-for", "workers.py",
      "        if not self._initialized:\n            for w in self._workers:\n",
      "        if False:\n            for w in self._workers:\n",
      "closing a pool never initialised waits for its workers' imports"),
    M("workers-no-preload", "workers.py",
      "        importlib.import_module(preload)   # init's module, while the parent gets",
      "        pass  # nothing imported early:",
      "a deferred pool's workers import nothing until they are initialised"),
    M("workers-fork-keeps-fds", "workers.py",
      "        _close_inherited()\n",
      "        pass\n",
      "a forked worker keeps the parent's descriptors: another worker's stdin never ends"),
    M("workers-fork-beside-threads", "workers.py",
      '        return len(os.listdir("/proc/self/task")) == 1\n',
      "        return True\n",
      "workers are forked from a process that runs other threads"),
    M("params-key-check-loads-rclpy", "nodes/parameters.py",
      '                                      "hand_eye": "hand_eye_params",\n',
      "",
      "checking a parameter file's keys loads rclpy (through the hand_eye node module)"),
    M("offline-idle-work-dropped", "offline.py",
      "        pool.run_idle(len(pool.idle))\n",
      "",
      "process_bag's idle work is never run when the pass does not wait"),
    M("bags-metadata-parsed-every-open", "io/bags/reading.py",
      "@functools.lru_cache(maxsize=16)\ndef _parsed_metadata(",
      "def _parsed_metadata(",
      "a metadata.yaml is parsed again at every opening of its bag"),
    M("workers-init-twice", "workers.py",
      "        if self._initialized:\n",
      "        if False:\n",
      "a pool's workers can be sent their init call twice"),
    M("offline-unpaired-count", "offline.py",
      '        self.count("unpaired_left", sync.stats.dropped_left + pl)\n',
      '        self.count("unpaired_left", pl)\n',
      "left images dropped by the stereo pairing missing from the loss ledger"),
    # -- held-out batch 1 (tools/mutation_heldout.py --batch 1): the bugs no test caught,
    # with the tests written for them
    # core/handeye/average.py
    M("avg-parallel-counted-twice", "core/handeye/average.py",
      '    parallel = ~small & (sep < min_axis_angle_deg)\n',
      '    parallel = (sep < min_axis_angle_deg)\n',
      'a pair with a small rotation is counted under parallel axes too (counted twice)'),
    # core/handeye/budget.py
    M("budget-dof-correction", "core/handeye/budget.py",
      '    r2 = float(np.mean(np.square(board_dev_mm))) * n / max(n - 2, 1)\n',
      '    r2 = float(np.mean(np.square(board_dev_mm))) * n / max(n - 1, 1)\n',
      'the in-sample scatter corrected by n/(n-1), not n/(n-2)'),
    M("budget-systematic-rotation-sign", "core/handeye/budget.py",
      '        moved = d[:, :3] + np.cross(d[:, 3:], np.asarray(lev))\n',
      '        moved = d[:, :3] - np.cross(d[:, 3:], np.asarray(lev))\n',
      "the systematic correction's rotation moves the board origin the wrong way"),
    M("budget-largest-min", "core/handeye/budget.py",
      '    out["largest"] = max(finite, key=lambda k: finite[k])\n',
      '    out["largest"] = min(finite, key=lambda k: finite[k])\n',
      'the budget names the smallest part as the largest'),
    # core/handeye/select.py
    M("select-corner-rms-per-coordinate", "core/handeye/select.py",
      '            px[i] = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))\n',
      '            px[i] = float(np.sqrt(np.mean(e ** 2)))\n',
      'the held-out corner RMS per coordinate, not per corner (sqrt 2 low)'),
    # core/handeye/systematic.py
    M("systematic-residual-variance", "core/handeye/systematic.py",
      '    s2 = float(2.0 * res.cost / dof)\n',
      '    s2 = float(res.cost / dof)\n',
      'the residual variance from the cost without its factor 2'),
    M("systematic-nees-model-term", "core/handeye/systematic.py",
      '            S = s2 * (np.eye(6) + Jn @ Ainv @ Jn.T)\n',
      '            S = s2 * np.eye(6)\n',
      'held-out NEES ignores the uncertainty of X, Y and the model'),
    M("systematic-prior-scale", "core/handeye/systematic.py",
      '            out.append(p[12:] / level)\n',
      '            out.append(p[12:] * level)\n',
      'the prior residual multiplies by the level instead of dividing'),
    M("systematic-min-samples", "core/handeye/systematic.py",
      '    if n < _MIN_SAMPLES_SYSTEMATIC:\n',
      '    if n <= _MIN_SAMPLES_SYSTEMATIC:\n',
      'six samples treated as too few for the systematic term'),
    # core/handeye/plan.py
    M("plan-score-deg-target", "core/handeye/plan.py",
      '    return (mm / cfg.target_mm) ** 2 + (deg / cfg.target_deg) ** 2\n',
      '    return (mm / cfg.target_mm) ** 2 + (deg / cfg.target_mm) ** 2\n',
      'the rotation part of the trace score divided by the mm target'),
    M("plan-suggest-twice", "core/handeye/plan.py",
      '        free[k] = False\n',
      '        pass\n',
      'the same candidate can be suggested twice'),
    # core/tf.py
    M("tf-jump-boundary", "core/tf.py",
      '        if (newest is not None and newest - int(stamp_ns) > self._jump_back) or (\n',
      '        if (newest is not None and newest - int(stamp_ns) >= self._jump_back) or (\n',
      'a transform exactly jump_back_ns older clears the buffer'),
    # core/locator.py
    M("locator-size-one-sided", "core/locator.py",
      '                factor = max(rng / rng_size, rng_size / rng)\n',
      '                factor = rng / rng_size\n',
      'the size gate rejects only a pair that is too far, not too near'),
    M("locator-cut-right", "core/locator.py",
      '            u[axis], u[2 + axis] = dl.cut_sigma_px, dr.cut_sigma_px\n',
      '            u[axis], u[2 + axis] = dl.cut_sigma_px, dl.cut_sigma_px\n',
      "the right image's threshold-cut term taken from the left detection"),
    M("locator-id-reuse", "core/locator.py",
      '                tr = _Track(state.next_k)\n',
      '                tr = _Track(len(tracks))\n',
      "a new blob's id from the number of known blobs (a retired id reused)"),
    # core/distances.py
    M("distances-max-units", "core/distances.py",
      '                               1000.0 * float(e.max()) if e.size else math.nan))\n',
      '                               float(e.max()) if e.size else math.nan))\n',
      "a target's largest error in metres, reported as mm"),
    # core/detection.py
    M("detection-edge-width-cosine", "core/detection.py",
      '    return float((s1[ok] ** 2 / s2[ok] * cos[ok]).sum() / k) / '
      '(2.0 * math.sqrt(math.pi))\n',
      '    return float((s1[ok] ** 2 / s2[ok]).sum() / k) / (2.0 * math.sqrt(math.pi))\n',
      "the edge width without the normal's cosine to the sampling axis"),
    M("detection-shade-y-mean", "core/detection.py",
      '                          weighted["m01"] / total - m["m01"] / m["m00"]])\n',
      '                          weighted["m01"] / total - m["m10"] / m["m00"]])\n',
      "the shading shift's y part relative to the x mean"),
    # core/sync.py
    M("sync-skew-abs", "core/sync.py",
      '        self.stats.max_abs_skew_ns = max(self.stats.max_abs_skew_ns, abs(rs - ls))\n',
      '        self.stats.max_abs_skew_ns = max(self.stats.max_abs_skew_ns, rs - ls)\n',
      'max_abs_skew_ns ignores pairs whose right frame is earlier'),
    M("pose-receive-refresh", "core/sync.py",
      '            self._received[i] = recv\n',
      '            pass\n',
      'a pose re-sent at the same stamp keeps the old receive time'),
    # core/calibration/detection.py
    M("saddle-accepts-extremum", "core/calibration/detection.py",
      '        ok = active & (det < 0)\n',
      '        ok = active & (det != 0)\n',
      'a window without a saddle (a blob) moves the corner to its extremum'),
    M("saddle-gradient-block", "core/calibration/detection.py",
      '        cg = v[:, None, None] * AtA_inv[3:5, 3:5][None]\n',
      '        cg = v[:, None, None] * AtA_inv[:2, :2][None]\n',
      "the corner covariance from the quadratic terms' block, not the gradient's"),
    M("saddle-sigma-per-axis", "core/calibration/detection.py",
      '    sigma[good] = np.sqrt(np.maximum(np.trace(cov[good], axis1=1, axis2=2), 0.0) / 2.0)\n',
      '    sigma[good] = np.sqrt(np.maximum(np.trace(cov[good], axis1=1, axis2=2), 0.0))\n',
      'the corner sigma as a 2-D norm, not per axis'),
    M("saddle-max-shift", "core/calibration/detection.py",
      '    good = np.isfinite(cov[:, 0, 0]) & (moved <= max_shift)\n',
      '    good = np.isfinite(cov[:, 0, 0])\n',
      'a corner moved beyond max_shift is kept'),
    M("calib-sigma-median", "core/calibration/detection.py",
      '                sigma_px=float(np.median(finite)) if finite.size else float("nan"))\n',
      '                sigma_px=float(np.mean(finite)) if finite.size else float("nan"))\n',
      "the detection's sigma_px as the mean, not the median, of its corners'"),
    # io/bag_samples.py
    M("bag-samples-window", "io/bag_samples.py",
      '    half = int(round(still_window_s * 0.5e9))\n',
      '    half = int(round(still_window_s * 1e9))\n',
      'the stillness window twice still_window_s'),
    M("bag-samples-middle", "io/bag_samples.py",
      '    chosen = {g[len(g) // 2][0]: (f"stop{k:03d}", g[len(g) // 2][1])\n',
      '    chosen = {g[0][0]: (f"stop{k:03d}", g[0][1])\n',
      "a stop's first image chosen, not its middle one"),
    M("bag-samples-still-or", "io/bag_samples.py",
      '        return dt <= still_translation_m and float(np.arccos(c)) <= rot_tol\n',
      '        return dt <= still_translation_m or float(np.arccos(c)) <= rot_tol\n',
      'a pose that only rotates counted as still'),
    # io/config.py
    M("config-noise-zero", "io/config.py",
      '                or v < 0:\n',
      '                or v <= 0:\n',
      'a robot_pose_noise of 0 refused (documented >= 0)'),
    # nodes/detect_triangulate.py
    M("detect-slop-units", "nodes/detect_triangulate.py",
      '        slop_ns = int(round(values["sync.slop_s"] * 1e9))\n',
      '        slop_ns = int(round(values["sync.slop_s"] * 1e6))\n',
      'sync.slop_s converted with 1e6'),
    # -- held-out batch 2 (tools/mutation_heldout.py --batch 2): the bugs no test caught
    # when it was measured, with the tests written after
    M("avg2-min-pairs", "core/handeye/average.py",
      '    if len(Xs) < MIN_PAIRS:\n',
      '    if len(Xs) <= MIN_PAIRS:\n',
      'exactly MIN_PAIRS usable pairs refused'),
    M("budget2-camera-units", "core/handeye/budget.py",
      '        c2 = 1e6 * float(np.mean([_centre_variance(s, cameras, px, np.zeros(3))\n',
      '        c2 = 1e3 * float(np.mean([_centre_variance(s, cameras, px, np.zeros(3))\n',
      "the camera part's m^2 -> mm^2 factor 1e3, not 1e6"),
    M("budget2-pnp-rms", "core/handeye/budget.py",
      '        px = float(np.sqrt(np.mean(np.square(pnp))))\n',
      '        px = float(np.mean(pnp))\n',
      "the corners' pixel noise as the mean PnP residual, not the RMS"),
    M("select2-combine-mm-scale", "core/handeye/select.py",
      '        return ({k: np.hypot(np.asarray(h.px) / ref_px, h.mm / ref_mm)\n',
      '        return ({k: np.hypot(np.asarray(h.px) / ref_px, h.mm)\n',
      "the combined score's board position not divided by its median RMS"),
    M("select2-centre-at-point", "core/handeye/select.py",
      '    return float(np.trace(Jc @ cov @ Jc.T))\n',
      '    return float(np.trace(cov[:3, :3]))\n',
      "the centre variance of the pose's translation, not propagated to the board point"),
    M("eiv2-pose-rotation-transpose", "core/handeye/eiv.py",
      '            dR = np.einsum("kji,kjl->kil", self.C[:, :3, :3], C[:, :3, :3])\n',
      '            dR = np.einsum("kij,kjl->kil", self.C[:, :3, :3], C[:, :3, :3])\n',
      'pose pairs: the rotation residual without the transpose of the measured rotation'),
    M("systematic2-weights-swapped", "core/handeye/systematic.py",
      '    w = np.array([1 / s_t] * 3 + [1 / s_r] * 3)\n',
      '    w = np.array([1 / s_r] * 3 + [1 / s_t] * 3)\n',
      'the residual whitening swaps the translation and rotation levels'),
    M("systematic2-dof-parameters", "core/handeye/systematic.py",
      '        p = 12 + (18 if level > 0 else 0)\n',
      '        p = 12\n',
      "the first pass's degrees of freedom ignore the 18 systematic parameters"),
    M("systematic2-eye-to-hand-implied", "core/handeye/systematic.py",
      '    return X @ cam_T_board @ np.linalg.inv(Y)\n',
      '    return X @ cam_T_board @ Y\n',
      'eye-to-hand: the implied flange pose without inv(Y)'),
    M("plan2-rotation-noise", "core/handeye/plan.py",
      '                "robot_r": max(float(self.robot_sigma_rot_rad), '
      'SIGMA_FLOORS["robot_r"])}\n',
      '                "robot_r": max(float(self.robot_sigma_pos_m), SIGMA_FLOORS["robot_r"])}\n',
      "the planner's rotation noise taken from the position noise"),
    M("plan2-outline-spacing", "core/handeye/plan.py",
      '    lo, hi = uv.min(axis=0) - spacing, uv.max(axis=0) + spacing\n',
      '    lo, hi = uv.min(axis=0), uv.max(axis=0)\n',
      'the board outline at the outer corners, not one spacing beyond'),
    M("locator2-track-cost-flat", "core/locator.py",
      '                    cost[p, t] = dist\n',
      '                    cost[p, t] = 0.0\n',
      'blobs matched to known ids regardless of distance within the gate'),
    M("calib2-spacing-max", "core/calibration/detection.py",
      '    return float(min(dx.min(), dy.min()))\n',
      '    return float(max(dx.min(), dy.min()))\n',
      'the corner spacing from the wider direction (the subpixel window too large)'),
    M("bag-samples2-group-drift", "io/bag_samples.py",
      '        if current and not close(current[0][1], at):\n',
      '        if current and not close(current[-1][1], at):\n',
      'a stop compared with its latest pose, not its first (a slow drift stays one stop)'),
    M("config2-flat-covariance", "io/config.py",
      '    if cov.shape == (36,):\n        cov = cov.reshape(6, 6)\n',
      '    if False:\n        cov = cov.reshape(6, 6)\n',
      'a flat 36-number covariance refused'),
)

#: Left out of the workers' copies of the tree (symlinked when ``_LINKED``).
_SKIP = {".git", ".venv", "build", "install", "log", ".pytest_cache", "__pycache__",
         ".mypy_cache", ".ruff_cache", ".coverage"}
_LINKED = {"bags"}


def _copy_tree(dest: Path) -> None:
    """A private copy of the source tree (the package, tests, data, configs) at ``dest``."""
    dest.mkdir(parents=True)
    for entry in ROOT.iterdir():
        if entry.name in _SKIP:
            continue
        if entry.name in _LINKED:
            (dest / entry.name).symlink_to(entry)
        elif entry.is_dir():
            shutil.copytree(entry, dest / entry.name,
                            ignore=shutil.ignore_patterns(*_SKIP), symlinks=True)
        else:
            shutil.copy2(entry, dest / entry.name)


def _run_tests(tree: Path, tests: tuple[str, ...], timeout_s: float) -> tuple[bool, float]:
    """Run the tests of the copy at ``tree`` against its package; (passed, seconds)."""
    t0 = time.monotonic()
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1",
           "PYTHONPATH": os.pathsep.join([str(tree)] + ([os.environ["PYTHONPATH"]]
                                                       if os.environ.get("PYTHONPATH")
                                                       else []))}
    try:
        proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p",
                               "no:cacheprovider", *tests], cwd=tree, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, timeout=timeout_s, env=env)
        passed = proc.returncode == 0
    except subprocess.TimeoutExpired:
        passed = False  # a mutant that hangs the tests is caught (by the time-out)
    return passed, time.monotonic() - t0


def _stale(m: Mutant) -> bool:
    return (ROOT / m.path).read_text().count(m.old) != 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-k", default="",
                        help="only mutants whose name or module contains this (several: "
                             "comma-separated, any of them)")
    parser.add_argument("-v", action="store_true", help="say what each mutant does")
    parser.add_argument("-j", type=int, default=2, help="workers (default 2)")
    parser.add_argument("--list", action="store_true",
                        help="print the table (mutant, module, tests) and stale mutants only")
    parser.add_argument("--timeout", type=float, default=600.0, help="per mutant, seconds")
    parser.add_argument("--baseline", action="store_true",
                        help="first run every chosen module's tests unmutated in the copies: "
                             "a set that fails there would make its mutants look caught")
    args = parser.parse_args(argv)
    t_start = time.monotonic()
    names = [m.name for m in MUTANTS]
    dup = sorted({n for n in names if names.count(n) > 1})
    missing = sorted({m.module for m in MUTANTS} - set(TESTS))
    if dup or missing:
        print(f"bad mutant table: duplicate names {dup}, modules without tests {missing}")
        return 2
    keys = args.k.split(",")
    chosen = [m for m in MUTANTS if any(k in m.name or k in m.module for k in keys)]
    live = []
    stale = 0
    for m in chosen:
        if _stale(m):
            stale += 1
            print(f"STALE    {m.name}: its text is not (once) in {m.path}", flush=True)
        else:
            live.append(m)
    if args.list:
        for m in live:
            print(f"{m.name:38s} {m.module:28s} {' '.join(Path(t).name for t in m.tests)}")
        print(f"{len(live)} live mutants in {len({m.module for m in live})} modules"
              + (f", {stale} stale" if stale else ""))
        return 0 if stale == 0 else 1
    results: dict[str, bool] = {}
    lock = threading.Lock()
    todo: queue.Queue[Mutant] = queue.Queue()
    if args.baseline:
        # the same machinery with an empty mutation of each module's first mutant
        for module in dict.fromkeys(m.module for m in live):
            first = next(m for m in live if m.module == module)
            todo.put(Mutant(f"baseline:{module}", module, first.old, first.old, "no change"))
    else:
        for m in live:
            todo.put(m)

    def worker(tree: Path) -> None:
        while True:
            try:
                m = todo.get_nowait()
            except queue.Empty:
                return
            path = tree / m.path
            original = path.read_text()
            try:
                path.write_text(original.replace(m.old, m.new))
                passed, secs = _run_tests(tree, m.tests, args.timeout)
            finally:
                path.write_text(original)
            with lock:
                if m.name.startswith("baseline:"):
                    results[m.name] = passed
                    print(f"{'passes  ' if passed else 'FAILS   '} {m.name} ({secs:.0f} s)",
                          flush=True)
                    continue
                results[m.name] = passed
                label = "SURVIVED" if passed else "caught  "
                print(f"{label} {m.name} ({secs:.0f} s)"
                      + (f": {m.what}" if args.v or passed else ""), flush=True)

    with tempfile.TemporaryDirectory(prefix="eye_in_hand-mutation-") as tmp:
        trees = []
        for k in range(max(1, min(args.j, len(live)))):
            tree = Path(tmp) / f"w{k}"
            _copy_tree(tree)
            trees.append(tree)
        threads = [threading.Thread(target=worker, args=(t,), daemon=True) for t in trees]
        for t in threads:
            t.start()
        for t in threads:
            while t.is_alive():
                t.join(0.5)
    if args.baseline:
        failing = sorted(n for n, ok in results.items() if not ok)
        print(f"baseline: {len(results) - len(failing)}/{len(results)} test sets pass unmutated"
              + (f"; failing: {', '.join(failing)}" if failing else "")
              + f" ({time.monotonic() - t_start:.0f} s, {len(trees)} workers)")
        return 0 if not failing else 1
    survived = [n for n in names if results.get(n)]
    caught = sum(1 for v in results.values() if not v)
    print(f"mutation score: {caught}/{len(results)} caught"
          + (f", {stale} stale" if stale else "")
          + (f"; survived: {', '.join(survived)}" if survived else "")
          + f" ({time.monotonic() - t_start:.0f} s, {len(trees)} workers)")
    return 0 if not survived and stale == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
