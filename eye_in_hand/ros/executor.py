"""A lean single-threaded executor: the same callbacks as rclpy's, a fraction of the cost.

rclpy's :class:`~rclpy.executors.SingleThreadedExecutor` rebuilds its whole wait set from
every node's entities at each wake-up and runs each ready callback as a ``Task`` around a
coroutine, one per ``spin_once``. On this machine a bare wake-up costs about 0.5 ms of CPU in
Python, and a ``hand_eye`` node that takes four robot poses and four camera-frame messages per
stereo pair pays it eight times per pair (``benchmarks/bench_ros_glue.py --wakeups``).

:class:`LeanExecutor` keeps rclpy's semantics for what the package's nodes use and does less
per wake-up:

- the entity lists (subscriptions, timers, services, guard conditions, waitables) and their
  handle-to-entity maps are rebuilt only when an entity or a node is added or removed (rclpy
  calls :meth:`wake` then);
- one wait set object is kept and refilled in C;
- a subscription marked passive (:func:`set_passive`) is left out of the waits: its owner
  takes its messages when it needs them (:func:`take_queued`), so a 125 Hz - 1 kHz robot
  pose stream does not wake the node for every pose;
- the QoS events of the subscriptions (an incompatible QoS or type: what a warning
  reports, never data; two handlers per subscription, fourteen in a ``hand_eye``) are in a
  wait at most once per :data:`EVENT_POLL_S`, and a wait without them ends by then: an event
  is reported up to half a second later, and each wake-up adds and checks 14 fewer entities
  (20-30 us of a bare wake-up's 210-380 us of CPU here,
  ``benchmarks/bench_ros_glue.py --event-poll``);
- each ready entity's callback is called directly, and the ready subscriptions are drained
  of every message they hold, so messages that queued together cost one wake-up. Messages of
  several topics are delivered round by round, as rclpy's one message per subscription per
  wake-up would: first the oldest message of every topic, then the second of every topic,
  and so on, in the order they arrived within a round. A burst of one topic (six left images
  that arrived before their six rights, as a reliable writer's resend after discovery brings
  them) thus still reaches a stereo sync as pairs, not as six lefts that overflow its queue.

The handles of the entities are held (``with handle``) from one rebuild to the next, so an
entity destroyed while the executor waits on it is destroyed at the next rebuild, which its
removal triggers (rclpy holds them for one wait). A callback that returns a coroutine (an
``async def`` service or subscription callback), a waitable (its ``execute`` is a coroutine),
a service client's response and every task made with :meth:`create_task` run on rclpy's own
task machinery: while any task is outstanding, ``spin_once`` is rclpy's. Callbacks run on the
spinning thread one at a time, whatever their callback group (a single-threaded executor).
An exception raised by a callback propagates out of ``spin_once``, as with rclpy's.
"""
from __future__ import annotations

import inspect
import threading
import time
from collections.abc import Iterable
from contextlib import ExitStack
from typing import Any

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

__all__ = ["LeanExecutor", "set_passive", "is_passive", "take_queued", "run_due_timers",
           "DueTimers",
           "reception_times_known", "RECEPTION_STAMPING_RMWS"]

#: QoS events (by default an incompatible QoS or type: what a warning reports, never the
#: data; any other handlers a subscription was given too) are in a wait at most once in this
#: many seconds (module docstring)
EVENT_POLL_S = 0.5

#: the attribute that marks a subscription passive (:func:`set_passive`)
_PASSIVE = "_eye_in_hand_passive"


def set_passive(subscription: Any, passive: bool) -> None:
    """Leave ``subscription`` out of :class:`LeanExecutor`'s waits (``passive``), or put it
    back. A passive subscription's messages stay queued in the middleware, up to its QoS
    depth, until its owner takes them with :func:`take_queued` when it needs them: the
    executor does not wake for each one. Other executors ignore the mark and call the
    callback for every message, as for any subscription. Takes effect at the next wait."""
    setattr(subscription, _PASSIVE, bool(passive))


def is_passive(subscription: Any) -> bool:
    """Whether ``subscription`` is marked passive (:func:`set_passive`)."""
    return bool(getattr(subscription, _PASSIVE, False))


#: Middlewares whose ``received_timestamp`` is the system time at which the sample arrived
#: (checked for Fast DDS, the package's; rmw_cyclonedds stamps at the take or not at all)
RECEPTION_STAMPING_RMWS = ("rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")


def reception_times_known() -> bool:
    """Whether this process's middleware stamps messages at reception
    (:data:`RECEPTION_STAMPING_RMWS`): only then can a passive subscription's messages be
    taken later with the time they arrived."""
    from rclpy.utilities import get_rmw_implementation_identifier

    return get_rmw_implementation_identifier() in RECEPTION_STAMPING_RMWS


def take_queued(subscription: Any) -> list[tuple[Any, int]]:
    """Every message queued on ``subscription``, oldest first, each with its reception time:
    the middleware's ``received_timestamp`` (int ns, system clock)."""
    handle, msg_type, raw = subscription.handle, subscription.msg_type, subscription.raw
    out: list[tuple[Any, int]] = []
    with handle:
        while (one := handle.take_message(msg_type, raw)) is not None:
            out.append((one[0], int(one[1]["received_timestamp"])))
    return out


def run_due_timers(timers: Iterable[Any], within_ns: int) -> int:
    """Run now the callback of each timer that would fire within ``within_ns``, after putting
    it back by a period (``Timer.reset``): a node awake anyway (a camera frame's messages)
    does the periodic work of the next moments then, instead of waking for it (a wake-up
    after idle costs hundreds of microseconds of CPU on a small machine, docs/ros.md). None
    and canceled timers are skipped; any executor. Returns how many ran."""
    ran = 0
    for timer in timers:
        if timer is None:
            continue
        left = timer.time_until_next_call()     # None: canceled
        if left is not None and left <= within_ns:
            timer.reset()
            timer.callback()
            ran += 1
    return ran


class DueTimers:
    """Timers whose work a node awake anyway runs early: :meth:`poke`, called with the
    messages that wake it, looks at most every ``look_s`` seconds (monotonic) and runs each
    timer due before the next look (:func:`run_due_timers`)."""

    __slots__ = ("timers", "_look_s", "_due")

    def __init__(self, timers: Iterable[Any], look_s: float) -> None:
        self.timers = tuple(timers)
        self._look_s = float(look_s)
        self._due = time.monotonic() + self._look_s

    def poke(self) -> int:
        """Look, when a look is due: how many timers ran."""
        now = time.monotonic()
        if now < self._due:
            return 0
        self._due = now + self._look_s
        return run_due_timers(self.timers, int(self._look_s * 1e9))


class _Entities:
    """The entities of the executor's nodes at one moment, and the handle maps of the ready
    lists (``pointer -> entity``)."""

    __slots__ = ("subs", "timers", "services", "clients", "guards", "own_guards", "waitables",
                 "events", "sub_by_ptr", "timer_by_ptr", "service_by_ptr", "guard_by_ptr",
                 "counts")

    def __init__(self, nodes: list[Any], own_guards: list[Any]) -> None:
        self.subs = [s for n in nodes for s in n.subscriptions]
        self.timers = [t for n in nodes for t in n.timers]
        self.services = [s for n in nodes for s in n.services]
        self.clients = [c for n in nodes for c in n.clients]
        self.guards = [g for n in nodes for g in n.guards]
        self.own_guards = own_guards
        waitables = [w for n in nodes for w in n.waitables]
        #: QoS event handlers (one or two per subscription by default) with their event
        #: handle, added to the wait set in C; every other waitable through its own methods
        self.events = [(w, h) for w in waitables
                       if (h := getattr(w, "_EventHandler__event", None)) is not None]
        self.waitables = [w for w in waitables
                          if getattr(w, "_EventHandler__event", None) is None]
        self.sub_by_ptr = {s.handle.pointer: s for s in self.subs}
        self.timer_by_ptr = {t.handle.pointer: t for t in self.timers}
        self.service_by_ptr = {s.handle.pointer: s for s in self.services}
        self.guard_by_ptr = {g.handle.pointer: g for g in self.guards}
        extra = [w.get_num_entities() for w in self.waitables]
        events = len(self.events) + sum(e.num_events for e in extra)
        self.counts = (
            len(self.subs) + sum(e.num_subscriptions for e in extra),
            len(self.guards) + len(own_guards) + sum(e.num_guard_conditions for e in extra),
            len(self.timers) + sum(e.num_timers for e in extra),
            len(self.clients) + sum(e.num_clients for e in extra),
            len(self.services) + sum(e.num_services for e in extra),
            events)


class LeanExecutor(SingleThreadedExecutor):
    """A :class:`~rclpy.executors.SingleThreadedExecutor` with a cheaper wake-up (module
    docstring). Use it as rclpy's: ``rclpy.spin(node, LeanExecutor())``, ``add_node`` then
    ``spin``, or ``spin_once`` in a loop."""

    def __init__(self, *, context: Any = None) -> None:
        super().__init__(context=context)
        self._entities: _Entities | None = None
        #: bumped whenever the entities change, so that a rebuild that raced a change (a
        #: subscription made on another thread while the lists were read) is not kept
        self._generation = 0
        self._generation_lock = threading.Lock()
        self._wait_set: Any = None
        #: the subscriptions and events of a wait without the passive subscriptions, keyed by
        #: which subscriptions are passive (cleared at each rebuild)
        self._passive_sets: dict[tuple[int, ...], Any] = {}
        #: the handles of ``_entities``, held from one rebuild to the next
        self._held = ExitStack()
        #: held by the spinning thread from the wait to the end of the dispatch
        self._spin_lock = threading.Lock()
        #: when the next wait takes the QoS events in (time.monotonic())
        self._events_due = 0.0

    # -- rclpy calls these when entities or nodes come and go -------------------------------
    def wake(self) -> None:
        self._stale()
        super().wake()

    def add_node(self, node: Any) -> bool:
        self._stale()
        return super().add_node(node)

    def remove_node(self, node: Any) -> None:
        self._stale()
        super().remove_node(node)
        if self._spin_lock.acquire(blocking=False):   # not spinning: let its handles go now
            try:
                self._held.close()
            finally:
                self._spin_lock.release()

    def _stale(self) -> None:
        with self._generation_lock:
            self._generation += 1
            self._entities = None

    # -- spinning -----------------------------------------------------------------------------
    def spin_once(self, timeout_sec: float | None = None) -> None:
        if self._tasks:
            # coroutines in flight (async callbacks, waitables, futures): rclpy's path runs them
            super().spin_once(timeout_sec)
            return
        with self._spin_lock:
            entities = self._entities
            if entities is None:
                entities = self._rebuild()
                if entities is None:
                    return         # an entity was destroyed while rebuilding: again next time
            if entities.clients:
                self._held.close()
                super().spin_once(timeout_sec)    # service clients: rclpy's futures
                return
            timeout_ns = -1 if timeout_sec is None or timeout_sec < 0 \
                else int(timeout_sec * 1e9)
            passive = tuple(sub for sub in entities.subs if is_passive(sub))
            subs, events = self._without(entities, passive) if passive \
                else (entities.subs, entities.events)
            if events:
                # QoS events in this wait only once per EVENT_POLL_S (module docstring); a
                # wait without them ends by then at the latest
                now = time.monotonic()
                if now >= self._events_due:
                    self._events_due = now + EVENT_POLL_S
                else:
                    events = []
                    cap = int((self._events_due - now) * 1e9) + 1
                    timeout_ns = cap if timeout_ns < 0 else min(timeout_ns, cap)
            ws = self._wait_set
            ws.clear_entities()
            for sub in subs:
                ws.add_subscription(sub.handle)
            for srv in entities.services:
                ws.add_service(srv.handle)
            for tmr in entities.timers:
                ws.add_timer(tmr.handle)
            for gc in entities.guards:
                ws.add_guard_condition(gc.handle)
            for gc in entities.own_guards:
                ws.add_guard_condition(gc.handle)
            for waitable, event in events:
                waitable._event_index = ws.add_event(event)
            for waitable in entities.waitables:
                waitable.add_to_wait_set(ws)
            ws.wait(timeout_ns)
            if self._is_shutdown:
                self._held.close()
                return
            if not self._context.ok():
                self._held.close()
                raise ExternalShutdownException()
            with self._work_tracker:
                self._dispatch(entities, ws, events)

    def _rebuild(self) -> _Entities | None:
        """The entities of the nodes now, their handles held until the next rebuild."""
        self._held.close()
        self._held = ExitStack()
        generation = self._generation
        entities = _Entities(self.get_nodes(), [self._guard, self._sigint_gc])
        try:
            for group in (entities.subs, entities.timers, entities.services, entities.guards,
                          entities.own_guards):
                for entity in group:
                    self._held.enter_context(entity.handle)
            for waitable in entities.waitables:
                self._held.enter_context(waitable)
            for waitable, _ in entities.events:
                self._held.enter_context(waitable)
            context_handle: Any = self._context.handle
            self._held.enter_context(context_handle)
        except _rclpy.InvalidHandle:
            self._held.close()
            return None
        self._wait_set = _rclpy.WaitSet(*entities.counts, context_handle)
        self._passive_sets = {}
        # used for this wait; kept only if nothing changed meanwhile (else rebuilt next time)
        with self._generation_lock:
            self._entities = entities if generation == self._generation else None
        return entities

    def _without(self, entities: _Entities, passive: tuple[Any, ...]
                 ) -> tuple[list[Any], list[tuple[Any, Any]]]:
        """The subscriptions and QoS events of a wait without the ``passive`` subscriptions
        and their event handlers (kept until the next rebuild): the middleware ends a wait
        on a reader's events also when the reader holds unread messages, so they would end
        every wait at once while a passive subscription holds some."""
        key = tuple(id(sub) for sub in passive)
        found = self._passive_sets.get(key)
        if found is None:
            handlers = [h for sub in passive for h in getattr(sub, "event_handlers", ())]
            skip = {id(h) for h in handlers}
            found = self._passive_sets[key] = (
                [sub for sub in entities.subs if sub not in passive],
                [(w, e) for w, e in entities.events if id(w) not in skip])
        return found

    def _dispatch(self, entities: _Entities, ws: Any, events: list[tuple[Any, Any]]
                  ) -> None:
        """Run the callbacks of what the wait found ready: timers, subscriptions (drained),
        guard conditions, services, then waitables (as rclpy's order: timers first)."""
        for ptr in ws.get_ready_entities("timer"):
            tmr = entities.timer_by_ptr.get(ptr)
            if tmr is not None and tmr.handle.is_timer_ready():
                tmr.handle.call_timer()
                self._run(tmr.callback())
        ready: list[Any] = [sub for ptr in ws.get_ready_entities("subscription")
                            if (sub := entities.sub_by_ptr.get(ptr)) is not None]
        if len(ready) == 1:
            self._drain(ready[0])
        elif ready:
            # several topics: every queued message, round by round (the k-th of each topic
            # before the (k+1)-th of any), in arrival order within a round (module docstring)
            taken: list[tuple[int, int, int, Any, Any]] = []
            for sub in ready:
                handle, msg_type, raw = sub.handle, sub.msg_type, sub.raw
                k = 0
                while (one := handle.take_message(msg_type, raw)) is not None:
                    taken.append((k, one[1]["received_timestamp"], len(taken), sub, one))
                    k += 1
            taken.sort(key=_round_then_arrival)
            for _, _, _, sub, one in taken:
                self._deliver(sub, one)
        for ptr in ws.get_ready_entities("guard_condition"):
            gc = entities.guard_by_ptr.get(ptr)
            if gc is not None and gc.callback is not None:
                self._run(gc.callback())
        for ptr in ws.get_ready_entities("service"):
            srv = entities.service_by_ptr.get(ptr)
            if srv is None:
                continue
            request, header = srv.handle.service_take_request(srv.srv_type.Request)
            if header is None:
                continue
            response = srv.callback(request, srv.srv_type.Response())
            if inspect.iscoroutine(response):
                self.create_task(_respond_later(srv, response, header))
            else:
                srv.send_response(response, header)
        for waitable, _ in events:
            if ws.is_ready("event", waitable._event_index) and waitable.is_ready(ws):
                self.create_task(waitable.execute(waitable.take_data()))
        for waitable in entities.waitables:
            if waitable.is_ready(ws):
                data = waitable.take_data()
                self.create_task(waitable.execute(data))

    def _drain(self, sub: Any) -> None:
        """Every message queued on one subscription, oldest first."""
        handle, msg_type, raw = sub.handle, sub.msg_type, sub.raw
        while (one := handle.take_message(msg_type, raw)) is not None:
            self._deliver(sub, one)

    def _deliver(self, sub: Any, taken: Any) -> None:
        if sub._callback_type is type(sub).CallbackType.MessageOnly:
            self._run(sub.callback(taken[0]))
        else:
            self._run(sub.callback(*taken))

    def _run(self, result: Any) -> None:
        """A callback's result: a coroutine goes on to rclpy's task machinery."""
        if inspect.iscoroutine(result):
            self.create_task(result)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        self._entities = None
        done = super().shutdown(timeout_sec)     # wakes a waiting spin, waits for its work
        if self._spin_lock.acquire(timeout=-1 if timeout_sec is None or timeout_sec < 0
                                   else timeout_sec):
            try:
                self._held.close()
                self._wait_set = None
                self._passive_sets = {}
            finally:
                self._spin_lock.release()
        return done


def _round_then_arrival(item: tuple[int, int, int, Any, Any]) -> tuple[int, int, int]:
    return item[0], item[1], item[2]


async def _respond_later(srv: Any, pending: Any, header: Any) -> None:
    srv.send_response(await pending, header)
