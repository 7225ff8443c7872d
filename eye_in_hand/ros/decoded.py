"""Subscriptions that take a message's serialized bytes and decode them with a given decoder.

rclpy turns each taken message into a Python object of its generated class, one attribute and
one nested ``__init__`` at a time: 9-14 us for a ``PointStamped`` or a ``PoseStamped``, 19 us
for a ``PoseWithCovarianceStamped`` and 65 us for a ``MarkerArray`` of two markers. A live
``hand_eye`` takes four to eight of them per stereo pair. :func:`decoded_subscription` takes
the bytes instead (``raw=True``) and hands them to a decoder: ``hand_eye`` reads the fields
it uses straight from little-endian CDR (``eye_in_hand.io.cdr``, 1-9 us a message) through
``eye_in_hand.nodes.hand_eye_poses.fields_decoder``, other encodings and ``joint_states``
through ``eye_in_hand.io.bags.decoding.jazzy_decoder`` (rosbags' generated CDR decoder, 2-25 us
for the same messages: a ``rosbags`` object with the fields of the ROS message, which every
reader of :mod:`eye_in_hand.ros` takes as it takes an rclpy one).

Bytes that do not decode are not lost silently: ``on_bad(topic, error)`` is called with the
decoder's error (the node reports it on ``diagnostics``) and the callback is not.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["decoded_subscription", "decode_each", "msgtype_of", "undecodable"]


def undecodable(topic: str, exc: Exception) -> str:
    """The report of a message on ``topic`` whose bytes did not decode."""
    return f"{topic}: a message that does not decode ({type(exc).__name__}: {exc}): ignored"


def msgtype_of(msg_class: Any) -> str:
    """``package/msg/Name`` of an rclpy message class."""
    return f"{msg_class.__module__.split('.', 1)[0]}/msg/{msg_class.__name__}"


def decoded_subscription(node: Any, msg_class: Any, topic: str,
                         callback: Callable[[Any], None], qos: Any, *,
                         decoder_for: Callable[[str], Callable[[bytes], Any]],
                         on_bad: Callable[[str, Exception], None]) -> Any:
    """``node.create_subscription(msg_class, topic, ..., qos, raw=True)`` whose callback
    decodes the bytes with ``decoder_for(msgtype)`` (``msgtype`` the class's
    ``package/msg/Name``) and calls ``callback(message)``; bytes that do not decode go to
    ``on_bad(topic, error)``. The subscription keeps the decoder (its ``decode`` attribute)
    for messages taken outside its callback (:func:`decode_each`)."""
    decode = decoder_for(msgtype_of(msg_class))
    name = [topic]

    def take(raw: bytes) -> None:
        try:
            msg = decode(raw)
        except Exception as exc:  # noqa: BLE001 - any decoder error: reported, the node goes on
            on_bad(name[0], exc)
            return
        callback(msg)

    sub = node.create_subscription(msg_class, topic, take, qos, raw=True)
    name[0] = sub.topic_name           # resolved: namespace and remapping applied
    sub.decode = decode
    return sub


def decode_each(sub: Any, taken: list[tuple[Any, int]],
                on_bad: Callable[[str, Exception], None]) -> list[tuple[Any, int]]:
    """Messages taken from a :func:`decoded_subscription` outside its callback (``(bytes,
    reception time)``, e.g. from :func:`eye_in_hand.ros.executor.take_queued`), decoded;
    those that do not decode go to ``on_bad`` and are left out. A subscription of rclpy
    messages passes its messages through as they are."""
    decode = getattr(sub, "decode", None)
    if decode is None:
        return taken
    out = []
    for raw, received_ns in taken:
        try:
            out.append((decode(raw), received_ns))
        except Exception as exc:  # noqa: BLE001 - as in decoded_subscription
            on_bad(sub.topic_name, exc)
    return out
