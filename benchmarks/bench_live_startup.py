"""Live start-up losses: the live step of ``make demo``, repeated (issue #14).

Runs the demo's step 3 (``launch`` detect_triangulate + hand_eye, ``echo /target/pose``,
``play bags/localization``) ``--runs`` times in a row, with fresh processes each time, and
prints how many of the bag's stereo pairs gave a live target/pose in each run, and which were
missing. Load the other core while it runs to see the busy-machine case, e.g.::

    python -c 'while 1: pass' & LOAD=$!
    .venv/bin/python benchmarks/bench_live_startup.py --runs 10
    kill $LOAD

Needs the calibrations of a ``make demo`` run (``--demo-out``, default ``demo_out``).
"""
from __future__ import annotations

import argparse
import os
import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from eye_in_hand.demo import LEFT, live_step  # noqa: E402
from eye_in_hand.io.bags import bag_info, iter_messages  # noqa: E402
from eye_in_hand.io.cdr import image_from_cdr  # noqa: E402
from eye_in_hand.ros.stamps import header_stamp_ns  # noqa: E402

LEDGER = ("left_frames", "right_frames", "sync_unpaired_left", "sync_unpaired_right",
          "dropped_pairs", "no_target", "failed_pairs", "points_published", "points",
          "poses_published", "rejected")


class Diagnostics:
    """The latest /diagnostics values of every node, received on a thread."""

    def __init__(self) -> None:
        import threading

        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor

        rclpy.init(args=[])
        self.node = rclpy.create_node("bench_live_startup")
        self.latest: dict[str, dict[str, str]] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 50)
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._spin, daemon=True)
        self._th.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.ex.spin_once(timeout_sec=0.1)

    def _on(self, msg) -> None:
        for st in msg.status:
            self.latest[st.name] = {kv.key: kv.value for kv in st.values}

    def spin(self, seconds: float) -> None:
        time.sleep(seconds)

    def ledger(self) -> str:
        out = []
        for name, values in sorted(self.latest.items()):
            parts = [f"{k}={values[k]}" for k in LEDGER if k in values]
            parts += [f"{k}={v}" for k, v in values.items()
                      if k.startswith("refused.") and v != "0" and "rate" not in k]
            if parts:
                out.append(f"{name}: " + " ".join(parts))
        return "; ".join(out) or "no diagnostics received"

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self._th.join()
        self.ex.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--demo-out", default="demo_out",
                        help="output folder of a make demo run (its calibrations)")
    parser.add_argument("--bag", default=str(ROOT / "bags" / "localization"))
    args = parser.parse_args()
    demo = Path(args.demo_out).resolve()
    params = ROOT / "config" / "eye_in_hand.yaml"      # the shipped bring-up, as make demo
    calib, hand_eye = demo / "calibration", demo / "hand_eye" / "hand_eye.yaml"
    if not hand_eye.is_file():
        print(f"bench_live_startup: {hand_eye} not found: run make demo first", file=sys.stderr)
        return 1
    bag = Path(args.bag)
    n = bag_info(bag).topics[LEFT].count
    stamps = [header_stamp_ns(image_from_cdr(raw))
              for _t, _m, _s, raw in iter_messages(bag, [LEFT])]
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(120, 200)))
    env["PYTHONUNBUFFERED"] = "1"
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    diags = Diagnostics()
    counts = []
    for run in range(1, args.runs + 1):
        diags.latest.clear()
        t0 = time.monotonic()
        live, _log = live_step(params, bag, demo / f"bench_live_{run}.jsonl", env, n,
                               calibration=calib, hand_eye=hand_eye, quiet=True)
        got = {m["header"]["stamp"]["sec"] * 10**9 + m["header"]["stamp"]["nanosec"]
               for m in live}
        missing = [i + 1 for i, s in enumerate(stamps) if s not in got]
        counts.append(len(got))
        diags.spin(2.5)                     # the nodes' last diagnostics before they stopped
        print(f"run {run:2d} ledger: {diags.ledger()}")
        print(f"run {run:2d}: {len(got)}/{n} frames live in {time.monotonic() - t0:.1f} s"
              + (f", missing frames {missing}" if missing else ""), flush=True)
        for line in _log.splitlines():
            if "WARN" in line or "ERROR" in line or "restart" in line:
                print("    " + line[:300], flush=True)
    diags.close()
    full = sum(c == n for c in counts)
    print(f"{full}/{len(counts)} runs with {n}/{n} frames; frames per run: {counts}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
