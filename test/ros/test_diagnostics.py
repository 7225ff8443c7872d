"""Tests of eye_in_hand.ros.diagnostics: levels, values, publication over DDS, log once."""
from __future__ import annotations

import pytest

from eye_in_hand.errors import ConfigError
from eye_in_hand.ros.diagnostics import ERROR, OK, STALE, WARN, NodeDiagnostics, OncePerCause


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class FakeLogger:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def warning(self, text: str) -> None:
        self.lines.append(("warn", text))

    def error(self, text: str) -> None:
        self.lines.append(("error", text))


def values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


@pytest.fixture
def node(ros_context, namespace):
    from rclpy.node import Node

    n = Node("diag_test", context=ros_context, namespace=namespace)
    yield n
    n.destroy_node()


def test_once_per_cause_logs_first_occurrence_only():
    log = FakeLogger()
    once = OncePerCause(log)
    assert once.report("bad_encoding", "left/image_raw: encoding 'yuv' unsupported")
    assert not once.report("bad_encoding", "left/image_raw: again")
    assert once.report("stale_pose", "no pose at 12 ns", level=ERROR)
    assert not once.report("stale_pose", "no pose at 13 ns", level=ERROR)
    assert once.counts == {"bad_encoding": 2, "stale_pose": 2}
    assert [lvl for lvl, _ in log.lines] == ["warn", "error"]
    assert log.lines[0][1].startswith("left/image_raw: encoding 'yuv' unsupported")
    assert "further 'bad_encoding' occurrences are counted" in log.lines[0][1]
    with pytest.raises(ValueError, match="level"):
        once.report("x", "y", level=7)


def test_counters_rates_gauges_and_rules(node):
    clock = FakeClock()
    diag = NodeDiagnostics(node, period_s=0, clock=clock, hardware_id="rig-7")
    diag.expect_rate("frames", 5.0)
    diag.warn_above("latency_ms", 50.0)
    diag.warn_below("inliers", 10, level=ERROR)
    diag.stale_after("pose", 2.0, level=STALE)
    # First period: 10 frames in 1 s, fresh pose, low latency -> OK.
    for _ in range(10):
        diag.count("frames")
    diag.gauge("latency_ms", 3.25)
    diag.gauge("pose", "ok")
    clock.t += 1.0
    msg = diag.publish()
    status = msg.status[0]
    assert status.level == bytes([OK]) and status.message == "OK"
    assert status.name == "diag_test" and status.hardware_id == "rig-7"
    v = values(status)
    assert v["frames"] == "10" and v["frames rate (Hz)"] == "10.000"
    assert v["latency_ms"] == "3.25" and v["pose"] == "ok"
    # Second period: 2 frames in 1 s, high latency -> WARN with both reasons.
    diag.count("frames", 2)
    diag.gauge("latency_ms", 80.0)
    clock.t += 1.0
    status = diag.publish().status[0]
    assert status.level == bytes([WARN])
    assert "frames at 2.00 Hz < 5 Hz" in status.message
    assert "latency_ms = 80 > 50" in status.message
    assert values(status)["frames"] == "12"
    # Third: pose stale for 3 s -> STALE; few inliers -> ERROR; the highest wins, listed first.
    diag.count("frames", 10)
    diag.gauge("latency_ms", 1.0)
    diag.gauge("inliers", 4)
    clock.t += 1.5
    status = diag.publish().status[0]
    assert status.level == bytes([STALE])
    assert status.message.startswith("no pose for 3.5 s; inliers = 4 < 10")
    assert diag.counter("frames") == 22 and diag.counter("never") == 0


def test_expect_rate_declares_counter_and_warns_before_first_event(node):
    clock = FakeClock()
    diag = NodeDiagnostics(node, period_s=0, clock=clock)
    diag.expect_rate("frames", 1.0)
    clock.t += 1.0
    status = diag.publish().status[0]
    assert status.level == bytes([WARN]) and values(status)["frames"] == "0"


def test_reported_problems_raise_level_for_one_period(node):
    clock = FakeClock()
    diag = NodeDiagnostics(node, period_s=0, clock=clock)
    assert diag.report("bad_data_length", "left/image_raw: data: length 11 != 12")
    assert not diag.report("bad_data_length", "left/image_raw: data: length 10 != 12")
    assert diag.report("no_camera_info", "right/camera_info missing", level=ERROR)
    clock.t += 1.0
    status = diag.publish().status[0]
    assert status.level == bytes([ERROR])
    assert status.message == ("no_camera_info: right/camera_info missing; "
                              "bad_data_length: left/image_raw: data: length 10 != 12")
    v = values(status)
    assert v["problem: bad_data_length"] == "2" and v["problem: no_camera_info"] == "1"
    # No new problems: back to OK, while the totals stay visible.
    clock.t += 1.0
    status = diag.publish().status[0]
    assert status.level == bytes([OK])
    assert values(status)["problem: bad_data_length"] == "2"
    assert diag.causes == {"bad_data_length": 2, "no_camera_info": 1}


def test_bad_rule_level_and_period(node):
    with pytest.raises(ConfigError, match="period_s"):
        NodeDiagnostics(node, period_s=-1.0)
    diag = NodeDiagnostics(node, period_s=0)
    diag.add_rule(lambda s: (9, "nonsense"))
    with pytest.raises(ValueError, match="level"):
        diag.publish()


def test_published_on_relative_topic_by_timer(ros_context, executor, namespace, spin_until):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node

    from eye_in_hand.ros.qos import RESULT_QOS

    worker = Node("worker", context=ros_context, namespace=namespace)
    listener = Node("listener", context=ros_context, namespace=namespace)
    executor.add_node(worker)
    executor.add_node(listener)
    got: list[DiagnosticArray] = []
    listener.create_subscription(DiagnosticArray, "diagnostics", got.append, RESULT_QOS)
    diag = NodeDiagnostics(worker, period_s=0.05)
    for _ in range(3):
        diag.count("frames")
    # Wait for the first publication to arrive (discovery done), then report a problem.
    assert spin_until(executor, lambda: len(got) >= 1, 10.0)
    assert got[0].status[0].name == "worker" and values(got[0].status[0])["frames"] == "3"
    diag.report("bad_frame", "left/image_raw: step too short")
    seen = len(got)

    def warned() -> int | None:
        return next((i for i in range(seen, len(got))
                     if got[i].status[0].level == bytes([WARN])), None)

    assert spin_until(executor, lambda: warned() is not None, 10.0)
    i = warned()
    assert "bad_frame: left/image_raw: step too short" in got[i].status[0].message
    # The next period has no new problem: OK again.
    assert spin_until(executor, lambda: len(got) > i + 1, 10.0)
    assert got[i + 1].status[0].level == bytes([OK])
    assert values(got[i + 1].status[0])["problem: bad_frame"] == "1"
    assert diag.published >= 3
    diag.destroy()
    with pytest.raises(RuntimeError, match="after destroy"):
        diag.publish()


def test_published_while_simulated_time_stands_still(ros_context, executor, namespace,
                                                     spin_until):
    """Under use_sim_time with no /clock, ROS time is frozen; diagnostics keep coming."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from eye_in_hand.ros.qos import RESULT_QOS

    worker = Node("sim_worker", context=ros_context, namespace=namespace,
                  parameter_overrides=[Parameter("use_sim_time", value=True)])
    assert worker.get_clock().now().nanoseconds == 0
    executor.add_node(worker)
    got: list[DiagnosticArray] = []
    worker.create_subscription(DiagnosticArray, "diagnostics", got.append, RESULT_QOS)
    diag = NodeDiagnostics(worker, period_s=0.05)
    diag.expect_rate("frames", 1.0)
    assert spin_until(executor, lambda: len(got) >= 2, 10.0)
    assert got[-1].status[0].level == bytes([WARN])
    assert "frames at 0.00 Hz" in got[-1].status[0].message
