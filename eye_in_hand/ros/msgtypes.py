"""Message classes looked up by type name, from ROS interface packages only.

A bag names its message types (``sensor_msgs/msg/Image``), and so does the ROS graph. Importing
``<pkg>.msg`` for whatever a bag names would run the ``__init__`` of any Python package that
happens to be installed (a bag naming ``this/msg/Foo`` would import ``this``). So a type is
imported only when:

- its name matches ``^[A-Za-z][A-Za-z0-9_]*/msg/[A-Z][A-Za-z0-9_]*$`` (``pkg/Type`` is read as
  ``pkg/msg/Type``);
- ``pkg`` is a Python package (found without importing it) that rosidl generated: its folder
  holds the ``<pkg>_s__rosidl_typesupport_c`` extension that ``rosidl_generator_py`` builds for
  every interface package, and a ``msg`` subpackage.

Nothing is imported before both checks pass.

:func:`message_definition` writes an installed type's ``.msg`` definition as rosbag2 stores it,
and :func:`installed_type_hash` its RIHS01 hash (to compare with the hash a bag recorded).
"""
from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path
from typing import Any

from eye_in_hand.errors import BagError, EyeInHandError

__all__ = ["MSGTYPE_PATTERN", "valid_msgtype", "interface_package_dir", "import_message_type",
           "message_definition", "installed_type_hash"]

#: A message type name that may be imported.
MSGTYPE_PATTERN = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/msg/[A-Z][A-Za-z0-9_]*$")


def _normalise(msgtype: str) -> str:
    parts = msgtype.split("/") if isinstance(msgtype, str) else []
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return msgtype if isinstance(msgtype, str) else ""


def valid_msgtype(msgtype: str) -> bool:
    """Whether ``msgtype`` is a well-formed message type name (``pkg/msg/Type`` or
    ``pkg/Type``)."""
    return bool(MSGTYPE_PATTERN.match(_normalise(msgtype)))


def interface_package_dir(package: str) -> Path | None:
    """The folder of the installed rosidl-generated Python package ``package``, or None.

    Found with :func:`importlib.util.find_spec` on the top-level name, which locates the package
    without running its code.
    """
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", package or ""):
        return None
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None  # not installed, or a plain module
    for location in spec.submodule_search_locations:
        folder = Path(location)
        if not (folder / "msg" / "__init__.py").is_file():
            continue
        if any(folder.glob(f"{package}_s__rosidl_typesupport_c*")) or any(
                folder.glob(f"_{package}_s.ep.rosidl_typesupport_c*")):
            return folder
    return None


def import_message_type(msgtype: str) -> Any:
    """The Python message class for ``pkg/msg/Type``, or None when it is not an installed
    ROS interface type.

    Args:
        msgtype: e.g. ``sensor_msgs/msg/Image`` (``pkg/Type`` is read as ``pkg/msg/Type``).

    Returns:
        The class (e.g. ``sensor_msgs.msg.Image``), or None when the name is malformed, the
        package is not a rosidl interface package (nothing is imported then), or it has no such
        message.
    """
    name = _normalise(msgtype)
    if not MSGTYPE_PATTERN.match(name):
        return None
    package, _, type_name = name.split("/")
    folder = interface_package_dir(package)
    if folder is None:
        return None
    try:
        module = importlib.import_module(f"{package}.msg")
    except ImportError:
        return None
    cls = getattr(module, type_name, None)
    if cls is None or not hasattr(cls, "_TYPE_SUPPORT") and not hasattr(
            type(cls), "_TYPE_SUPPORT"):
        return None
    return cls


_BASE_TYPES = {
    "boolean": "bool", "octet": "byte", "float": "float32", "double": "float64",
    "long double": "float64",
}
_SEQ = re.compile(r"^sequence<(.+?)(?:,\s*(\d+))?>$")
_ARR = re.compile(r"^(.+)\[(\d+)\]$")


def _msg_field_type(idl: str, deps: list[str]) -> str:
    """Translate one ``get_fields_and_field_types`` entry into ``.msg`` syntax."""
    if m := _SEQ.match(idl):
        inner = _msg_field_type(m.group(1), deps)
        return f"{inner}[<={m.group(2)}]" if m.group(2) else f"{inner}[]"
    if m := _ARR.match(idl):
        return f"{_msg_field_type(m.group(1), deps)}[{m.group(2)}]"
    if "/" in idl:
        pkg, name = idl.split("/")[0], idl.split("/")[-1]
        full = f"{pkg}/msg/{name}"
        if full not in deps:
            deps.append(full)
        return f"{pkg}/{name}"
    return _BASE_TYPES.get(idl, idl)


def message_definition(msgtype: str) -> str:
    """The ``.msg`` definition of an installed message type, dependencies appended.

    Built from the Python class (``get_fields_and_field_types``), in the concatenated form
    rosbag2 stores (``====`` line, ``MSG: pkg/msg/Dep``, definition). Constants and default values
    are not included (they do not change the wire format).

    Args:
        msgtype: ``pkg/msg/Type``.

    Returns:
        The definition text.

    Raises:
        BagError: the type (or one of its field types) is not installed.
    """
    deps: list[str] = [msgtype]
    parts: list[str] = []
    i = 0
    while i < len(deps):
        name = deps[i]
        cls = import_message_type(name)
        if cls is None:
            raise BagError(f"message type {name} (used by {msgtype}) is not installed")
        lines = [f"{_msg_field_type(t, deps)} {field}"
                 for field, t in cls.get_fields_and_field_types().items()]
        text = "\n".join(lines) + "\n"
        parts.append(text if i == 0 else f"{'=' * 80}\nMSG: {name}\n{text}")
        i += 1
    return "".join(parts)


_HASHES: dict[str, str | None] = {}


def installed_type_hash(msgtype: str) -> str | None:
    """The RIHS01 type hash of the installed message class, or None when unknown.

    Computed from the class's fields (see :func:`message_definition`), so it can be compared
    with the hash a bag recorded (metadata >= 7). Cached per type.
    """
    if msgtype not in _HASHES:
        # local: rosbags' type system costs ~55 ms at start-up of every node (all load this
        # module through ros.markers); only bag_player's type check needs it
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        try:
            store = get_typestore(Stores.EMPTY)
            store.register(dict(get_types_from_msg(message_definition(msgtype), msgtype)))
            _HASHES[msgtype] = store.hash_rihs01(msgtype)
        except (EyeInHandError, ValueError, KeyError):
            _HASHES[msgtype] = None
    return _HASHES[msgtype]
