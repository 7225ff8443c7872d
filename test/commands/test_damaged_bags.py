"""Damaged bags in every command that reads them: the damage is skipped, counted and named,
everything else is used."""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.io.bags import (
    BagWriter,
    bag_info,
    default_typestore,
    deserialize,
    iter_messages,
    serialize,
)
from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
from eye_in_hand.sim import World
from eye_in_hand.sim.output import write_bag

LEFT, RIGHT = "/stereo/left/image_raw", "/stereo/right/image_raw"
BOARD = "chessboard:9x6:0.025"


def _chunks(mcap: Path) -> list[tuple[int, int]]:
    """(offset, offset of the chunk's records) of each chunk record, by a scan."""
    data = mcap.read_bytes()
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            (n,) = struct.unpack_from("<I", data, pos + 9 + 28)
            out.append((pos, pos + 9 + 32 + n + 8))
        if op == 0x02:
            break
        pos += 9 + length
    return out


def _smash(mcap: Path, at: int, n: int = 64, seed: int = 7) -> None:
    """``n`` random bytes at byte ``at``."""
    data = bytearray(mcap.read_bytes())
    data[at:at + n] = np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()
    mcap.write_bytes(bytes(data))


def _image_chunk(mcap: Path, topic: str, k: int) -> tuple[int, int]:
    """The chunk holding the ``k``-th message of ``topic``: (offset, records offset)."""
    stamps = [s for _t, _m, s, _r in iter_messages(mcap.parent, [topic])]
    from rosbags.rosbag2 import Reader

    with Reader(mcap.parent) as reader:
        infos = reader.storage.storages[0].chunks
        conn = next(c for c in reader.connections if c.topic == topic)
        hit = [c for c in infos if c.message_start_time <= stamps[k] <= c.message_end_time
               and c.channel_count.get(conn.id)]
    # chunks may overlap in time (the simulator's first chunk holds the robot stream):
    # the smallest candidate is the image's own chunk
    best = min(hit, key=lambda c: sum(c.channel_count.values()))
    offsets = dict(_chunks(mcap))
    return best.chunk_start_offset, offsets[best.chunk_start_offset]


def _copy(src: Path, dst: Path, edit=None) -> None:
    """An uncompressed copy of a bag, each message passed through ``edit(topic, index, raw)``."""
    info = bag_info(src)
    seen: dict[str, int] = {}
    with BagWriter(dst) as out:
        for name, t in info.topics.items():
            out.add_topic(name, t.msgtype)
        for topic, _mt, stamp, raw in iter_messages(src):
            k = seen[topic] = seen.get(topic, -1) + 1
            out.write(topic, stamp, edit(topic, k, raw) if edit else raw)


@pytest.fixture(scope="module")
def cal_bag(tmp_path_factory) -> Path:
    """A 640x360 calibration bag (7 still stops, about 2 images each), uncompressed, with two
    truncated left images (the 5th and 6th: both of a stop) and one NaN robot pose: damage
    inside messages."""
    d = tmp_path_factory.mktemp("damaged")
    world = World.default().with_image_size(640, 360)
    write_bag(world, d / "sim", scenario="calibration", frames=7, seed=4, hold_frames=2,
              still_images_only=True)
    store = default_typestore()

    def edit(topic: str, k: int, raw: bytes) -> bytes:
        if topic == LEFT and k in (4, 5):
            return raw[: len(raw) // 2]                         # truncated images
        if topic == "/ee_pose" and k == 700:
            msg = deserialize(raw, "geometry_msgs/msg/PoseStamped")
            msg.pose.position.x = float("nan")
            return serialize(msg, "geometry_msgs/msg/PoseStamped", store)
        return raw

    _copy(d / "sim", d / "bag", edit)
    return d / "bag"


def _damaged_copy(cal_bag: Path, tmp_path: Path, k: int = 10) -> tuple[Path, int]:
    """The calibration bag with 64 random bytes over the first records of the chunk holding
    the ``k``-th left image; returns (bag, chunk offset)."""
    import shutil

    bag = tmp_path / "bag"
    shutil.copytree(cal_bag, bag)
    mcap = next(bag.glob("*.mcap"))
    off, records = _image_chunk(mcap, LEFT, k)
    _smash(mcap, records + 2)
    return bag, off


def test_bag_info_check_lists_damaged_chunk_and_truncated_image(cal_bag, tmp_path, capsys):
    bag, off = _damaged_copy(cal_bag, tmp_path)
    assert main(["bag", "info", str(bag)]) == 0          # the summary alone reads no chunk
    capsys.readouterr()
    assert main(["bag", "info", str(bag), "--check"]) == 2
    out = capsys.readouterr().out
    assert f"chunk at byte {off}" in out and LEFT in out
    assert "message" in out and "data" in out            # the truncated image, named
    assert main(["bag", "info", str(bag), "--check", "--json"]) == 2
    check = json.loads(capsys.readouterr().out)["check"]
    wheres = [r["where"] for r in check["damage"]["records"]]
    assert f"chunk at byte {off}" in wheres and "message" in wheres
    assert check["damage"]["messages_lost"] >= 2
    total = sum(t.count for t in bag_info(bag).topics.values())
    assert sum(check["read"].values()) + check["damage"]["messages_lost"] == total
    assert main(["bag", "info", str(cal_bag), "--check"]) == 2   # the truncated images only
    assert "2 damaged region(s)" in capsys.readouterr().out


def test_calibrate_stereo_from_a_damaged_bag(cal_bag, tmp_path, capsys):
    bag, off = _damaged_copy(cal_bag, tmp_path)
    n_left = bag_info(bag).topics[LEFT].count
    rc = main(["calibrate", "stereo", "--bag", str(bag), "--left-topic", LEFT, "--right-topic",
               RIGHT, "--board", BOARD, "-o", str(tmp_path / "out"), "--no-html"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert f"chunk at byte {off}" in cap.err and "damaged" in cap.err
    damage = json.loads((tmp_path / "out" / "report.json").read_text())["input"]["damage"]
    assert damage["regions"] == 3                 # the chunk and the truncated images
    assert damage["by_topic"][LEFT] >= 2
    pairs = json.loads((tmp_path / "out" / "report.json").read_text())["input"]["pairs"]
    assert n_left - damage["messages_lost"] <= pairs < n_left


def test_calibrate_camera_from_a_damaged_bag(cal_bag, tmp_path, capsys):
    bag, off = _damaged_copy(cal_bag, tmp_path)
    rc = main(["calibrate", "camera", "--bag", str(bag), "--left-topic", LEFT, "--board",
               BOARD, "-o", str(tmp_path / "out"), "--no-html"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert f"chunk at byte {off}" in cap.err and "damaged bag" in cap.out
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["input"]["damage"]["regions"] == 3
    assert report["input"]["images"] == bag_info(bag).topics[LEFT].count - \
        report["input"]["damage"]["by_topic"][LEFT]


def test_calibrate_handeye_from_a_damaged_bag(cal_bag, tmp_path, capsys):
    bag, off = _damaged_copy(cal_bag, tmp_path)
    rc = main(["calibrate", "handeye", "--bag", str(bag), "--board", BOARD, "--left-topic",
               LEFT, "--right-topic", RIGHT, "--robot-pose", "ee_pose",
               "-o", str(tmp_path / "out"), "--no-html"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert f"chunk at byte {off}" in cap.err
    assert "/ee_pose" in cap.err and "must be finite" in cap.err  # the NaN pose, named
    assert f"{LEFT}" in cap.err and "damaged" in cap.err           # the truncated image
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    text = json.dumps(report)
    assert f"chunk at byte {off}" in text and "must be finite" in text
    damage = report["input"]["damage"]
    assert damage["regions"] == 3   # the chunk, the NaN pose, the truncated image of a stop
    assert damage["by_topic"]["/ee_pose"] >= 2


def test_too_few_samples_left_is_a_clear_error(cal_bag, tmp_path, capsys):
    """Damage everywhere: the calibration says how few samples remain, in one line."""
    import shutil

    bag = tmp_path / "bag"
    shutil.copytree(cal_bag, bag)
    mcap = next(bag.glob("*.mcap"))
    hits = {_image_chunk(mcap, LEFT, k) for k in range(2, bag_info(bag).topics[LEFT].count)}
    for off, records in hits:
        _smash(mcap, records + 2, seed=off)
    rc = main(["calibrate", "handeye", "--bag", str(bag), "--board", BOARD, "--left-topic",
               LEFT, "--right-topic", RIGHT, "--robot-pose", "ee_pose",
               "-o", str(tmp_path / "out"), "--no-html"])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err
    assert "usable samples" in err or "samples" in err.splitlines()[-1]


@pytest.fixture(scope="module")
def loc_bag(tmp_path_factory) -> tuple[Path, World]:
    out = tmp_path_factory.mktemp("damaged_loc") / "loc"
    world = World.default().with_image_size(640, 360)
    write_bag(world, out, scenario="localization", frames=12, seed=3)
    return out, world


def _hand_eye(tmp_path: Path, world: World) -> Path:
    path = tmp_path / "hand_eye.yaml"
    save_hand_eye(path, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth"))
    return path


def test_process_a_bag_with_a_corrupt_zstd_chunk(loc_bag, tmp_path, capsys):
    import shutil

    src, world = loc_bag
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    mcap = next(bag.glob("*.mcap"))
    off, records = _image_chunk(mcap, RIGHT, 6)
    chunk_data = records            # compressed: the zstd frame starts here
    _smash(mcap, chunk_data + 40)
    out = tmp_path / "out"
    rc = main(["process", str(bag), "--hand-eye", str(_hand_eye(tmp_path, world)), "-o",
               str(out), "--quiet", "--workers", "1"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "damaged bag: 1 damaged region(s) skipped" in cap.out
    assert f"chunk at byte {off}" in cap.err and "decompress" in cap.err
    summary = json.loads((out / "summary.json").read_text())
    c, damage = summary["counts"], summary["damage"]
    assert damage["regions"] == 1 and c["damaged_regions"] == 1
    rec = damage["records"][0]
    assert rec["where"] == f"chunk at byte {off}" and RIGHT in rec["topics"]
    assert rec["start_ns"] <= rec["end_ns"] and rec["messages"] >= 1
    assert c["messages_lost"] == rec["messages"]
    # the rest was processed: every pair not touched by the chunk
    assert 12 - rec["messages"] <= c["pairs"] < 12 and c["localized"] == c["pairs"]
    assert "/ee_pose" not in rec["topics"]


def test_process_verify_crc_names_a_flipped_bit(loc_bag, tmp_path, capsys):
    src, world = loc_bag
    bag = tmp_path / "raw"
    _copy(src, bag)
    mcap = next(bag.glob("*.mcap"))
    off, records = _image_chunk(mcap, LEFT, 3)
    data = bytearray(mcap.read_bytes())
    data[records + 200_000] ^= 0x10                # one pixel of an image
    mcap.write_bytes(bytes(data))
    he = str(_hand_eye(tmp_path, world))
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(tmp_path / "o1"), "--quiet",
                 "--workers", "1"]) == 0
    assert json.loads((tmp_path / "o1" / "summary.json").read_text())["damage"]["regions"] == 0
    capsys.readouterr()
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(tmp_path / "o2"), "--quiet",
                 "--workers", "1", "--verify-crc"]) == 0
    cap = capsys.readouterr()
    assert f"chunk at byte {off}" in cap.err and "CRC mismatch" in cap.err
    damage = json.loads((tmp_path / "o2" / "summary.json").read_text())["damage"]
    assert damage["regions"] == 1 and damage["by_topic"].get(LEFT, 0) >= 1
