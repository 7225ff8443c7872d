"""The ``bag_player`` node's parameters: their table and the validated configuration.

A part of :class:`eye_in_hand.nodes.bag_player.BagPlayer`: :func:`declare_player_config`
declares :data:`NODE_PARAMETERS` on the node and returns a :class:`PlayerConfig`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

from eye_in_hand.errors import ConfigError
from eye_in_hand.ros.params import Param, declare_params

__all__ = ["NODE_PARAMETERS", "PlayerConfig", "declare_player_config"]


@dataclass(frozen=True)
class PlayerConfig:
    """Validated ``bag_player`` parameters."""

    bag: str
    rate: float
    loop: bool
    clock: bool
    clock_hz: float
    topics: tuple[str, ...]
    start_offset: float
    wait_for_subscribers: float
    wait_for_topics: tuple[str, ...] = ()


#: The node's parameters (declared at start-up; the keys its parameter file may hold).
NODE_PARAMETERS: tuple[Param, ...] = (
    Param("bag", "", "bag directory or .mcap/.db3 file"),
    Param("rate", 1.0, "playback speed factor (2.0: twice as fast)", range=(0.001, 1000.0)),
    Param("loop", False, "restart at the end"),
    Param("clock", False, "publish rosgraph_msgs/Clock on /clock (for use_sim_time)"),
    Param("clock_hz", 40.0, "/clock publishing frequency", range=(0.1, 1000.0)),
    Param("topics", (), "topics to play (empty: all)", type="str[]"),
    Param("start_offset", 0.0, "seconds into the bag to start from", range=(0.0, 1e9)),
    Param("wait_for_subscribers", 0.0, "wait up to this many seconds for a subscriber on "
          "every topic (0: do not wait)", range=(0.0, 3600.0)),
    Param("wait_for_topics", (), "with wait_for_subscribers: also wait until each of these "
          "topics has a publisher and a subscriber (the downstream hops of a pipeline)",
          type="str[]"),
)


def declare_player_config(node: Any) -> PlayerConfig:
    """Declare :data:`NODE_PARAMETERS` on ``node`` and validate them.

    ``wait_for_topics`` are resolved against the node's namespace.

    Raises:
        ConfigError: a parameter is missing, of the wrong type or out of range (names it).
    """
    try:
        v = declare_params(node, NODE_PARAMETERS)
    except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
        raise ConfigError(f"{node.get_name()}: bad parameter: {exc}") from exc
    bag, rate, loop, clock, clock_hz = (v["bag"], v["rate"], v["loop"], v["clock"],
                                        v["clock_hz"])
    topics, offset, wait = v["topics"], v["start_offset"], v["wait_for_subscribers"]
    downstream = v["wait_for_topics"]
    if not bag:
        raise ConfigError("parameter 'bag' is required (a bag directory or .mcap file)")
    return PlayerConfig(bag=str(bag), rate=float(rate), loop=bool(loop), clock=bool(clock),
                        clock_hz=float(clock_hz), topics=tuple(str(t) for t in topics),
                        start_offset=float(offset), wait_for_subscribers=float(wait),
                        wait_for_topics=tuple(node.resolve_topic_name(str(t))
                                              for t in downstream))
