"""The demo behind ``make demo``: calibrate from a bag, localize live and offline, compare.

Steps (each one a real ``eye-in-hand`` command, printed before it runs):

1. ``calibrate stereo`` from ``bags/calibration`` (intrinsics, distortion, extrinsic);
2. ``calibrate handeye`` from the same bag, with that stereo calibration (no ground truth used);
3. live over DDS: ``launch`` starts ``detect_triangulate`` and ``hand_eye`` (the images come from
   the bag, so ``stereo_capture`` is not started), ``echo`` listens on ``/target/pose``, and
   ``play`` replays ``bags/localization`` through the ``bag_player`` node;
4. offline: ``process`` runs the same pipeline over the same bag with no DDS;
5. the results: both calibrations and the base-frame target error against the bag's ground
   truth, and the live-vs-offline agreement on every frame both produced.

Everything is written under ``demo_out/`` (replaced on each run). DDS traffic stays on this
machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) on a domain id of its own unless
``ROS_DOMAIN_ID`` is set.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from eye_in_hand.commands.common import deprecated_alias
from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.transforms import transform_distance
from eye_in_hand.errors import EXIT_UNEXPECTED, debug_enabled, unexpected_error_line
from eye_in_hand.io.bags import bag_info, deserialize, iter_messages
from eye_in_hand.io.config import load_hand_eye
from eye_in_hand.io.results import compare_outputs, output_messages
from eye_in_hand.ros.camera_info import camera_info_to_model
from eye_in_hand.ros.geometry import point_to_xyz, transform_to_matrix
from eye_in_hand.ros.stamps import header_stamp_ns

ROOT = Path(__file__).resolve().parent.parent
BOARD = "chessboard:9x6:0.025"
LEFT, RIGHT = "/stereo/left/image_raw", "/stereo/right/image_raw"
#: What detect_triangulate and hand_eye publish for the bundled world's one target (id "red"),
#: recorded during the live step and compared with the output bag of ``process``.
OUTPUT_TOPICS = ("/target/point", "/target/point_cov", "/targets/markers", "/targets/red/point",
                 "/targets/red/point_cov", "/target/pose", "/target/pose_cov",
                 "/target/red/pose", "/target/red/pose_cov", "/target/poses", "/target/markers",
                 "/hand_eye/transform", "/tf", "/tf_static")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "eye_in_hand.cli", *args]


def _show(cmd: Sequence[str]) -> str:
    shown = ["eye-in-hand" if c == "eye_in_hand.cli" else c for c in cmd[3:]]
    return "$ eye-in-hand " + " ".join(shown[1:] if shown and shown[0] == "eye-in-hand" else
                                       shown)


def _run(cmd: list[str], env: dict[str, str], *, quiet: bool = False) -> str:
    print(_show(cmd), flush=True)
    proc = subprocess.run(cmd, env=env, text=True, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT)
    out = proc.stdout
    if not quiet or proc.returncode != 0:
        for line in out.splitlines():
            if "\r" not in line and "it/s]" not in line and "img/s]" not in line:
                print("  " + line)
    if proc.returncode != 0:
        raise SystemExit(f"demo: step failed (exit {proc.returncode}): {' '.join(cmd)}")
    return out


def _ground_truth(bag: Path) -> dict[str, Any]:
    out: dict[str, Any] = {"targets": {}}
    for topic, mt, _t, raw in iter_messages(bag, ["/ground_truth/hand_eye",
                                                  "/ground_truth/target",
                                                  "/stereo/left/camera_info",
                                                  "/stereo/right/camera_info"]):
        msg = deserialize(raw, mt)
        if topic == "/ground_truth/hand_eye":
            out["ee_T_cam"] = transform_to_matrix(msg.transform)
        elif topic == "/ground_truth/target":
            out["targets"].setdefault(header_stamp_ns(msg), point_to_xyz(msg.point))
        elif topic.endswith("camera_info") and topic not in out:
            out[topic] = camera_info_to_model(msg)
    return out


def _stats(errors_m: Sequence[float]) -> str:
    e = np.asarray(errors_m) * 1000.0
    if e.size == 0:
        return "no frames"
    return (f"RMS {np.sqrt(np.mean(e ** 2)):.3f} mm, p95 {np.percentile(e, 95):.3f} mm, "
            f"max {e.max():.3f} mm over {e.size} frames")


def _wait_subscribed(recorder: subprocess.Popen, topics: Sequence[str], timeout_s: float
                     ) -> str:
    """Read the recorder's log until it subscribed to every topic (or ``timeout_s`` passed, or
    it exited); returns what it printed."""
    import selectors

    assert recorder.stderr is not None
    want, text = set(topics), []
    sel = selectors.DefaultSelector()
    sel.register(recorder.stderr, selectors.EVENT_READ)
    end = time.monotonic() + timeout_s
    while want and time.monotonic() < end and recorder.poll() is None:
        if not sel.select(timeout=0.2):
            continue
        line = recorder.stderr.readline()
        text.append(line)
        for topic in list(want):
            if f"subscribed to {topic} (" in line:
                want.discard(topic)
    sel.close()
    if want:
        raise SystemExit(f"demo: the recorder did not subscribe to {sorted(want)} within "
                         f"{timeout_s:.0f} s:\n{''.join(text)[-2000:]}")
    return "".join(text)


def live_step(params: Path, loc_bag: Path, live_file: Path, env: dict[str, str], n_pairs: int,
              *, calibration: Path, hand_eye: Path, quiet: bool = False,
              record: Path | None = None) -> tuple[list[dict], str]:
    """Step 3: ``launch`` (no stereo_capture), ``echo /target/pose``, ``play`` the bag.

    With ``record``, ``record`` also writes every output topic of the nodes
    (:data:`OUTPUT_TOPICS`) into that bag; the replay starts once it is subscribed to all.

    Nothing is lost to discovery: ``play --wait-for-topics`` waits, before the first message,
    until every hop of the pipeline has a publisher and a subscriber: its own topics (images,
    robot pose: matched subscribers) and ``/target/point`` (detect_triangulate -> hand_eye)
    and ``/target/pose`` (hand_eye -> echo), however slowly the processes start.

    Returns:
        The target poses received (JSON dicts) and the launch's output.
    """
    launch_cmd = _cli("launch", "--params", str(params), "--calibration", str(calibration),
                      "--hand-eye", str(hand_eye), "--skip", "stereo_capture")
    echo_cmd = _cli("echo", "/target/pose", "--json", "--count", str(n_pairs),
                    "--timeout", "60")
    play_cmd = _cli("play", str(loc_bag), "--topics", LEFT, RIGHT, "/ee_pose",
                    "--wait-for-subscribers", "60", "--wait-for-topics", "/target/point",
                    "/target/pose")
    if not quiet:
        print(_show(launch_cmd) + " &", flush=True)
    launch = subprocess.Popen(launch_cmd, env=env, text=True, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, start_new_session=True)
    recorder = None
    if record is not None:
        record_cmd = _cli("record", "-o", str(record), *OUTPUT_TOPICS)
        if not quiet:
            print(_show(record_cmd) + " &", flush=True)
        recorder = subprocess.Popen(record_cmd, env=env, text=True, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.PIPE)
    if not quiet:
        print(_show(echo_cmd) + f" > {live_file.name} &", flush=True)
    with live_file.open("w") as fh:
        echo = subprocess.Popen(echo_cmd, env=env, text=True, stdout=fh,
                                stderr=subprocess.PIPE)
        try:
            if recorder is not None:
                _wait_subscribed(recorder, OUTPUT_TOPICS, 60.0)
            _run(play_cmd, env, quiet=quiet)
            # The last poses are still in flight (a busy machine detects late): wait while
            # they keep coming, up to 10 s after the last one and 60 s in all.
            size, last, end = -1, time.monotonic(), time.monotonic() + 60.0
            while echo.poll() is None and time.monotonic() < min(last + 10.0, end):
                if live_file.stat().st_size != size:
                    size, last = live_file.stat().st_size, time.monotonic()
                time.sleep(0.1)
        finally:
            if echo.poll() is None:
                echo.send_signal(signal.SIGINT)
                echo.wait(timeout=10)
            if recorder is not None:
                time.sleep(0.5)                 # the last frame's outputs, after its pose
                recorder.send_signal(signal.SIGINT)
                recorder.communicate(timeout=30)
            os.killpg(launch.pid, signal.SIGINT)
            try:
                launch_out, _ = launch.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(launch.pid, signal.SIGKILL)
                launch_out, _ = launch.communicate()
    live = [json.loads(line) for line in live_file.read_text().splitlines() if line.strip()]
    return live, launch_out


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; returns 0 when every step ran and the live path produced poses."""
    parser = argparse.ArgumentParser(prog="python -m eye_in_hand.demo", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calibration-bag", default=str(ROOT / "bags" / "calibration"))
    parser.add_argument("--localization-bag", default=str(ROOT / "bags" / "localization"))
    out_flag = parser.add_argument("-o", "--output", default="demo_out",
                                   help="output folder (replaced; default: %(default)s)")
    deprecated_alias(parser, "--out", out_flag)
    args = parser.parse_args(argv)

    t_start = time.monotonic()
    out = Path(args.output).resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(120, 200)))
    env["PYTHONUNBUFFERED"] = "1"
    cal_bag, loc_bag = Path(args.calibration_bag), Path(args.localization_bag)
    calib, he_dir = out / "calibration", out / "hand_eye"

    print("== 1/5 stereo calibration from", cal_bag, flush=True)
    _run(_cli("calibrate", "stereo", "--bag", str(cal_bag), "--left-topic", LEFT,
              "--right-topic", RIGHT, "--board", BOARD, "-o", str(calib)), env)

    print("\n== 2/5 hand-eye calibration from", cal_bag, "(with the stereo calibration above)",
          flush=True)
    _run(_cli("calibrate", "handeye", "--bag", str(cal_bag), "--board", BOARD,
              "--calibration", str(calib), "--left-topic", LEFT, "--right-topic", RIGHT,
              "-o", str(he_dir)), env)

    print("\n== 3/5 live over DDS: launch detect_triangulate + hand_eye, echo /target/pose, "
          "play", loc_bag, flush=True)
    params = ROOT / "config" / "eye_in_hand.yaml"      # the shipped bring-up, as it is
    n_pairs = bag_info(loc_bag).topics[LEFT].count
    live_file = out / "live_target_pose.jsonl"
    live, launch_out = live_step(params, loc_bag, live_file, env, n_pairs,
                                 calibration=calib, hand_eye=he_dir / "hand_eye.yaml",
                                 record=out / "live_outputs")
    (out / "launch.log").write_text(launch_out)
    for msg in live[:3]:
        p = msg["pose"]["position"]
        stamp = msg["header"]["stamp"]
        print(f"  target/pose @ {stamp['sec']}.{stamp['nanosec']:09d}"
              f"  [{p['x']:.5f}, {p['y']:.5f}, {p['z']:.5f}] m in {msg['header']['frame_id']}")
    if len(live) > 3:
        print(f"  ... {len(live)} poses in {live_file}")

    print("\n== 4/5 offline: the same pipeline over the same bag, no DDS", flush=True)
    processed = out / "processed"
    _run(_cli("process", str(loc_bag), "--calibration", str(calib), "--hand-eye",
              str(he_dir / "hand_eye.yaml"), "--params", str(params), "-o", str(processed),
              "--quiet"), env)

    print("\n== 5/5 results against the bags' ground truth", flush=True)
    targets: dict[int, np.ndarray] = _ground_truth(loc_bag)["targets"]
    _print_calibrations(cal_bag, calib, he_dir / "hand_eye.yaml")
    live_pts = _compare_live_offline(out, targets, live, processed, n_pairs)
    print(f"\ndemo finished in {time.monotonic() - t_start:.0f} s; outputs in {out}")
    return 0 if live_pts else 1


def _print_calibrations(cal_bag: Path, calib: Path, hand_eye: Path) -> None:
    """Step 5: the stereo and hand-eye calibrations against the calibration bag's truth."""
    cal_truth = _ground_truth(cal_bag)
    rig = StereoRig.load(calib)
    true_rig = StereoRig.from_ros_pair(cal_truth["/stereo/left/camera_info"],
                                       cal_truth["/stereo/right/camera_info"])
    he = load_hand_eye(hand_eye)
    dt, dr = transform_distance(he.transform, cal_truth["ee_T_cam"])
    print(f"stereo calibration: fx {rig.left.fx:.2f} px (true {true_rig.left.fx:.2f}), baseline "
          f"{1000 * rig.baseline:.3f} mm (true {1000 * true_rig.baseline:.3f})")
    print(f"hand-eye ({he.method}): {1000 * dt:.3f} mm, {np.degrees(dr):.4f} deg from the true "
          "mount")


def _compare_live_offline(out: Path, targets: dict[int, np.ndarray],
                          live: list[dict[str, Any]], processed: Path,
                          n_pairs: int) -> dict[int, np.ndarray]:
    """Step 5: the live and the offline poses against the true ``targets`` (by stamp) and
    against each other, and the two output bags message by message; the live poses by
    stamp."""
    live_pts = {m["header"]["stamp"]["sec"] * 10**9 + m["header"]["stamp"]["nanosec"]:
                np.array([m["pose"]["position"][k] for k in "xyz"]) for m in live}
    offline = {}
    with (processed / "results.csv").open() as fh:
        for row in csv.DictReader(fh):
            if row["status"] == "ok":
                offline[int(row["stamp_ns"])] = np.array(
                    [float(row[k]) for k in ("x_base", "y_base", "z_base")])
    common = sorted(set(live_pts) & set(offline))
    diff = max((float(np.max(np.abs(live_pts[s] - offline[s]))) for s in common), default=0.0)
    live_err = [float(np.linalg.norm(p - targets[s])) for s, p in live_pts.items()
                if s in targets]
    offline_err = [float(np.linalg.norm(p - targets[s])) for s, p in offline.items()
                   if s in targets]
    print(f"live:    {len(live_pts)}/{n_pairs} frames, {_stats(live_err)}")
    print(f"offline: {len(offline)}/{n_pairs} frames, {_stats(offline_err)}")
    print(f"live vs offline: {len(common)} frames in both, largest difference {diff:.2e} m")
    live_msgs = output_messages(out / "live_outputs", OUTPUT_TOPICS)
    offline_msgs = output_messages(processed, OUTPUT_TOPICS)
    problems = compare_outputs(live_msgs, offline_msgs, set(common))
    n_msgs = sum(len([m for m in v if m[0] in set(common)]) for v in live_msgs.values())
    print(f"live vs offline bags: {len(set(live_msgs) | set(offline_msgs))} topics, "
          f"{n_msgs} messages of those frames: " + (
              "identical" if not problems else "DIFFERENT: " + "; ".join(problems[:5])))
    return live_pts


def guarded_main(argv: Sequence[str] | None = None) -> int:
    """``main`` behind the top-level guard every entry point has: an unexpected error is one
    line and exit 70 (``--debug`` or ``EYE_IN_HAND_DEBUG=1``: the traceback)."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    if debug:
        args.remove("--debug")
    try:
        return main(args)
    except (SystemExit, KeyboardInterrupt):
        raise
    except BaseException as exc:  # noqa: BLE001 - the top-level guard: one line, not a traceback
        if debug or debug_enabled():
            raise
        print(unexpected_error_line("python -m eye_in_hand.demo", exc), file=sys.stderr)
        return EXIT_UNEXPECTED


if __name__ == "__main__":
    sys.exit(guarded_main())
