"""``eye-in-hand play BAG``: publish a bag's messages over DDS at the recorded pace."""
from __future__ import annotations

import argparse

from rclpy.parameter import Parameter

from eye_in_hand.commands.common import bounded
from eye_in_hand.errors import InputError
from eye_in_hand.io.bags import bag_info
from eye_in_hand.nodes.bag_player import BagPlayer, spin_player
from eye_in_hand.ros.names import check_parameter_text
from eye_in_hand.ros.node_main import run_with_executor, sigterm_as_interrupt

HELP = "publish a bag's messages over DDS at the recorded pace (like ros2 bag play)"

__all__ = ["HELP", "add_arguments", "run"]


#: How long ``--wait-for-topics`` waits when ``--wait-for-subscribers`` is not given (s).
WAIT_S = 60.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand play``."""
    parser.add_argument("bag", help="bag directory (metadata.yaml) or a single .mcap/.db3 file")
    parser.add_argument("-r", "--rate", type=bounded(0, 1000, lo_open=True), default=1.0,
                        help="playback speed factor, (0, 1000] (default 1.0; 2.0 plays twice "
                             "as fast)")
    parser.add_argument("-l", "--loop", action="store_true", help="restart at the end, forever")
    parser.add_argument("--clock", action="store_true",
                        help="publish /clock (rosgraph_msgs/Clock) with the bag time, for nodes "
                             "with use_sim_time")
    parser.add_argument("--clock-hz", type=bounded(0, 1000, "Hz", lo_open=True), default=40.0,
                        metavar="HZ",
                        help="/clock publishing frequency, (0, 1000] Hz (default 40, as ros2 "
                             "bag play)")
    parser.add_argument("--topics", nargs="+", default=[], metavar="TOPIC",
                        help="play only these topics (default: all)")
    parser.add_argument("--start-offset", type=bounded(0, 1e7, "s"), default=0.0, metavar="S",
                        help="start S seconds into the bag, 0 to 1e7 (default 0)")
    parser.add_argument("--wait-for-subscribers", type=bounded(0, 3600, "s"), default=None,
                        metavar="S",
                        help="before the first message, wait up to S seconds (0 to 3600) "
                             "until every topic has a subscriber (default: 0, do not wait, "
                             "like ros2 bag play, where messages sent before discovery "
                             f"completes are lost; {WAIT_S:g} with --wait-for-topics)")
    parser.add_argument("--wait-for-topics", nargs="+", default=[], metavar="TOPIC",
                        help="also wait until each TOPIC (the pipeline's downstream hops, e.g. "
                             "/target/point /target/pose) has a publisher and a subscriber "
                             "(up to --wait-for-subscribers S)")


def wait_for_subscribers_s(args: argparse.Namespace) -> float:
    """The wait before the first message: ``--wait-for-subscribers``, else :data:`WAIT_S` with
    ``--wait-for-topics`` (which would otherwise wait for nothing), else 0."""
    if args.wait_for_subscribers is not None:
        return float(args.wait_for_subscribers)
    return WAIT_S if args.wait_for_topics else 0.0


def run(args: argparse.Namespace) -> int:
    """Play the bag until its end (or forever with ``--loop``); Ctrl-C stops cleanly."""
    bag_info(args.bag)  # fail with one clear line before starting ROS
    check_parameter_text(str(args.bag), "BAG")
    for topic in args.topics or ():
        check_parameter_text(topic, "--topics")
    wait = wait_for_subscribers_s(args)
    overrides = [
        Parameter("bag", value=str(args.bag)),
        Parameter("rate", value=float(args.rate)),
        Parameter("loop", value=bool(args.loop)),
        Parameter("clock", value=bool(args.clock)),
        Parameter("clock_hz", value=float(args.clock_hz)),
        Parameter("start_offset", value=float(args.start_offset)),
        Parameter("wait_for_subscribers", value=float(wait)),
    ]
    if args.wait_for_topics:
        if not wait > 0:
            raise InputError("--wait-for-topics: waits up to --wait-for-subscribers S, which "
                             "is 0: give S > 0 (or leave it out: 60 s)")
        overrides.append(Parameter("wait_for_topics", Parameter.Type.STRING_ARRAY,
                                   list(args.wait_for_topics)))
    if args.topics:  # an empty list would be typed as a byte array
        overrides.append(Parameter("topics", Parameter.Type.STRING_ARRAY, list(args.topics)))
    sigterm_as_interrupt()
    return run_with_executor(lambda: BagPlayer(parameter_overrides=overrides), spin_player,
                             args=[])
