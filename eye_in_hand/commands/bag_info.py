"""``eye-in-hand bag info BAG``: storage, time range and topics of a bag, like
``ros2 bag info``."""
from __future__ import annotations

import argparse
import json
from datetime import datetime, timezone

from eye_in_hand.io.bags import DamageLog, bag_info, check_bag

HELP = "print a bag's storage, duration, start/end and per-topic type and count"

__all__ = ["HELP", "add_arguments", "run", "format_info"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand bag info``."""
    parser.add_argument("bag", help="bag directory (metadata.yaml) or a single .mcap/.db3 file")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object instead of the human-readable table")
    parser.add_argument("--check", action="store_true",
                        help="read and decode every message, with chunk CRCs checked, and "
                             "list the damaged parts (topic, time range, messages lost); "
                             "exit status 2 when there are any")


def _stamp(ns: int) -> str:
    sec = ns / 1e9
    text = datetime.fromtimestamp(sec, tz=timezone.utc).strftime("%b %d %Y %H:%M:%S.%f")
    return f"{text[:-3]} UTC ({sec:.9f})"


def _size(n: int) -> str:
    value = float(n)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if value < 1024 or unit == "GiB":
            return f"{value:.1f} {unit}" if unit != "B" else f"{n} B"
        value /= 1024
    return f"{n} B"  # pragma: no cover


def format_info(info) -> str:  # noqa: ANN001 - BagInfo, imported lazily
    """The ``ros2 bag info``-like text for a :class:`eye_in_hand.io.bags.BagInfo`."""
    lines = [
        f"Files:             {', '.join(f.name for f in info.files)}",
        f"Bag size:          {_size(info.size_bytes)}",
        f"Storage id:        {info.storage}",
        f"Metadata version:  {info.version if info.version is not None else 'none (bare file)'}",
        f"ROS distro:        {info.ros_distro or 'unknown'}",
        f"Duration:          {info.duration_ns / 1e9:.9f}s",
        f"Start:             {_stamp(info.start_ns)}",
        f"End:               {_stamp(info.end_ns)}",
        f"Messages:          {info.message_count}",
        f"Compression:       {info.compression_format or 'none'}"
        + (f" ({info.compression_mode} mode)" if info.compression_mode else ""),
    ]
    width = max((len(t.name) for t in info.topics.values()), default=0)
    tw = max((len(t.msgtype) for t in info.topics.values()), default=0)
    first = True
    for topic in info.topics.values():
        head = "Topic information: " if first else " " * 19
        first = False
        lines.append(f"{head}Topic: {topic.name:<{width}} | Type: {topic.msgtype:<{tw}} | "
                     f"Count: {topic.count} | Serialization Format: "
                     f"{topic.serialization_format}")
    if first:
        lines.append("Topic information: (none)")
    for note in info.notes:
        lines.append(f"Note:              {note}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Print the bag summary."""
    info = bag_info(args.bag)
    damage = DamageLog()
    good = check_bag(args.bag, damage) if args.check else None
    if args.json:
        data = info.to_dict()
        if good is not None:
            data["check"] = {"read": good, "damage": damage.to_dict()}
        print(json.dumps(data, indent=None))
    else:
        print(format_info(info))
        if good is not None:
            total = sum(good.values())
            if not damage:
                print(f"Check:             all {total} messages read and decoded, no damage")
            else:
                print(f"Check:             {total} messages read and decoded; "
                      f"{damage.summary()}")
                for line in damage.lines(limit=50):
                    print(f"Damaged:           {line}")
    return 2 if damage else 0
