"""Speed of the image conversions on the hot path (per call, median of repeated runs), and
the executor's CPU per received message.

Run: ``.venv/bin/python benchmarks/bench_ros_glue.py [--wakeups | --event-poll |
--publish-after-idle]``

``--wakeups``: another process publishes 2000 small messages at 500 Hz to a node on rclpy's
``SingleThreadedExecutor``; printed is the node process's CPU per received message with 0
publishers (the floor: a bare wake-up and take), with 12 and 24 publishers made the default
way (two QoS-event handlers each, rebuilt into the wait set at every wake-up) and without
handlers (``eye_in_hand.ros.publishers.OutputPublishers``), then the same node on
``eye_in_hand.ros.executor.LeanExecutor`` (what the package's nodes spin on), and on it with
the subscription passive and its messages taken at 30 Hz (``set_passive``, ``take_queued``:
how ``hand_eye`` takes robot poses), the layouts alternating, median of ``--rounds`` rounds.

``--event-poll``: another process publishes 1500 small messages at 30 Hz (a camera frame's
rate: each wake-up after 33 ms asleep) to a node with ``hand_eye``'s entities (7
subscriptions with their default QoS-event handlers, 14 events, 5 timers, the parameter
services) on ``LeanExecutor``; printed is the spinning thread's CPU per received message with
the QoS events in a wait at most every 0.5 s (``EVENT_POLL_S``, the default) and in every wait
(0), the two alternating every 50 messages in one process, for each of ``--rounds`` rounds.

``--publish-after-idle``: the CPU of ``Publisher.publish`` in the publishing thread, in
bursts of seven publications on seven topics (what ``hand_eye`` sends for one stereo pair),
each topic subscribed by another process: 600 bursts at 30 Hz, then 600 back to back, then
one publication at 30 Hz on a topic nobody subscribes to. On this machine the first
publication after 33 ms idle costs far more than the rest of its burst (the middleware wakes
its own and the subscriber's sleeping threads), so a node that publishes at camera rate pays
it once per frame whatever it publishes (docs/localization.md).

Prints, for a 1280x720 stereo-camera frame: numpy -> Image (one copy into the message),
Image -> numpy for rclpy and rosbags messages (zero-copy views, padded rows included),
big-endian mono16 (one byte-swapping copy), bgr8 -> rgb8 conversion, JPEG/PNG encode and decode,
and a CameraInfo -> CameraModel conversion.
"""
from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from eye_in_hand.core.camera import CameraModel
from eye_in_hand.ros.camera_info import camera_info_to_model, model_to_camera_info
from eye_in_hand.ros.images import (
    compressed_to_numpy,
    image_to_numpy,
    numpy_to_compressed,
    numpy_to_image,
)


def bench(fn: Callable[[], object], repeat: int = 30) -> float:
    """Median wall time of ``fn`` in milliseconds."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore
    from sensor_msgs.msg import Image

    rng = np.random.default_rng(0)
    h, w = 720, 1280
    y, x = np.mgrid[0:h, 0:w]
    bgr = np.stack([x % 256, y % 256, (x + y) % 256], -1).astype(np.uint8)
    bgr[::7, ::5] = rng.integers(0, 255, size=bgr[::7, ::5].shape, dtype=np.uint8)
    mono16 = rng.integers(0, 65535, size=(h, w), dtype=np.uint16)
    typestore = get_typestore(Stores.ROS2_JAZZY)

    msg = numpy_to_image(bgr, "bgr8")
    raw = serialize_message(msg)
    rb_msg = typestore.deserialize_cdr(raw, "sensor_msgs/msg/Image")
    padded = Image(height=h, width=w, encoding="bgr8", step=w * 3 + 64)
    padded.data = np.zeros(h * (w * 3 + 64), np.uint8).tobytes()
    big = Image(height=h, width=w, encoding="mono16", is_bigendian=1, step=w * 2)
    big.data = mono16.astype(">u2").tobytes()
    jpeg = numpy_to_compressed(bgr, "jpeg")
    png = numpy_to_compressed(bgr, "png")
    cam = CameraModel(K=np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]]),
                      dist=np.zeros(5), width=w, height=h)
    info = model_to_camera_info(cam)

    rows = [
        ("numpy_to_image bgr8 (1 copy)", lambda: numpy_to_image(bgr, "bgr8")),
        ("image_to_numpy rclpy bgr8 (view)", lambda: image_to_numpy(msg)),
        ("image_to_numpy rosbags bgr8 (view)", lambda: image_to_numpy(rb_msg)),
        ("image_to_numpy padded rows (view)", lambda: image_to_numpy(padded)),
        ("image_to_numpy big-endian mono16 (swap)", lambda: image_to_numpy(big)),
        ("image_to_numpy bgr8 -> rgb8", lambda: image_to_numpy(msg, desired_encoding="rgb8")),
        ("image_to_numpy copy=True", lambda: image_to_numpy(msg, copy=True)),
        ("rclpy serialize + deserialize (reference)",
         lambda: deserialize_message(serialize_message(msg), Image)),
        ("numpy_to_compressed jpeg q95", lambda: numpy_to_compressed(bgr, "jpeg")),
        ("compressed_to_numpy jpeg", lambda: compressed_to_numpy(jpeg)),
        ("numpy_to_compressed png level 3", lambda: numpy_to_compressed(bgr, "png")),
        ("compressed_to_numpy png", lambda: compressed_to_numpy(png)),
        ("camera_info_to_model", lambda: camera_info_to_model(info)),
    ]
    print(f"image {w}x{h} bgr8 ({bgr.nbytes / 1e6:.2f} MB); median of 30 runs")
    for name, fn in rows:
        print(f"  {name:<44s} {bench(fn):9.3f} ms")


def _wakeup_publisher(count: int = 2000, period_s: float = 0.002) -> None:
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node

    rclpy.init()
    node = Node("wakeup_source")
    pub = node.create_publisher(PoseStamped, "wakeup", 100)
    while pub.get_subscription_count() == 0:
        time.sleep(0.05)
    time.sleep(0.5)
    msg = PoseStamped()
    for _ in range(count):
        pub.publish(msg)
        time.sleep(period_s)
    time.sleep(0.5)


def _wakeup_cost(publishers: int, quiet: bool, lean: bool = False,
                 passive: bool = False) -> float:
    """CPU microseconds of this process per message received (see the module docstring)."""
    import subprocess
    import sys

    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.event_handler import PublisherEventCallbacks
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from eye_in_hand.ros.executor import LeanExecutor, set_passive, take_queued

    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("wakeup_sink", context=context)
    extra = {"event_callbacks": PublisherEventCallbacks(use_default_callbacks=False)} \
        if quiet else {}
    for k in range(publishers):
        node.create_publisher(PoseStamped, f"out{k}", 10, **extra)
    got: list[object] = []
    sub = node.create_subscription(PoseStamped, "wakeup", got.append, 100)
    if passive:    # taken at 30 Hz, as hand_eye takes robot poses with each camera frame
        set_passive(sub, True)
        node.create_timer(1 / 30, lambda: got.extend(m for m, _ in take_queued(sub)))
    ex = (LeanExecutor if lean else SingleThreadedExecutor)(context=context)
    ex.add_node(node)
    src = subprocess.Popen([sys.executable, __file__, "--wakeup-source"])
    while not got and src.poll() is None:
        ex.spin_once(timeout_sec=0.05)
    c0, n0 = time.process_time(), len(got)
    while src.poll() is None:
        ex.spin_once(timeout_sec=0.05)
    cpu, n = time.process_time() - c0, len(got) - n0
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    return cpu / max(1, n) * 1e6


def wakeups(rounds: int) -> None:
    import os
    import random

    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(120, 200)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    layouts = [(0, False, False, False), (12, False, False, False), (12, True, False, False),
               (24, False, False, False), (24, True, False, False), (0, False, True, False),
               (12, True, True, False), (12, True, True, True)]
    runs: dict[tuple[int, bool, bool, bool], list[float]] = {k: [] for k in layouts}
    for _ in range(rounds):
        for key in layouts:
            runs[key].append(_wakeup_cost(*key))
    floor = statistics.median(runs[(0, False, False, False)])
    print(f"executor CPU per received message, median of {rounds} rounds "
          f"(floor: rclpy's executor, no publisher, {floor:.0f} us)")
    for (n, quiet, lean, passive), values in runs.items():
        med = statistics.median(values)
        kind = "without QoS-event handlers" if quiet else "default handlers"
        name = "LeanExecutor" if lean else "rclpy's executor"
        if passive:
            name, kind = "LeanExecutor", "passive, taken at 30 Hz"
        print(f"  {name:<17s} {n:2d} publishers, {kind:<27s} {med:7.0f} us  "
              f"({med / floor:.2f}x the floor)")


def event_poll(rounds: int) -> None:
    import os
    import random
    import subprocess
    import sys

    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node

    from eye_in_hand.ros import executor as lean_executor

    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(120, 200)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    default = lean_executor.EVENT_POLL_S
    print(f"LeanExecutor CPU per received message at 30 Hz, QoS events every {default:g} s "
          "against in every wait (alternating every 50 messages)")
    got = [0]

    def count(_raw: object) -> None:
        got[0] += 1

    for r in range(rounds):
        got[0] = 0
        context = rclpy.Context()
        rclpy.init(context=context)
        node = Node("event_poll_sink", context=context)
        node.create_subscription(PoseStamped, "wakeup", count, 100, raw=True)
        for k in range(6):
            node.create_subscription(PoseStamped, f"quiet{k}", count, 100, raw=True)
        for k in range(5):
            node.create_timer(1.0 + 0.1 * k, lambda: None)
        ex = lean_executor.LeanExecutor(context=context)
        ex.add_node(node)
        src = subprocess.Popen([sys.executable, __file__, "--wakeup-source", "--count", "1500",
                                "--period", str(1 / 30)])
        cpu = {default: [0, 0], 0.0: [0, 0]}
        try:
            while got[0] < 30 and src.poll() is None:
                ex.spin_once(timeout_sec=0.5)
            while src.poll() is None:
                mode = default if (got[0] // 50) % 2 else 0.0
                lean_executor.EVENT_POLL_S = mode
                n0, t0 = got[0], time.thread_time_ns()
                ex.spin_once(timeout_sec=0.5)
                cpu[mode][0] += time.thread_time_ns() - t0
                cpu[mode][1] += got[0] - n0
        finally:
            lean_executor.EVENT_POLL_S = default
            ex.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=context)
        polled, every = (cpu[m][0] / max(1, cpu[m][1]) / 1e3 for m in (default, 0.0))
        print(f"  round {r + 1}: events every {default:g} s {polled:6.1f} us, in every wait "
              f"{every:6.1f} us per message ({cpu[default][1]} and {cpu[0.0][1]} messages)")


def _publish_sink(topics: int, seconds: float) -> None:
    """A subscriber of ``topics`` result topics in another process (``--publish-sink``)."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node

    from eye_in_hand.ros.qos import RESULT_QOS

    rclpy.init()
    node = Node("publish_sink")
    for k in range(topics):
        node.create_subscription(PoseStamped, f"burst{k}", lambda _raw: None, RESULT_QOS,
                                 raw=True)
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass          # terminated by the measuring process: done


def publish_after_idle(pairs: int = 600, topics: int = 7) -> None:
    """CPU of ``Publisher.publish`` (serialized bytes, ``RESULT_QOS``) in this process's
    thread: bursts of ``topics`` publications at 30 Hz, one per topic as ``hand_eye`` sends
    its outputs for a stereo pair, each topic subscribed by another process; then the same
    bursts back to back; then one publication at 30 Hz on a topic nobody subscribes to."""
    import os
    import random
    import subprocess
    import sys

    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node
    from rclpy.serialization import serialize_message

    from eye_in_hand.ros.qos import RESULT_QOS

    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(120, 200)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    sink = subprocess.Popen([sys.executable, __file__, "--publish-sink", "--count",
                             str(topics), "--period", str(2 * pairs / 30 + 20)])
    rclpy.init()
    node = Node("publish_source")
    pubs = [node.create_publisher(PoseStamped, f"burst{k}", RESULT_QOS) for k in range(topics)]
    lone = node.create_publisher(PoseStamped, "burst_nobody", RESULT_QOS)
    raw = serialize_message(PoseStamped())
    try:
        deadline = time.monotonic() + 30
        while any(p.get_subscription_count() == 0 for p in pubs):
            if time.monotonic() > deadline:
                raise SystemExit("the subscriber process did not match")
            time.sleep(0.05)
        time.sleep(1.0)
        print(f"Publisher.publish CPU (this thread, {len(raw)}-byte PoseStamped, RESULT_QOS), "
              f"{pairs} bursts of {topics}, each topic subscribed by another process:")
        for label, period in (("at 30 Hz (33 ms idle before each burst)", 1 / 30),
                              ("back to back", 0.0)):
            per = [0] * topics
            for _ in range(pairs):
                if period:
                    time.sleep(period)
                for k, pub in enumerate(pubs):
                    t0 = time.thread_time_ns()
                    pub.publish(raw)
                    per[k] += time.thread_time_ns() - t0
            each = ", ".join(f"{v / pairs / 1e3:.0f}" for v in per)
            print(f"  {label:<40s} burst {sum(per) / pairs / 1e3:6.0f} us (each: {each})")
        total = 0
        for _ in range(pairs // 2):
            time.sleep(1 / 30)
            t0 = time.thread_time_ns()
            lone.publish(raw)
            total += time.thread_time_ns() - t0
        lone_us = total / (pairs // 2) / 1e3
        print(f"  {'one on a topic nobody subscribes to, 30 Hz':<46s} {lone_us:6.0f} us")
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        sink.terminate()
        sink.wait(timeout=10)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--wakeups", action="store_true", help="the executor part only")
    parser.add_argument("--rounds", type=int, default=3, help="--wakeups rounds (default 3)")
    parser.add_argument("--event-poll", action="store_true",
                        help="QoS events polled against waited on every time (30 Hz)")
    parser.add_argument("--publish-after-idle", action="store_true",
                        help="publish's CPU in bursts at 30 Hz against back to back")
    parser.add_argument("--wakeup-source", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--publish-sink", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--count", type=int, default=2000, help=argparse.SUPPRESS)
    parser.add_argument("--period", type=float, default=0.002, help=argparse.SUPPRESS)
    opts = parser.parse_args()
    if opts.wakeup_source:
        _wakeup_publisher(opts.count, opts.period)
    elif opts.publish_sink:
        _publish_sink(opts.count, opts.period)
    elif opts.publish_after_idle:
        publish_after_idle()
    elif opts.event_poll:
        event_poll(opts.rounds)
    elif opts.wakeups:
        wakeups(opts.rounds)
    else:
        main()
