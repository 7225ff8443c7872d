"""``eye-in-hand record -o BAG TOPIC...``: record topics into a rosbag2 bag."""
from __future__ import annotations

import argparse
import shutil

from rclpy.parameter import Parameter

from eye_in_hand.commands.common import bounded
from eye_in_hand.errors import BagError, InputError
from eye_in_hand.io.atomic import check_output_dir
from eye_in_hand.io.bags import COMPRESSIONS, STORAGES
from eye_in_hand.nodes.bag_recorder import BagRecorder, spin_recorder
from eye_in_hand.ros.names import check_parameter_text, check_topic_name
from eye_in_hand.ros.node_main import run_with_executor, sigterm_as_interrupt

HELP = "record topics into a rosbag2 bag (mcap or sqlite3), like ros2 bag record"

__all__ = ["HELP", "add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand record``."""
    parser.add_argument("topics", nargs="*", metavar="TOPIC",
                        help="topics to record (waits for topics that do not exist yet)")
    parser.add_argument("-o", "--output", required=True, metavar="BAG",
                        help="bag directory to create (must not exist, or give --overwrite)")
    parser.add_argument("--overwrite", action="store_true",
                        help="delete an existing bag of that name when recording starts (a "
                             "recording is written in place, so that a crash keeps what was "
                             "recorded)")
    parser.add_argument("-a", "--all", action="store_true",
                        help="record every topic, including ones that appear later, except "
                             "hidden ones (a name component starting with '_')")
    parser.add_argument("-s", "--storage", choices=STORAGES, default=STORAGES[0],
                        help="storage plugin (default mcap, as ros2 bag record on Jazzy)")
    parser.add_argument("--compression", choices=tuple(c or "none" for c in COMPRESSIONS),
                        default="none",
                        help="zstd: compressed MCAP chunks (mcap) or per-message zstd "
                             "(sqlite3); default none")
    parser.add_argument("-d", "--duration", type=bounded(0, 1e7, "s"), default=0.0, metavar="S",
                        help="stop after S seconds, 0 to 1e7 (default 0: until Ctrl-C / "
                             "SIGTERM)")
    parser.add_argument("--max-cache-mb", type=bounded(1, 65536, "MiB"), default=512.0,
                        metavar="MIB",
                        help="MiB of received messages that may wait for the disk before new "
                             "ones are dropped, 1 to 65536 (default 512)")
    parser.add_argument("--discovery-period", type=bounded(0.01, 60, "s"), default=0.2,
                        metavar="S",
                        help="seconds between polls for new topics, 0.01 to 60 (default 0.2)")


def run(args: argparse.Namespace) -> int:
    """Record until ``--duration`` passes or Ctrl-C/SIGTERM; the bag is always left valid."""
    if not args.topics and not args.all:
        raise InputError("give the topics to record, or --all")
    check_parameter_text(str(args.output), "-o")
    for topic in args.topics:
        check_topic_name(topic, "record TOPIC")
    out = check_output_dir(args.output, overwrite=args.overwrite)
    if out.is_dir():  # empty, or --overwrite
        shutil.rmtree(out)
    overrides = [
        Parameter("output", value=str(args.output)),
        Parameter("all", value=bool(args.all)),
        Parameter("storage", value=args.storage),
        Parameter("compression", value="" if args.compression == "none" else args.compression),
        Parameter("discovery_period", value=float(args.discovery_period)),
        Parameter("duration", value=float(args.duration)),
        Parameter("max_cache_mb", value=float(args.max_cache_mb)),
    ]
    if args.topics:  # an empty list would be typed as a byte array
        overrides.append(Parameter("topics", Parameter.Type.STRING_ARRAY, list(args.topics)))
    sigterm_as_interrupt()
    try:
        return run_with_executor(
            lambda: BagRecorder(parameter_overrides=overrides),
            lambda node, ex: spin_recorder(node, float(args.duration), ex), args=[])
    except BagError as exc:
        cause = _os_error(exc)
        if cause is None:
            raise
        # a full disk or a file-size limit: the bag is written in place (so that a crash
        # keeps what was recorded); say so, under the bag's name
        raise BagError(f"{args.output}: cannot write ({cause.strerror or cause}); what was "
                       f"recorded until then stays in {args.output} (a bag without its index "
                       "is read by scanning, see docs/bags.md)") from exc


def _os_error(exc: BaseException) -> OSError | None:
    """The ``OSError`` behind ``exc`` (its causes), if any."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError):
            return e
        e = e.__cause__ or e.__context__
    return None
