"""Message types and decoding: the Jazzy type store, definitions stored in a bag (with the Jazzy
fallback), ``deserialize`` / ``serialize``, ``iter_decoded``, ``require_topics``."""
from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from eye_in_hand.errors import BagError, ConversionError
from eye_in_hand.io.bags.reading import _OpenBag, iter_messages
from eye_in_hand.io.bags.records import BagInfo, DamageLog

_DEFAULT_STORE: Any = None
_DEFAULT_LOCK = threading.Lock()


def default_typestore() -> Any:
    """A shared ROS 2 Jazzy ``rosbags`` type store (do not register types in it)."""
    global _DEFAULT_STORE
    with _DEFAULT_LOCK:
        if _DEFAULT_STORE is None:
            # local: rosbags costs ~25 ms at CLI start-up (every command loads io.bags)
            from rosbags.typesys import Stores, get_typestore

            _DEFAULT_STORE = get_typestore(Stores.ROS2_JAZZY)
        return _DEFAULT_STORE


def jazzy_decoder(msgtype: str) -> Callable[[bytes], Any]:
    """``decode(raw)``: one message type's CDR bytes (with the 4-byte encapsulation header)
    into a ``rosbags`` message object, with the ROS 2 Jazzy definition. rosbags' generated
    decoder takes 3-26 us for the live inputs of ``hand_eye`` (a PointStamped to a
    MarkerArray) where rclpy's conversion of a taken message takes 9-65 us
    (docs/localization.md). Errors of malformed bytes propagate as they are (struct,
    index and decoding errors): the caller reports them.

    Raises:
        BagError: ROS 2 Jazzy does not define ``msgtype``.
    """
    store = default_typestore()
    if msgtype not in store.types:
        raise BagError(f"message type {msgtype} is not defined in ROS 2 Jazzy: no decoder")
    deserialize = store.deserialize_cdr

    def decode(raw: bytes) -> Any:
        return deserialize(raw, msgtype)

    return decode


def types_from_definition(msgtype: str, fmt: Any, text: str) -> dict[str, Any]:
    """The message types of one connection's recorded definition (``msg`` or ``idl`` text),
    for a type store's ``register``."""
    # local: rosbags costs ~25 ms at CLI start-up (every command loads io.bags)
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    if fmt == MessageDefinitionFormat.MSG:
        return dict(get_types_from_msg(text, msgtype))
    types: dict[str, Any] = {}
    sep = "=" * 80 + "\n"
    if text.startswith(f"{sep}IDL: "):
        for part in text.split(sep)[1:]:
            _header, idl = part.split("\n", 1)
            types.update(get_types_from_idl(idl))
    else:
        types.update(get_types_from_idl(text))
    return types


def _type_refs(fields: Any) -> Iterator[str]:
    """The message type names a rosbags field list refers to."""
    # local: rosbags.interfaces costs ~14 ms at CLI start-up (every command loads io.bags)
    from rosbags.interfaces import Nodetype

    def walk(node: Any) -> Iterator[str]:
        kind, detail = node
        if kind == Nodetype.NAME:
            yield detail
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            yield from walk(detail[0])

    for _name, node in fields:
        yield from walk(node)


def _type_closure(types: Mapping[str, Any], roots: Iterable[str]) -> tuple[dict[str, Any],
                                                                         set[str]]:
    """``types`` restricted to ``roots`` and the types they use, recursively; and the names
    used but not in ``types``."""
    out: dict[str, Any] = {}
    missing: set[str] = set()
    todo = list(roots)
    while todo:
        name = todo.pop()
        if name in out or name in missing:
            continue
        if name not in types:
            missing.add(name)
            continue
        out[name] = types[name]
        todo.extend(_type_refs(types[name][1]))
    return out, missing


def typestore_for(path: str | Path, msgtypes: Iterable[str] | None = None) -> Any:
    """A type store that can decode every message of a bag (or the types asked for).

    It holds the message definitions stored in the bag (MCAP schemas, the sqlite3
    ``message_definitions`` table of Jazzy bags) and, for every other type, the ROS 2 Jazzy
    definitions. A bag's own definition wins over Jazzy's, so bags from other distributions
    whose types changed still decode; a stored definition that does not parse is replaced by
    the Jazzy one when Jazzy defines the type (and :func:`deserialize` falls back to the Jazzy
    definition for a message the stored one does not decode).

    Args:
        path: a bag directory or a ``.mcap``/``.db3`` file.
        msgtypes: only these types (and the types they use) are registered; None: all. Building
            every type costs ~0.1 s, and loading the Jazzy definitions ~0.15 s more, which is
            skipped when the bag defines everything asked for.

    Returns:
        A ``rosbags.typesys.store.Typestore``; pass it to :func:`deserialize`.

    Raises:
        BagError: the bag cannot be opened, or a stored definition cannot be parsed.
    """
    # local: rosbags costs ~25 ms at CLI start-up (every command loads io.bags)
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_typestore

    wanted = None if msgtypes is None else set(msgtypes)
    types: dict[str, Any] = {}
    with _OpenBag(path) as bag:
        for conn in bag.connections():
            # every stored definition is parsed (cheap): a type asked for may be defined only
            # inside another topic's definition; building (register) is what costs
            if conn.msgdef.format == MessageDefinitionFormat.NONE or conn.msgtype in types:
                continue
            try:
                types.update(types_from_definition(conn.msgtype, conn.msgdef.format,
                                                    conn.msgdef.data))
            except Exception as exc:
                if conn.msgtype in default_typestore().types:
                    continue     # a stored definition that does not parse: Jazzy's is used
                raise BagError(f"bag {bag.path}: cannot parse the stored definition of "
                               f"{conn.msgtype} (topic {conn.topic}): {exc}") from exc
    if wanted is None or _type_closure(types, wanted)[1]:
        for name, fields in default_typestore().fielddefs.items():
            types.setdefault(name, fields)
    if wanted is not None:
        types = _type_closure(types, wanted)[0]
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(types)
    except Exception as exc:
        raise BagError(f"bag {Path(path)}: cannot build types from its definitions: {exc}"
                       ) from exc
    return store


def deserialize(raw: bytes | bytearray | memoryview, msgtype: str, typestore: Any = None) -> Any:
    """Decode CDR bytes into a ``rosbags`` message object.

    Args:
        raw: the serialized message (CDR with its 4-byte encapsulation header).
        msgtype: e.g. ``sensor_msgs/msg/Image``.
        typestore: from :func:`typestore_for`; default: the Jazzy type store. When the
            type store's definition does not decode the bytes and ROS 2 Jazzy defines the
            type, the Jazzy definition is tried before giving up (a bag may store an old or
            wrong definition).

    Returns:
        A rosbags dataclass instance (numpy arrays for numeric sequences).

    Raises:
        BagError: unknown type, or bytes that decode with neither definition.
    """
    store = typestore if typestore is not None else default_typestore()
    # the Jazzy store only when it is needed: building it costs ~0.1 s of CPU, at the first
    # message of every `process` run that decodes with the bag's own definitions
    if msgtype not in store.types and msgtype not in default_typestore().types:
        raise BagError(f"message type {msgtype} is not known (not in ROS 2 Jazzy and not "
                       "defined by the bag); cannot decode it")
    data = bytes(raw)
    try:
        if msgtype not in store.types:
            raise KeyError(msgtype)
        return store.deserialize_cdr(data, msgtype)
    except Exception as exc:
        # the bag's stored definition may be old or wrong (a recorder with another
        # distribution's definition): the Jazzy definition, when there is one, gets a try
        jazzy = default_typestore()
        if store is not jazzy and msgtype in jazzy.types:
            try:
                return jazzy.deserialize_cdr(data, msgtype)
            except Exception:
                pass
            raise BagError(f"cannot decode {len(raw)} bytes as {msgtype} with the bag's "
                           f"definition ({exc}) nor with the ROS 2 Jazzy one") from exc
        raise BagError(f"cannot decode {len(raw)} bytes as {msgtype}: {exc}") from exc


def serialize(msg: Any, msgtype: str, typestore: Any = None) -> bytes:
    """Encode a ``rosbags`` message object as CDR bytes (little endian).

    Args:
        msg: a rosbags message instance, e.g. ``store.types['std_msgs/msg/String'](data='x')``.
        msgtype: its type name.
        typestore: default: the Jazzy type store.

    Returns:
        The CDR bytes, with encapsulation header.

    Raises:
        BagError: unknown type, or a message that does not match the type.
    """
    store = typestore if typestore is not None else default_typestore()
    if msgtype not in store.types:
        raise BagError(f"message type {msgtype} is not known; cannot encode it")
    if hasattr(type(msg), "get_fields_and_field_types"):
        raise BagError(f"got an rclpy {type(msg).__name__} for {msgtype}: pass its CDR bytes "
                       "(rclpy.serialization.serialize_message(msg)) or a rosbags message")
    try:
        return bytes(store.serialize_cdr(msg, msgtype))
    except Exception as exc:
        raise BagError(f"cannot encode a {type(msg).__name__} as {msgtype}: {exc}") from exc


def require_topics(info: BagInfo, topics: Iterable[str]) -> None:
    """Check that a bag has every topic in ``topics``, with at least one message.

    Args:
        info: from :func:`bag_info`.
        topics: the topic names needed.

    Raises:
        BagError: naming the missing (or empty) topics and listing what the bag has.
    """
    missing = [t for t in topics if t not in info.topics]
    empty = [t for t in topics if t in info.topics and info.topics[t].count == 0]
    if not missing and not empty:
        return
    have = ", ".join(f"{t.name} ({t.msgtype}, {t.count})" for t in info.topics.values())
    parts = []
    if missing:
        parts.append(f"lacks topic{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    if empty:
        parts.append(f"has no messages on {', '.join(empty)}")
    raise BagError(f"bag {info.path} {' and '.join(parts)}; it has: {have or 'no topics'}")





def iter_decoded(path: str | Path, topics: Iterable[str] | None = None,
                 start_ns: int | None = None, end_ns: int | None = None, *,
                 damage: DamageLog | None = None) -> Iterator[tuple[str, int, Any]]:
    """Like :func:`iter_messages`, with each message decoded (for offline processing).

    Types are taken from :func:`typestore_for` (the bag's own definitions, Jazzy for the rest;
    a message that its stored definition does not decode is tried with the Jazzy one).

    Args:
        damage: as :func:`iter_messages`; a message that does not decode is recorded there
            too (:meth:`DamageLog.bad_message`, naming topic and log time) and skipped.

    Yields:
        ``(topic, log_time_ns, message)`` with rosbags message objects (numpy arrays for
        numeric sequences).

    Raises:
        BagError: as :func:`iter_messages`, or (without ``damage``) a message that does not
            decode (names the topic and the log time).
    """
    store = typestore_for(path)
    for topic, msgtype, stamp, raw in iter_messages(path, topics, start_ns, end_ns,
                                                    damage=damage):
        try:
            msg = deserialize(raw, msgtype, store)
        except BagError as exc:
            if damage is None:
                raise BagError(f"bag {Path(path)}, topic {topic} at {stamp} ns: {exc}") from exc
            damage.bad_message(topic, stamp, str(exc))
            continue
        yield topic, stamp, msg


def check_bag(path: str | Path, damage: DamageLog) -> dict[str, int]:
    """Read and decode every message of a bag, chunk CRCs checked: what ``bag info --check``
    does.

    Args:
        path: a bag directory or a ``.mcap``/``.db3`` file.
        damage: receives every damaged region and every message that does not decode
            (images: their layout and data length are checked without copying the pixels).

    Returns:
        Topic -> number of messages read and decoded.

    Raises:
        BagError: the bag cannot be opened at all.
    """
    # local: io.cdr at module top measured ~20 ms more at CLI start-up (every command loads
    # io.bags; python -X importtime), and only `bag info --check` needs it
    from eye_in_hand.io.cdr import image_from_cdr, is_image_type

    store = typestore_for(path)
    good: dict[str, int] = {}
    for topic, msgtype, stamp, raw in iter_messages(path, views=True, verify_crc=True,
                                                    damage=damage):
        try:
            img = image_from_cdr(raw) if is_image_type(msgtype) else None
            if img is not None:
                if img.height * img.step > len(img.data):
                    raise ConversionError(f"image data: {len(img.data)} bytes, "
                                          f"height x step needs {img.height * img.step}")
            else:
                deserialize(raw, msgtype, store)
        except (BagError, ConversionError) as exc:
            damage.bad_message(topic, stamp, str(exc))
            continue
        good[topic] = good.get(topic, 0) + 1
    return good
