"""CPU of the ``hand_eye`` node per stereo pair, on its own: a live stream of what the detector
and the robot send it, every output subscribed (issue 24: at most 1.5 ms per pair).

Run: ``.venv/bin/python benchmarks/bench_hand_eye_node.py [--rounds 3] [--compare OTHER]
[--pose-rate HZ]``

This process plays ``detect_triangulate`` and the robot driver: ``ee_pose`` at 125 Hz and, at
30 Hz, one located target as the detector sends it (``target/point_cov``, ``target/point``,
``targets/red/point_cov``, ``targets/red/point``, ``targets/markers``, stamped 8 ms before
they go out, as an image is), for ``--pairs`` pairs. It subscribes to every ``hand_eye``
output (``target/pose``, ``target/pose_cov``, ``target/red/pose(_cov)``, ``target/poses``,
``target/markers``, ``/tf``) and counts the poses. Printed per round: the node process's CPU
per pair (Linux ``/proc``, between the 60th and the last-60th pair: start-up and the idle
tail left out), split between its Python thread (the executor and every callback) and the
middleware's threads, and the poses received. No images and no detector share the machine,
so the figure moves far less between runs than the live chain's (``bench_localization.py
--live-only``, which measures the same node beside the detector).

``--pose-rate HZ``: ``ee_pose`` at that rate instead of 125 Hz (a 1 kHz arm: 33 poses a
pair).

``--compare OTHER``: the node of another checkout (started from its directory, with it on
``PYTHONPATH``) in alternate rounds; the medians of both are printed.

``--floor``: also, in alternate rounds, the floor node (:func:`floor_node`: the same
subscriptions and seven publications per pair on the same executor, QoS and publishers, and
nothing else: no decoding, no localization, no timers or diagnostics), and each node's
median as a multiple of its median. What the floor costs is the price of the traffic on
this machine (waking after 33 ms idle, the middleware's threads, the first publication of a
burst: ``bench_ros_glue.py --publish-after-idle``); what ``hand_eye`` costs above it is its
own work.

``--rate-scale K``: both streams K times as fast (K = 5: 150 pairs and 625 poses per second),
the same messages per pair. What a pair costs falls as the rate rises (2026-11-28, 1200 pairs,
rounds alternating: 2.30 and 1.85 ms at 30 Hz, 1.09 and 1.15 ms at 150 Hz): on this machine
code that runs after tens of milliseconds idle costs more than the same code run back to back
(caches, branch history and the virtual CPU's wake-up), so the difference is the price of
waking 30 times a second, not work the node does.
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_localization import (  # this script's folder is on sys.path
    spin_in_background,
    subscribe_outputs,
)

ROOT = Path(__file__).resolve().parent.parent

HAND_EYE_YAML = """\
setup: eye_in_hand
parent_frame: tool0
child_frame: camera_left_optical_frame
translation: [0.032, -0.061, 0.041]
quat_xyzw: [0.0093915, -0.0151881, 0.7112696, 0.7026925]
method: refined
covariance:
- [1.0e-9, 0.0, 0.0, 0.0, 0.0, 0.0]
- [0.0, 1.0e-9, 0.0, 0.0, 0.0, 0.0]
- [0.0, 0.0, 1.0e-9, 0.0, 0.0, 0.0]
- [0.0, 0.0, 0.0, 4.0e-9, 0.0, 0.0]
- [0.0, 0.0, 0.0, 0.0, 4.0e-9, 0.0]
- [0.0, 0.0, 0.0, 0.0, 0.0, 4.0e-9]
covariance_order: [x, y, z, rx, ry, rz]
sample_count: 15
"""

PARAMS = """\
/**/hand_eye:
  ros__parameters:
    mode: localization
    hand_eye_file: {hand_eye}
    robot_pose_source: ee_pose
    base_frame: base_link
    ee_frame: tool0
    camera_frame: camera_left_optical_frame
    max_pose_gap_s: 0.05
    max_pose_wait_s: 1.0
    max_target_wait_s: 1.0
"""

def _cpu_s(pid: int) -> float:
    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK")


def _threads_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds of each thread of ``pid`` by kind: ``python`` (the interpreter's thread,
    where the executor and every callback run) and ``middleware`` (Fast DDS's threads)."""
    out = {"python": 0.0, "middleware": 0.0}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:                       # a thread that ended meanwhile
            continue
        fields = stat.rsplit(")", 1)[1].split()
        kind = "python" if task.name == str(pid) else "middleware"
        out[kind] += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return out


def floor_node() -> None:
    """The floor of ``hand_eye``'s CPU per pair (``--floor``): a node with its traffic and
    no work. On :class:`~eye_in_hand.ros.executor.LeanExecutor`, as ``hand_eye``, it
    subscribes (serialized bytes, not decoded) to what the detector sends per pair
    (``target/point``, ``target/point_cov``, ``targets/red/point_cov``, ``targets/markers``)
    and to ``ee_pose`` (passive: taken with each frame, as ``hand_eye`` takes robot poses),
    and at each ``targets/markers`` takes the queued poses and publishes seven prebuilt
    messages (``target/pose(_cov)``, ``target/red/pose(_cov)``, ``target/poses``,
    ``target/markers``, ``/tf``: what ``hand_eye`` sends per pair, every output subscribed),
    on the same QoS and publishers without event handlers. No timer, parameter file,
    diagnostics or decoding."""
    import rclpy
    from geometry_msgs.msg import (
        PointStamped,
        PoseArray,
        PoseStamped,
        PoseWithCovarianceStamped,
    )
    from rclpy.node import Node
    from tf2_msgs.msg import TFMessage
    from visualization_msgs.msg import MarkerArray

    from eye_in_hand.ros.executor import LeanExecutor, set_passive, take_queued
    from eye_in_hand.ros.node_main import prepare_process, sigterm_as_interrupt
    from eye_in_hand.ros.outputs import Sphere
    from eye_in_hand.ros.outputs_cdr import (
        point_pose_cdr,
        pose_array_cdr,
        sphere_markers_cdr,
        translation_tf_cdr,
    )
    from eye_in_hand.ros.publishers import OutputPublishers
    from eye_in_hand.ros.qos import RESULT_QOS, ROBOT_POSE_QOS, TARGET_POINT_QOS
    from eye_in_hand.ros.tf import tf_qos

    prepare_process()
    sigterm_as_interrupt()
    rclpy.init()
    node = Node("hand_eye")
    create = OutputPublishers(node, lambda *_a: None).create
    p, cov = (0.4, 0.1, 0.5), [[1e-8, 0, 0], [0, 1e-8, 0], [0, 0, 4e-8]]
    pose, pose_cov = point_pose_cdr(p, cov, 5, "base_link")
    out = [(create(PoseStamped, "target/pose", RESULT_QOS), pose),
           (create(PoseWithCovarianceStamped, "target/pose_cov", RESULT_QOS), pose_cov),
           (create(PoseWithCovarianceStamped, "target/red/pose_cov", RESULT_QOS), pose_cov),
           (create(PoseStamped, "target/red/pose", RESULT_QOS), pose),
           (create(PoseArray, "target/poses", RESULT_QOS), pose_array_cdr([p], 5, "base_link")),
           (create(MarkerArray, "target/markers", RESULT_QOS), sphere_markers_cdr(
               [Sphere("red", p, 0.07, (1.0, 0.0, 0.0, 1.0))], 5, "base_link", 0.0)),
           (create(TFMessage, "/tf", tf_qos()),
            translation_tf_cdr([("base_link", "target_red", 5, p)]))]
    poses = node.create_subscription(PoseStamped, "ee_pose", lambda _raw: None,
                                     ROBOT_POSE_QOS, raw=True)
    set_passive(poses, True)

    def frame(_raw: bytes) -> None:
        take_queued(poses)
        for pub, msg in out:
            pub.publish(msg)

    for msg_type, topic, qos in ((PointStamped, "target/point", RESULT_QOS),
                                 (PoseWithCovarianceStamped, "target/point_cov", RESULT_QOS),
                                 (PoseWithCovarianceStamped, "targets/red/point_cov",
                                  TARGET_POINT_QOS)):
        node.create_subscription(msg_type, topic, lambda _raw: None, qos, raw=True)
    node.create_subscription(MarkerArray, "targets/markers", frame, RESULT_QOS, raw=True)
    executor = LeanExecutor()
    try:
        rclpy.spin(node, executor)
    except KeyboardInterrupt:
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def one_round(code_root: Path | None, params: Path, pairs: int, domain: int,
              rate_scale: float = 1.0, pose_hz: float = 125.0
              ) -> tuple[float, int, dict[str, float]]:
    """The node of ``code_root`` (None: :func:`floor_node`) fed ``pairs`` pairs at
    ``rate_scale`` times 30 Hz (poses at ``rate_scale`` times ``pose_hz``): (CPU ms per
    pair, poses received, CPU ms per pair of the node's Python thread and of its middleware
    threads)."""
    import rclpy
    from geometry_msgs.msg import (
        PointStamped,
        PoseStamped,
        PoseWithCovarianceStamped,
    )
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from visualization_msgs.msg import MarkerArray

    from eye_in_hand.ros.outputs import (
        Sphere,
        point_stamped,
        pose_with_covariance,
        rclpy_types,
        sphere_markers,
    )
    from eye_in_hand.ros.qos import RESULT_QOS, ROBOT_POSE_QOS, TARGET_POINT_QOS

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=str(code_root or ROOT))
    command = [sys.executable, str(Path(__file__).resolve()), "--floor-node"] \
        if code_root is None else [sys.executable, "-m", "eye_in_hand.nodes.hand_eye",
                                   "--ros-args", "--params-file", str(params)]
    node_proc = subprocess.Popen(command, cwd=code_root or ROOT, env=env,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    rclpy.init()
    node = Node("bench_hand_eye_feed")
    T = rclpy_types()
    received = [0]

    def on_pose(_msg: object) -> None:
        received[0] += 1

    node.create_subscription(PoseStamped, "/target/pose", on_pose, RESULT_QOS)
    subscribe_outputs(node, RESULT_QOS)
    pub_pose = node.create_publisher(PoseStamped, "/ee_pose", ROBOT_POSE_QOS)
    pub_cov = node.create_publisher(PoseWithCovarianceStamped, "/target/point_cov", RESULT_QOS)
    pub_point = node.create_publisher(PointStamped, "/target/point", RESULT_QOS)
    pub_tcov = node.create_publisher(PoseWithCovarianceStamped, "/targets/red/point_cov",
                                     TARGET_POINT_QOS)
    pub_tpoint = node.create_publisher(PointStamped, "/targets/red/point", TARGET_POINT_QOS)
    pub_markers = node.create_publisher(MarkerArray, "/targets/markers", RESULT_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    stop_spinning = spin_in_background(ex)
    try:
        deadline = time.monotonic() + 30.0
        while pub_markers.get_subscription_count() == 0 or \
                pub_pose.get_subscription_count() == 0:
            if time.monotonic() > deadline or node_proc.poll() is not None:
                raise SystemExit("the hand_eye node did not come up")
            time.sleep(0.05)
        time.sleep(1.0)                       # discovery of every output settles
        cov = [[1e-8, 0, 0], [0, 1e-8, 0], [0, 0, 4e-8]]
        t0 = time.time_ns()
        pose_period, frame_period = 1e9 / (pose_hz * rate_scale), 1e9 / (30.0 * rate_scale)
        k_pose = k_frame = 0
        cpu_a = cpu_b = None
        threads_a: dict[str, float] = {}
        threads_b: dict[str, float] = {}
        while k_frame < pairs:
            t_pose, t_frame = t0 + k_pose * pose_period, t0 + 8e6 + k_frame * frame_period
            t_next = min(t_pose, t_frame)
            delay = (t_next - time.time_ns()) / 1e9
            if delay > 0:
                time.sleep(delay)
            if t_pose <= t_frame:
                stamp = int(t_pose)
                msg = PoseStamped()
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
                msg.header.frame_id = "base_link"
                a = 0.2 * math.sin(stamp * 1e-9)
                msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = 0.4, a, 0.5
                msg.pose.orientation.w = 1.0
                pub_pose.publish(msg)
                k_pose += 1
                continue
            stamp = int(t_frame - 8e6)
            xyz = (0.01, 0.02, 0.6)
            cmsg = pose_with_covariance(T, xyz, cov, stamp, "camera_left_optical_frame")
            pmsg = point_stamped(T, xyz, stamp, "camera_left_optical_frame")
            pub_cov.publish(cmsg)
            pub_point.publish(pmsg)
            pub_tcov.publish(cmsg)
            pub_tpoint.publish(pmsg)
            pub_markers.publish(sphere_markers(T, [Sphere("red", xyz, 0.07, (1., 0., 0., 1.))],
                                               stamp, "camera_left_optical_frame"))
            k_frame += 1
            if k_frame == 60:
                cpu_a, threads_a = _cpu_s(node_proc.pid), _threads_cpu_s(node_proc.pid)
            elif k_frame == pairs - 60:
                cpu_b, threads_b = _cpu_s(node_proc.pid), _threads_cpu_s(node_proc.pid)
        time.sleep(0.5)
    finally:
        stop_spinning()
        node.destroy_node()
        rclpy.shutdown()
        node_proc.terminate()
        try:
            node_proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node_proc.kill()
    assert cpu_a is not None and cpu_b is not None
    n = pairs - 120
    return ((cpu_b - cpu_a) * 1e3 / n, received[0],
            {k: (threads_b[k] - threads_a[k]) * 1e3 / n for k in threads_b})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="rounds per checkout (default 3)")
    parser.add_argument("--pairs", type=int, default=600, help="pairs per round (default 600)")
    parser.add_argument("--compare", type=Path, metavar="OTHER",
                        help="another checkout's node in alternate rounds")
    parser.add_argument("--rate-scale", type=float, default=1.0, metavar="K",
                        help="both streams K times as fast (default 1: 30 Hz pairs, 125 Hz "
                             "poses)")
    parser.add_argument("--pose-rate", type=float, default=125.0, metavar="HZ",
                        help="the robot's ee_pose rate (default 125 Hz; a 1 kHz arm: 1000)")
    parser.add_argument("--floor", action="store_true",
                        help="also the floor node (the same traffic, no work) in alternate "
                             "rounds, and the node's ratio to it")
    parser.add_argument("--floor-node", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.floor_node:
        floor_node()
        return 0
    if args.pairs < 200:
        parser.error("--pairs: at least 200 (60 at each end are left out)")
    if not 0.1 <= args.rate_scale <= 20:
        parser.error("--rate-scale: between 0.1 and 20")
    if not 10 <= args.pose_rate <= 2000:
        parser.error("--pose-rate: between 10 and 2000 Hz")
    with tempfile.TemporaryDirectory() as tmp:
        he = Path(tmp) / "hand_eye.yaml"
        he.write_text(HAND_EYE_YAML)
        params = Path(tmp) / "params.yaml"
        params.write_text(PARAMS.format(hand_eye=he))
        codes: list[tuple[str, Path | None]] = [("this checkout", ROOT)]
        if args.compare is not None:
            codes.append((f"{args.compare}", args.compare.resolve()))
        if args.floor:
            codes.append(("floor", None))
        results: dict[str, list[float]] = {name: [] for name, _ in codes}
        domain = 100 + os.getpid() % 100
        for r in range(args.rounds):
            for name, code in codes:
                ms, got, threads = one_round(code, params, args.pairs, domain,
                                             args.rate_scale, args.pose_rate)
                results[name].append(ms)
                print(f"round {r + 1} {name}: {'hand_eye' if code else 'the floor node'} "
                      f"{ms:.2f} ms CPU per pair (Python "
                      f"thread {threads['python']:.2f}, middleware threads "
                      f"{threads['middleware']:.2f}), {got}/{args.pairs} poses received",
                      flush=True)
        floor = statistics.median(results["floor"]) if args.floor else None
        for name, values in results.items():
            med = statistics.median(values)
            ratio = f", {med / floor:.2f}x the floor" if floor and name != "floor" else ""
            print(f"{name}: median {med:.2f} ms CPU per pair{ratio} "
                  f"(target <= 1.5 ms at 30 Hz), pairs at {30 * args.rate_scale:g} Hz, "
                  f"ee_pose at {args.pose_rate * args.rate_scale:g} Hz, "
                  f"rounds {', '.join(f'{v:.2f}' for v in values)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
