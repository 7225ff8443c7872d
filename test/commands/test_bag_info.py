"""``eye-in-hand bag info`` and the one-line errors of the bag commands."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from eye_in_hand.cli import main
from eye_in_hand.io.bags import BagWriter, default_typestore, serialize

T0 = 1_700_000_000_000_000_000


def _bag(path: Path, storage: str = "mcap") -> Path:
    store = default_typestore()
    with BagWriter(path, storage, "zstd") as bag:
        bag.add_topic("/left/image_raw", "sensor_msgs/msg/Image")
        bag.add_topic("/chatter", "std_msgs/msg/String")
        for i in range(3):
            bag.write("/chatter", T0 + i * 500_000_000,
                      serialize(store.types["std_msgs/msg/String"](data=str(i)),
                                "std_msgs/msg/String"))
        img = store.types["sensor_msgs/msg/Image"]
        hdr = store.types["std_msgs/msg/Header"]
        stamp = store.types["builtin_interfaces/msg/Time"]
        import numpy as np

        bag.write("/left/image_raw", T0 + 250_000_000, img(
            header=hdr(stamp=stamp(sec=1, nanosec=2), frame_id="cam"), height=1, width=2,
            encoding="mono8", is_bigendian=0, step=2, data=np.array([1, 2], dtype=np.uint8)))
    return path


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_info_text(tmp_path: Path, capsys: pytest.CaptureFixture[str], storage: str) -> None:
    _bag(tmp_path / "bag", storage)
    assert main(["bag", "info", str(tmp_path / "bag")]) == 0
    out = capsys.readouterr().out
    assert f"Storage id:        {storage}" in out
    assert "Duration:          1.000000000s" in out
    assert "Messages:          4" in out
    assert "Topic: /chatter        | Type: std_msgs/msg/String   | Count: 3" in out
    assert "Topic: /left/image_raw | Type: sensor_msgs/msg/Image | Count: 1" in out
    assert "(1700000000.000000000)" in out and "(1700000001.000000000)" in out


def test_bag_info_json_on_a_single_mcap_file(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    _bag(tmp_path / "bag")
    assert main(["bag", "info", "--json", str(tmp_path / "bag" / "bag.mcap")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["storage"] == "mcap" and data["version"] is None
    assert data["start_ns"] == T0 and data["end_ns"] == T0 + 1_000_000_000
    assert {t["name"]: (t["type"], t["count"]) for t in data["topics"]} == {
        "/chatter": ("std_msgs/msg/String", 3), "/left/image_raw": ("sensor_msgs/msg/Image", 1)}


def test_missing_bag_is_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                       ) -> None:
    assert main(["bag", "info", str(tmp_path / "nope")]) == 1
    err = capsys.readouterr().err
    assert err == f"eye-in-hand: error: bag {tmp_path / 'nope'} does not exist\n"


@pytest.mark.parametrize("command", [["bag", "info"], ["play"]])
def test_corrupt_bag_gives_one_line_and_no_traceback(tmp_path: Path, ros_env: dict[str, str],
                                                     command: list[str]) -> None:
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n"
        "  relative_file_paths: [bad_0.mcap]\n")
    (bad / "bad_0.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    proc = subprocess.run([sys.executable, "-m", "eye_in_hand.cli", *command, str(bad)],
                          capture_output=True, text=True, timeout=60, env=ros_env)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"eye-in-hand: error: cannot open bag {bad}:")
    assert "Traceback" not in proc.stderr
