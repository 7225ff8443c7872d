"""LeanExecutor: rclpy's single-threaded semantics for what the nodes use, a cheaper wake-up."""
from __future__ import annotations

import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from eye_in_hand.ros.executor import (  # noqa: E402
    DueTimers,
    LeanExecutor,
    is_passive,
    run_due_timers,
    set_passive,
    take_queued,
)
from eye_in_hand.ros.spin import spin_until  # noqa: E402

QOS = 50


@pytest.fixture
def lean(ros_context):
    ex = LeanExecutor(context=ros_context)
    nodes: list[Node] = []

    def make(name: str, namespace: str) -> Node:
        node = Node(name, namespace=namespace, context=ros_context)
        nodes.append(node)
        ex.add_node(node)
        return node

    try:
        yield ex, make
    finally:
        for node in nodes:
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


def _matched(ex, pub, timeout_s: float = 10.0) -> bool:
    return spin_until(ex, lambda: pub.get_subscription_count() > 0, timeout_s)


def test_a_subscription_gets_every_message_in_order_and_queued_ones_in_one_spin(
        lean, namespace):
    ex, make = lean
    node = make("sink", namespace)
    got: list[int] = []
    node.create_subscription(Int32, "numbers", lambda m: got.append(m.data), QOS)
    pub = node.create_publisher(Int32, "numbers", QOS)
    assert _matched(ex, pub)
    for k in range(5):
        pub.publish(Int32(data=k))
    # the five messages are queued before the wait: one wake-up takes them all
    assert spin_until(ex, lambda: len(got) > 0, 10.0)
    assert spin_until(ex, lambda: len(got) == 5, 10.0)
    assert got == [0, 1, 2, 3, 4]
    time.sleep(0.2)
    for k in range(5, 9):
        pub.publish(Int32(data=k))
    time.sleep(0.3)                       # delivered to the subscription's queue meanwhile
    ex.spin_once(timeout_sec=2.0)
    assert got == list(range(9)), "a ready subscription is drained in one wake-up"


def test_a_passive_subscription_keeps_its_messages_without_waking_the_executor(
        lean, namespace, monkeypatch):
    """Marked passive, a subscription's messages wait in the middleware: the executor's waits
    run their full timeout (neither the subscription nor its QoS events end them, the events
    here in every wait) and the callback gets nothing; take_queued gives them in order with
    their reception times; made active again, it is waited on as before."""
    from eye_in_hand.ros import executor as lean_executor

    monkeypatch.setattr(lean_executor, "EVENT_POLL_S", 0.0)
    ex, make = lean
    node = make("passive", namespace)
    got: list[int] = []
    sub = node.create_subscription(Int32, "quiet", lambda m: got.append(m.data), QOS)
    pub = node.create_publisher(Int32, "quiet", QOS)
    assert _matched(ex, pub)
    set_passive(sub, True)
    assert is_passive(sub)
    before = time.time_ns()
    for k in range(5):
        pub.publish(Int32(data=k))
    time.sleep(0.2)                       # in the subscription's queue by now
    wakeups, end = 0, time.monotonic() + 0.5
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.1)
        wakeups += 1
    assert got == []
    assert wakeups <= 8, f"{wakeups} wake-ups in 0.5 s with a 0.1 s timeout: the waits ended early"
    taken = take_queued(sub)
    assert [m.data for m, _ in taken] == [0, 1, 2, 3, 4]
    stamps = [t for _, t in taken]
    assert stamps == sorted(stamps) and before <= stamps[0] and stamps[-1] <= time.time_ns()
    assert take_queued(sub) == []
    set_passive(sub, False)
    pub.publish(Int32(data=9))
    assert spin_until(ex, lambda: got == [9], 10.0)


def test_a_subscription_made_while_spinning_is_waited_on(lean, namespace):
    ex, make = lean
    node = make("late", namespace)
    pub = node.create_publisher(Int32, "late_topic", QOS)
    ex.spin_once(timeout_sec=0.05)        # entities built without the subscription
    got: list[int] = []
    node.create_subscription(Int32, "late_topic", lambda m: got.append(m.data), QOS)
    assert _matched(ex, pub)
    pub.publish(Int32(data=7))
    assert spin_until(ex, lambda: got == [7], 10.0)


def test_a_subscription_made_during_a_rebuild_is_waited_on(lean, namespace, monkeypatch,
                                                           ros_context):
    """A subscription made on another thread after a rebuild read the entity lists (and before
    it ended) is not lost: the rebuild is used for one wait, then done again."""
    import eye_in_hand.ros.executor as executor_module

    ex, make = lean
    node = make("race", namespace)
    got: list[int] = []
    made: list[object] = []

    class RacedEntities(executor_module._Entities):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            if not made:     # the lists are read: now the other thread makes its subscription
                made.append(node.create_subscription(Int32, "late", lambda m: got.append(m.data),
                                                     QOS))

    # the publisher's node is not on the executor: making it wakes nothing
    other = Node("race_pub", namespace=namespace, context=ros_context)
    try:
        pub = other.create_publisher(Int32, "late", QOS)
        monkeypatch.setattr(executor_module, "_Entities", RacedEntities)
        ex.spin_once(timeout_sec=0.1)
        assert made
        assert _matched(ex, pub)
        pub.publish(Int32(data=7))
        assert spin_until(ex, lambda: got == [7], 5.0)
    finally:
        other.destroy_node()


def test_a_destroyed_subscription_gets_nothing_more(lean, namespace):
    ex, make = lean
    node = make("gone", namespace)
    got: list[int] = []
    sub = node.create_subscription(Int32, "gone_topic", lambda m: got.append(m.data), QOS)
    pub = node.create_publisher(Int32, "gone_topic", QOS)
    assert _matched(ex, pub)
    pub.publish(Int32(data=1))
    assert spin_until(ex, lambda: got == [1], 10.0)
    node.destroy_subscription(sub)
    pub.publish(Int32(data=2))
    for _ in range(10):
        ex.spin_once(timeout_sec=0.02)
    assert got == [1]


def test_timers_fire_and_a_cancelled_timer_does_not(lean, namespace):
    ex, make = lean
    node = make("timers", namespace)
    ticks = {"a": 0, "b": 0}
    node.create_timer(0.01, lambda: ticks.__setitem__("a", ticks["a"] + 1))
    b = node.create_timer(0.01, lambda: ticks.__setitem__("b", ticks["b"] + 1))
    b.cancel()
    assert spin_until(ex, lambda: ticks["a"] >= 5, 5.0)
    assert ticks["b"] == 0
    b.reset()
    assert spin_until(ex, lambda: ticks["b"] >= 2, 5.0)


def test_a_timer_run_early_is_put_back_and_others_wait_for_their_time(lean, namespace):
    """``run_due_timers``: a timer due within the window runs now and is put back by a period
    (the executor does not run it again at its old time); one due later, a canceled one and
    None are left alone."""
    ex, make = lean
    node = make("due", namespace)
    ran = {"soon": [], "later": 0, "canceled": 0}
    soon = node.create_timer(0.4, lambda: ran["soon"].append(time.monotonic()))
    later = node.create_timer(30.0, lambda: ran.__setitem__("later", ran["later"] + 1))
    canceled = node.create_timer(0.4, lambda: ran.__setitem__("canceled", 1))
    canceled.cancel()
    spin_until(ex, lambda: False, 0.1)
    assert ran["soon"] == []
    t0 = time.monotonic()
    assert run_due_timers([soon, later, canceled, None], 400_000_000) == 1
    assert len(ran["soon"]) == 1 and ran["later"] == 0 and ran["canceled"] == 0
    assert soon.time_until_next_call() > 300_000_000         # a period from now
    spin_until(ex, lambda: False, 0.3)        # its old time (0.4 s after creation) passes
    assert len(ran["soon"]) == 1, ran["soon"]
    assert spin_until(ex, lambda: len(ran["soon"]) == 2, 5.0)
    assert ran["soon"][1] - t0 >= 0.35
    assert run_due_timers([soon], 0) == 0     # not due yet: nothing runs


def test_due_timers_look_once_a_period_and_run_what_falls_due_before_the_next(lean,
                                                                             namespace):
    """``DueTimers.poke``: nothing before its first look is due; then a timer due before the
    next look runs (and is put back), one due later does not, and the next look waits."""
    ex, make = lean
    node = make("due_timers", namespace)
    ran: list[str] = []
    soon = node.create_timer(0.3, lambda: ran.append("soon"))
    later = node.create_timer(30.0, lambda: ran.append("later"))
    due = DueTimers((soon, later, None), 0.2)
    assert due.poke() == 0 and ran == []            # the first look is 0.2 s away
    time.sleep(0.15)
    assert due.poke() == 0 and ran == []
    time.sleep(0.1)                                  # 0.25 s: soon is due in 0.05 s
    assert due.poke() == 1 and ran == ["soon"]
    assert due.poke() == 0                           # the next look is 0.2 s away
    assert soon.time_until_next_call() > 200_000_000


def _call(ros_context, namespace: str, name: str) -> Trigger.Response:
    """Call ``name`` from another node on rclpy's own executor, in another thread."""
    client_node = Node("caller", namespace=namespace, context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(client_node)
    try:
        cli = client_node.create_client(Trigger, name)
        assert cli.wait_for_service(timeout_sec=10.0)
        future = cli.call_async(Trigger.Request())
        ex.spin_until_future_complete(future, timeout_sec=10.0)
        assert future.done()
        return future.result()
    finally:
        ex.remove_node(client_node)
        client_node.destroy_node()
        ex.shutdown()


def _serve_in_thread(ex):
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            ex.spin_once(timeout_sec=0.02)

    t = threading.Thread(target=loop, daemon=True)
    t.start()
    return stop, t


def test_a_plain_service_answers(lean, namespace, ros_context):
    ex, make = lean
    node = make("server", namespace)

    def answer(request, response):
        response.success, response.message = True, "plain"
        return response

    node.create_service(Trigger, "plain", answer)
    stop, t = _serve_in_thread(ex)
    try:
        res = _call(ros_context, namespace, f"{namespace}/plain")
    finally:
        stop.set()
        t.join(5.0)
    assert res.success and res.message == "plain"


def test_an_async_service_answers_after_its_await(lean, namespace, ros_context):
    ex, make = lean
    node = make("async_server", namespace)
    from rclpy.task import Future

    pending: list[Future] = []

    async def answer(request, response):
        f = Future(executor=ex)
        pending.append(f)
        threading.Timer(0.1, lambda: f.set_result("later")).start()
        response.message = await f
        response.success = True
        return response

    node.create_service(Trigger, "slow", answer)
    stop, t = _serve_in_thread(ex)
    try:
        res = _call(ros_context, namespace, f"{namespace}/slow")
    finally:
        stop.set()
        t.join(5.0)
    assert res.success and res.message == "later"
    assert pending and pending[0].done()


def test_a_guard_condition_triggered_from_another_thread_runs_its_callback(lean, namespace):
    ex, make = lean
    node = make("guarded", namespace)
    hits: list[str] = []
    gc = node.create_guard_condition(lambda: hits.append(threading.current_thread().name))
    threading.Timer(0.05, gc.trigger).start()
    assert spin_until(ex, lambda: len(hits) == 1, 5.0)
    assert hits == [threading.current_thread().name], "callbacks run on the spinning thread"


def test_shutdown_from_another_thread_ends_spin(ros_context, namespace):
    ex = LeanExecutor(context=ros_context)
    node = Node("spinner", namespace=namespace, context=ros_context)
    ex.add_node(node)
    t = threading.Thread(target=ex.spin, daemon=True)
    t.start()
    time.sleep(0.1)
    assert ex.shutdown(timeout_sec=5.0)
    t.join(5.0)
    assert not t.is_alive()
    node.destroy_node()


def test_a_callback_exception_propagates(lean, namespace):
    ex, make = lean
    node = make("raiser", namespace)

    def boom() -> None:
        raise RuntimeError("callback failed")

    node.create_timer(0.01, boom)
    with pytest.raises(RuntimeError, match="callback failed"):
        spin_until(ex, lambda: False, 5.0)


def test_external_shutdown_is_reported(namespace):
    context = rclpy.Context()
    rclpy.init(context=context)
    ex = LeanExecutor(context=context)
    node = Node("external", namespace=namespace, context=context)
    ex.add_node(node)
    threading.Timer(0.1, lambda: rclpy.shutdown(context=context)).start()
    try:
        with pytest.raises(ExternalShutdownException):
            for _ in range(500):
                ex.spin_once(timeout_sec=0.02)
    finally:
        ex.remove_node(node)
        node.destroy_node()
        ex.shutdown()
        rclpy.try_shutdown(context=context)


def test_an_async_subscription_callback_runs(lean, namespace):
    ex, make = lean
    node = make("async_sink", namespace)
    got: list[int] = []

    async def take(msg) -> None:
        got.append(msg.data)

    node.create_subscription(Int32, "async_numbers", take, QOS)
    pub = node.create_publisher(Int32, "async_numbers", QOS)
    assert _matched(ex, pub)
    pub.publish(Int32(data=3))
    assert spin_until(ex, lambda: got == [3], 10.0)


def test_queued_messages_of_several_topics_come_in_arrival_order(lean, namespace):
    ex, make = lean
    node = make("pairs", namespace)
    got: list[tuple[str, int]] = []
    node.create_subscription(Int32, "left", lambda m: got.append(("left", m.data)), QOS)
    node.create_subscription(Int32, "right", lambda m: got.append(("right", m.data)), QOS)
    left = node.create_publisher(Int32, "left", QOS)
    right = node.create_publisher(Int32, "right", QOS)
    assert _matched(ex, left) and _matched(ex, right)
    sent = []
    for k in range(4):
        for side, pub in (("left", left), ("right", right)):
            pub.publish(Int32(data=k))
            sent.append((side, k))
            time.sleep(0.01)
    time.sleep(0.3)                       # all eight queued before the executor looks
    ex.spin_once(timeout_sec=2.0)
    assert got == sent, "the pairs interleave as they arrived, not left x4 then right x4"


def test_a_burst_of_one_topic_is_delivered_round_by_round(lean, namespace):
    """Six lefts that arrived before their six rights (a reliable writer's resend after
    discovery brings them so) reach the callbacks as pairs: a stereo sync with a queue of five
    per side loses none of them."""
    from eye_in_hand.core.sync import ApproximateStereoSync

    ex, make = lean
    node = make("burst", namespace)
    got: list[tuple[str, int]] = []
    sync: ApproximateStereoSync[int] = ApproximateStereoSync(0, queue_size=5)
    pairs: list[int] = []

    def on(side: str):
        def callback(m: Int32) -> None:
            got.append((side, m.data))
            push = sync.push_left if side == "left" else sync.push_right
            pairs.extend(p.left_stamp_ns for p in push(m.data, m.data))
        return callback

    node.create_subscription(Int32, "left", on("left"), QOS)
    node.create_subscription(Int32, "right", on("right"), QOS)
    left = node.create_publisher(Int32, "left", QOS)
    right = node.create_publisher(Int32, "right", QOS)
    assert _matched(ex, left) and _matched(ex, right)
    for pub in (left, right):
        for k in range(6):
            pub.publish(Int32(data=k))
            time.sleep(0.01)
    time.sleep(0.3)                       # all twelve queued before the executor looks
    ex.spin_once(timeout_sec=2.0)
    assert got == [(side, k) for k in range(6) for side in ("left", "right")]
    assert pairs == list(range(6)) and sync.stats.dropped == 0


def _strict_subscription(node: Node, seen: list[object]) -> None:
    """A reliable subscription on ``strict`` whose incompatible-QoS events go to ``seen``."""
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    node.create_subscription(
        Int32, "strict", lambda m: None,
        QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE),
        event_callbacks=SubscriptionEventCallbacks(incompatible_qos=seen.append))


def _best_effort_publisher(node: Node) -> None:
    """A best-effort publisher on ``strict``: incompatible with :func:`_strict_subscription`."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    node.create_publisher(Int32, "strict",
                          QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))


def test_a_qos_event_reaches_its_callback(lean, namespace):
    ex, make = lean
    node = make("events", namespace)
    seen: list[object] = []
    _strict_subscription(node, seen)
    _best_effort_publisher(node)
    assert spin_until(ex, lambda: len(seen) > 0, 10.0), "incompatible QoS not reported"


def test_a_wait_without_the_qos_events_ends_when_they_are_due(lean, namespace):
    """QoS events are in a wait once per ``EVENT_POLL_S``: a wait that leaves them out ends by
    then even when nothing else comes and no timeout was given, so that the next one takes
    them in (else an incompatible publisher would go unreported while the node is idle)."""
    ex, make = lean
    node = make("events_later", namespace)
    seen: list[object] = []
    _strict_subscription(node, seen)
    ex.spin_once(timeout_sec=0.0)         # this wait takes the events in: the next ones do not
    ex.spin_once(timeout_sec=0.0)
    assert ex._events_due > time.monotonic()
    returned = threading.Event()

    def spin() -> None:
        ex.spin_once()                    # no timeout, nothing to wake it but the events' due
        returned.set()

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    try:
        assert returned.wait(10.0), "a wait without the QoS events did not end when they " \
            "were due"
        _best_effort_publisher(node)
        assert spin_until(ex, lambda: len(seen) > 0, 10.0), "incompatible QoS not reported"
    finally:
        ex.wake()
        spinner.join(5.0)
