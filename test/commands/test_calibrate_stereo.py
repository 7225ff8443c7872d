"""``eye-in-hand calibrate stereo``: outputs from files and from a bag, bad input."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.core.camera import StereoRig

BOARD = "chessboard:9x6:1.0"


def _pairs(data_dir: Path) -> list[tuple[Path, Path]]:
    folder = data_dir / "opencv_stereo_chessboard"
    return [(f, folder / f.name.replace("left", "right"))
            for f in sorted(folder.glob("left*.jpg"))]


def _write_bag(path: Path, frames: dict[str, list[tuple[int, np.ndarray]]]) -> None:
    from eye_in_hand.io.bags import BagWriter, default_typestore

    store = default_typestore()
    Image = store.types["sensor_msgs/msg/Image"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    msgs = []
    for topic, items in frames.items():
        for stamp, img in items:
            msgs.append((stamp + (1000 if "right" in topic else 0), topic, Image(
                header=Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9),
                              frame_id=topic),
                height=img.shape[0], width=img.shape[1], encoding="mono8", is_bigendian=0,
                step=img.shape[1], data=img.ravel().copy())))
    with BagWriter(path) as bag:
        for topic in frames:
            bag.add_topic(topic, "sensor_msgs/msg/Image")
        for log, topic, msg in sorted(msgs, key=lambda m: m[0]):
            bag.write(topic, log, msg)


def test_stereo_from_files(data_dir: Path, tmp_path: Path, capsys) -> None:
    folder = data_dir / "opencv_stereo_chessboard"
    out = tmp_path / "rig"
    code = main(["calibrate", "stereo", "--left", str(folder / "left*.jpg"), "--right",
                 str(folder / "right*.jpg"), "--board", BOARD, "-o", str(out),
                 "--detector", "classic"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert sorted(p.name for p in out.iterdir()) == [
        "left.yaml", "report.html", "report.json", "right.yaml", "stereo.yaml"]
    report = json.loads((out / "report.json").read_text())
    for side in ("left", "right"):
        assert np.array(report[side]["K"]).shape == (3, 3)
        assert len(report[side]["dist"]) == 5 and report[side]["rms_px"] < 0.3
    st = report["stereo"]
    assert st["rms_px"] < 0.3 and np.array(st["R"]).shape == (3, 3) and len(st["T"]) == 3
    assert abs(st["baseline"] - 3.34) < 0.03
    assert st["epipolar_error_px"] < 0.2 and st["rectified_dy_mean_px"] <= 0.2
    assert abs(st["square_measured"]["mean"] - 1.0) < 0.02 and st["square_measured"]["std"] < 0.05
    assert len(report["views"]) == 13
    assert all({"file", "rms_px", "used"} <= v.keys() and v["used"] for v in report["views"])
    rig = StereoRig.load(out)
    assert rig.baseline == pytest.approx(st["baseline"])
    # ROS reads the stereo geometry from the two files alone
    (out / "stereo.yaml").unlink()
    ros = StereoRig.load(out)
    assert ros.baseline == pytest.approx(st["baseline"], rel=1e-6)
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4 and "Rectified pair" in html


def test_stereo_from_bag_matches_by_header_stamp(data_dir: Path, tmp_path: Path,
                                                 capsys) -> None:
    pairs = _pairs(data_dir)[:8]
    left = [(10**9 * (k + 1), cv2.imread(str(lf), cv2.IMREAD_GRAYSCALE))
            for k, (lf, _) in enumerate(pairs)]
    right = [(10**9 * (k + 1), cv2.imread(str(rf), cv2.IMREAD_GRAYSCALE))
             for k, (_, rf) in enumerate(pairs)]
    left.insert(3, (3_500_000_000, left[0][1]))  # no right partner: ignored
    _write_bag(tmp_path / "bag", {"/stereo/left/image_raw": left,
                                  "/stereo/right/image_raw": right})
    out = tmp_path / "rig"
    code = main(["calibrate", "stereo", "--bag", str(tmp_path / "bag"), "--left-topic",
                 "/stereo/left/image_raw", "--right-topic", "/stereo/right/image_raw",
                 "--board", BOARD, "-o", str(out), "--every", "1", "--no-html"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "1 image(s) had no partner" in captured.err
    report = json.loads((out / "report.json").read_text())
    assert [v["file"] for v in report["views"]] == [
        f"/stereo/left/image_raw@{10**9 * (k + 1)}" for k in range(8)]
    assert report["views"][0]["right_file"] == f"/stereo/right/image_raw@{10**9}"
    assert abs(report["stereo"]["baseline"] - 3.34) < 0.05


@pytest.mark.parametrize("case", ["count", "size", "few", "alpha", "topics"])
def test_stereo_bad_input_writes_nothing(case: str, data_dir: Path, tmp_path: Path,
                                         capsys) -> None:
    lefts, rights = tmp_path / "l", tmp_path / "r"
    lefts.mkdir()
    rights.mkdir()
    for lf, rf in _pairs(data_dir)[:6]:
        shutil.copy(lf, lefts / lf.name)
        shutil.copy(rf, rights / rf.name)
    extra: list[str] = []
    if case == "count":
        (rights / "right06.jpg").unlink()
        expect = "6 left image(s)"
    elif case == "size":
        for f in rights.iterdir():
            cv2.imwrite(str(f), cv2.resize(cv2.imread(str(f)), (320, 240)))
        expect = "left images are 640x480"
    elif case == "few":
        extra, expect = ["--min-views", "7"], "only 6 pair(s) with the board in both images"
    elif case == "alpha":   # refused by the option's range, before the images are read
        extra = ["--alpha", "1.5"]
        with pytest.raises(SystemExit) as exit_info:
            main(["calibrate", "stereo", "--left", str(lefts / "*"), "--right",
                  str(rights / "*"), "--board", BOARD, "-o", str(tmp_path / "rig")] + extra)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert err.splitlines() == ["eye-in-hand calibrate stereo: error: argument --alpha: "
                                    "must be within [0, 1], got 1.5 (see eye-in-hand calibrate "
                                    "stereo --help)"]
        assert not (tmp_path / "rig").exists()
        return
    else:
        extra, expect = ["--left-topic", "/a"], "either --left GLOB --right GLOB or --bag"
    out = tmp_path / "rig"
    code = main(["calibrate", "stereo", "--left", str(lefts / "*"), "--right", str(rights / "*"),
                 "--board", BOARD, "-o", str(out), "--no-html"] + extra
                if case != "topics" else
                ["calibrate", "stereo", "--board", BOARD, "-o", str(out)] + extra)
    err = capsys.readouterr().err
    assert code == 1 and expect in err, err
    assert len([ln for ln in err.splitlines() if ln.startswith("eye-in-hand: error:")]) == 1
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if ".partial-" in p.name] == []


def test_a_board_given_in_squares_stops_early_with_the_fix(data_dir, tmp_path, capsys):
    out = tmp_path / "rig"
    images = data_dir / "opencv_stereo_chessboard"
    assert main(["calibrate", "stereo", "--left", str(images / "left*.jpg"),
                 "--right", str(images / "right*.jpg"), "--board", "chessboard:10x7:1.0",
                 "-o", str(out)]) != 0
    err = capsys.readouterr().err
    assert ("no board chessboard:10x7:1 found in the first 8 left images; a 9x6 chessboard "
            "(inner corners) is found in 8 of them") in err
    assert not out.exists()
