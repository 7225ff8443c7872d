"""TF benchmark: the cost of the ``tf`` robot-pose source.

Run: ``.venv/bin/python benchmarks/bench_tf.py`` (a few seconds, no DDS).

Figures printed:
* ``TfBuffer.set_transform``: microseconds per transform, feeding a UR5e chain (6 joints per
  ``/tf`` message at 500 Hz) into a buffer of 4000 samples per edge;
* ``TfBuffer.lookup(base_link, tool0)`` at a stamp between two samples: microseconds per lookup
  (6 interpolated edges + 1 static edge), against ``PoseBuffer.lookup`` of the composed pose
  (the ``ee_pose`` source);
* agreement with forward kinematics at the interpolated joint vector (max position error, um),
  which is what interpolating each joint's transform instead of the tool pose costs;
* ``Localizer.locate`` of one point with covariance, with and without ``hand_eye.yaml``'s
  ``robot_pose_correction`` (the systematic robot model), against its floor, the
  ``PoseBuffer.lookup`` it starts with (best of 5 repeats);
* ``LocalizationPipeline.add_point`` of the same point, its robot pose buffered (queued, the
  wait rule, located, handed to a sink: what the ``hand_eye`` node pays per point before
  publishing), against ``Localizer.locate`` alone.
"""
from __future__ import annotations

import time

import numpy as np

from eye_in_hand.core.kinematics import DHChain
from eye_in_hand.core.localization import Localizer, LocalizerConfig
from eye_in_hand.core.pipeline import LocalizationPipeline, PipelineRules
from eye_in_hand.core.pose_correction import RobotPoseCorrection
from eye_in_hand.core.sync import PoseBuffer
from eye_in_hand.core.tf import TfBuffer
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.ros.tf import chain_tf_edges

T0 = 1_700_000_000_000_000_000
PERIOD = 2_000_000          # 500 Hz
N = 4000


def _q(t_s: float) -> np.ndarray:
    return np.array([0.1, -1.2, 1.3, -1.6, -1.5, 0.2]) + np.array(
        [0.3, -0.2, 0.25, 0.4, -0.3, 0.5]) * np.sin(2.0 * t_s)


def main() -> None:
    chain = DHChain.from_dict({**DHChain.ur5e().to_dict(),
                               "link_names": ["shoulder_link", "upper_arm_link", "forearm_link",
                                              "wrist_1_link", "wrist_2_link", "flange"]})
    tool = from_rotvec([0.0, 0.0, 0.3], [0.0, 0.0, 0.02])
    buf, poses = TfBuffer(N), PoseBuffer(N)
    buf.set_transform("flange", "tool0", 0, tool, static=True)
    stamps = [T0 + k * PERIOD for k in range(N)]
    edges = [chain_tf_edges(chain, _q(k * PERIOD / 1e9)) for k in range(N)]
    t = time.perf_counter()
    for s, es in zip(stamps, edges, strict=True):
        for p, c, T in es:
            buf.set_transform(p, c, s, T)
    add_us = (time.perf_counter() - t) / (N * 6) * 1e6
    for k, s in enumerate(stamps):
        poses.add(s, chain.fk(_q(k * PERIOD / 1e9)) @ tool)
    rng = np.random.default_rng(0)
    queries = [int(s) for s in rng.integers(stamps[1], stamps[-2], 2000)]
    t = time.perf_counter()
    for s in queries:
        buf.lookup("base_link", "tool0", s, 50_000_000)
    tf_us = (time.perf_counter() - t) / len(queries) * 1e6
    t = time.perf_counter()
    for s in queries:
        poses.lookup(s, 50_000_000)
    pb_us = (time.perf_counter() - t) / len(queries) * 1e6
    err = max(np.linalg.norm(buf.lookup("base_link", "tool0", s, 50_000_000)[:3, 3]
                             - (chain.fk(_q((s - T0) / 1e9)) @ tool)[:3, 3])
              for s in queries[:500])
    print(f"TfBuffer.set_transform: {add_us:.1f} us per transform (UR5e, 6 edges per message)")
    print(f"TfBuffer.lookup base_link -> tool0 (6 interpolated + 1 static edges): {tf_us:.1f} us;"
          f" PoseBuffer.lookup of the composed pose: {pb_us:.1f} us")
    print(f"TF chain at 500 Hz vs FK at the exact joint vector: max {err * 1e6:.2f} um")
    locate_figures(poses, queries)


def locate_figures(poses: PoseBuffer, queries: list[int]) -> None:
    """The localizer's cost per point with and without a robot pose correction."""
    ee_T_cam = from_rotvec([0.02, -0.03, 1.6], [0.05, 0.01, -0.04])
    corr = RobotPoseCorrection(np.diag([0.02, -0.01, 0.015]), np.full((3, 3), 0.003),
                               from_rotvec([np.pi, 0.0, 0.0])[:3, :3])
    p, cov = np.array([0.02, -0.01, 0.45]), np.diag([1e-8, 1e-8, 4e-7])

    def best(fn) -> float:
        runs = []
        for _ in range(5):
            t = time.perf_counter()
            for s in queries:
                fn(s)
            runs.append((time.perf_counter() - t) / len(queries) * 1e6)
        return min(runs)

    floor = best(lambda s: poses.lookup(s, 50_000_000))
    out = {}
    for name, c in (("without", None), ("with", corr)):
        loc = Localizer(ee_T_cam, np.eye(6) * 1e-8, LocalizerConfig(
            max_gap_ns=50_000_000, robot_sigma_pos_m=1.5e-4, robot_sigma_rot_rad=4e-4),
            pose_correction=c)
        loc.poses = poses
        out[name] = best(lambda s, loc=loc: loc.locate(s, p, cov))
    print(f"Localizer.locate, one point with covariance: {out['without']:.1f} us without a robot "
          f"pose correction, {out['with']:.1f} us with one (+{out['with'] - out['without']:.1f}"
          f" us); floor PoseBuffer.lookup {floor:.1f} us")
    pipeline_figure(poses, queries, ee_T_cam, p, cov)


class _Sink:
    def point_located(self, item, point_base, cov_base) -> None:
        pass

    def point_refused(self, item, reason, detail) -> None:
        raise AssertionError(f"{reason}: {detail}")


def pipeline_figure(poses: PoseBuffer, queries: list[int], ee_T_cam: np.ndarray,
                    p: np.ndarray, cov: np.ndarray) -> None:
    """The pipeline's cost per point over the localizer's (the queue and its rules)."""
    loc = Localizer(ee_T_cam, np.eye(6) * 1e-8, LocalizerConfig(
        max_gap_ns=50_000_000, robot_sigma_pos_m=1.5e-4, robot_sigma_rot_rad=4e-4))
    loc.poses = poses
    pipe = LocalizationPipeline(loc, PipelineRules(), wait_clock=time.monotonic,
                                points=_Sink())
    runs: dict[str, list[float]] = {"locate": [], "pipeline": []}
    for _ in range(5):
        t = time.perf_counter()
        for s in queries:
            loc.locate(s, p, cov)
        runs["locate"].append((time.perf_counter() - t) / len(queries) * 1e6)
        t = time.perf_counter()
        for s in queries:
            pipe.add_point(s, p, cov)
        runs["pipeline"].append((time.perf_counter() - t) / len(queries) * 1e6)
    best = {k: min(v) for k, v in runs.items()}
    print(f"LocalizationPipeline.add_point, one point with covariance, its pose buffered: "
          f"{best['pipeline']:.1f} us; Localizer.locate alone {best['locate']:.1f} us "
          f"(+{best['pipeline'] - best['locate']:.1f} us for the queue and its rules)")


if __name__ == "__main__":
    main()
