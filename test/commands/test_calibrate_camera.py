"""``eye-in-hand calibrate camera``: outputs, bag input, bad input leaves nothing behind."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.core.camera import CameraModel

BOARD = "chessboard:9x6:1.0"


def _images(data_dir: Path) -> Path:
    return data_dir / "opencv_stereo_chessboard"


def _leftovers(parent: Path) -> list[str]:
    return [p.name for p in parent.iterdir() if ".partial-" in p.name]


def write_image_bag(path: Path, topics: dict[str, list[tuple[int, np.ndarray]]]) -> None:
    """A bag of mono8 sensor_msgs/Image messages: {topic: [(header stamp ns, image)]}."""
    from eye_in_hand.io.bags import BagWriter, default_typestore

    store = default_typestore()
    Image = store.types["sensor_msgs/msg/Image"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    msgs = []
    for topic, frames in topics.items():
        for stamp, img in frames:
            msg = Image(header=Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9),
                                      frame_id="cam"),
                        height=img.shape[0], width=img.shape[1], encoding="mono8",
                        is_bigendian=0, step=img.shape[1], data=img.ravel().copy())
            msgs.append((stamp, topic, msg))
    with BagWriter(path) as bag:
        for topic in topics:
            bag.add_topic(topic, "sensor_msgs/msg/Image")
        for stamp, topic, msg in sorted(msgs, key=lambda m: (m[0], m[1])):
            bag.write(topic, stamp, msg)


def test_camera_from_files(data_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    images = tmp_path / "imgs"
    images.mkdir()
    for f in sorted(_images(data_dir).glob("left*.jpg")):
        shutil.copy(f, images / f.name)
    # an image without a board: listed with its reason and skipped
    blank = np.full((480, 640), 128, np.uint8)
    import cv2

    cv2.imwrite(str(images / "left99.png"), blank)
    code = main(["calibrate", "camera", "--images", str(images / "left*"), "--board", BOARD,
                 "-o", str(out), "--detector", "classic"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "skipped left99.png: no 9x6 chessboard found" in captured.err
    assert sorted(p.name for p in out.iterdir()) == ["camera.yaml", "report.html", "report.json"]
    report = json.loads((out / "report.json").read_text())
    cam = report["camera"]
    # OpenCV's recipe fits these images at 0.1963 px; the default saddle-point corners at 0.1668
    # (test/core/test_calibration_opencv_data.py checks both)
    assert abs(cam["rms_px"] - 0.1668) < 0.01
    assert np.array(cam["K"]).shape == (3, 3) and len(cam["dist"]) == 5
    views = report["views"]
    assert len(views) == 14 and sum(v["used"] for v in views) == 13
    missing = [v for v in views if not v["found"]]
    assert [v["file"] for v in missing] == ["left99.png"] and "chessboard" in missing[0]["reason"]
    assert report["input"]["skipped"][0]["file"] == "left99.png"
    model = CameraModel.load_yaml(out / "camera.yaml")
    np.testing.assert_allclose(model.K, cam["K"])
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 4 and "<script" not in html
    assert "left99.png" in html
    assert _leftovers(tmp_path) == []


def test_camera_from_bag_every_second_frame(data_dir: Path, tmp_path: Path, capsys) -> None:
    import cv2

    files = sorted(_images(data_dir).glob("left*.jpg"))
    frames = [(10**9 + k * 10**8, cv2.imread(str(f), cv2.IMREAD_GRAYSCALE))
              for k, f in enumerate(files)]
    write_image_bag(tmp_path / "bag", {"/left/image_raw": frames})
    out = tmp_path / "out"
    code = main(["calibrate", "camera", "--bag", str(tmp_path / "bag"), "--left-topic",
                 "/left/image_raw", "--every", "2", "--board", BOARD, "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    report = json.loads((out / "report.json").read_text())
    assert [v["file"] for v in report["views"]] == [
        f"/left/image_raw@{s}" for s, _ in frames[::2]]
    assert report["camera"]["rms_px"] < 0.3


@pytest.mark.parametrize("case", ["board", "unreadable", "few", "size", "nomatch", "topic"])
def test_camera_bad_input_writes_nothing(case: str, data_dir: Path, tmp_path: Path,
                                         capsys) -> None:
    import cv2

    images = tmp_path / "imgs"
    images.mkdir()
    files = sorted(_images(data_dir).glob("left*.jpg"))[:6]
    for f in files:
        shutil.copy(f, images / f.name)
    board = BOARD
    extra: list[str] = []
    expect = ""
    if case == "board":
        board, expect = "chessboard:9x6", "board spec 'chessboard:9x6'"
    elif case == "unreadable":
        (images / "left50.jpg").write_text("not an image")
        expect = "left50.jpg: not a readable image file"
    elif case == "few":
        extra, expect = ["--min-views", "8"], "only 6 usable board view(s) of 6 image(s)"
    elif case == "size":
        img = cv2.imread(str(files[0]))
        cv2.imwrite(str(images / "left50.jpg"), cv2.resize(img, (320, 240)))
        expect = "images differ in size"
    elif case == "nomatch":
        images = tmp_path / "nothing"
        expect = "no image files match"
    elif case == "topic":
        write_image_bag(tmp_path / "bag", {"/cam/image": [(1, np.zeros((4, 4), np.uint8))]})
        expect = "lacks topic /left/image_raw"
    out = tmp_path / "out"
    argv = ["calibrate", "camera", "--board", board, "-o", str(out)] + extra
    argv += (["--bag", str(tmp_path / "bag"), "--left-topic", "/left/image_raw"]
             if case == "topic" else ["--images", str(images / "*.jpg")])
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 1
    assert expect in err, err
    lines = [line for line in err.splitlines() if line.startswith("eye-in-hand: error:")]
    assert len(lines) == 1 and "Traceback" not in err
    assert not out.exists() and _leftovers(tmp_path) == []


def test_existing_output_folder_refused_then_replaced_whole(data_dir: Path, tmp_path: Path,
                                                            capsys) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "camera.yaml").write_text("old")
    argv = ["calibrate", "camera", "--images", str(_images(data_dir) / "left0*.jpg"),
            "--board", BOARD, "-o", str(out), "--no-html", "--reject-outliers"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already" in err and "--overwrite" in err, err
    assert (out / "camera.yaml").read_text() == "old"  # untouched
    assert main(argv + ["--overwrite"]) == 0
    assert "camera_matrix" in (out / "camera.yaml").read_text()
    # replaced whole: nothing of the old folder is left beside the new files
    assert sorted(p.name for p in out.iterdir()) == ["camera.yaml", "report.json"]
    assert _leftovers(tmp_path) == []


def test_camera_from_compressed_bag_and_wrong_topic_type(data_dir: Path, tmp_path: Path,
                                                         capsys) -> None:
    from eye_in_hand.io.bags import BagWriter, default_typestore

    store = default_typestore()
    Compressed = store.types["sensor_msgs/msg/CompressedImage"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    String = store.types["std_msgs/msg/String"]
    with BagWriter(tmp_path / "bag") as bag:
        bag.add_topic("/cam/image/compressed", "sensor_msgs/msg/CompressedImage")
        bag.add_topic("/chatter", "std_msgs/msg/String")
        for k, f in enumerate(sorted(_images(data_dir).glob("left*.jpg"))[:7]):
            data = np.frombuffer(f.read_bytes(), np.uint8)
            stamp = 10**9 + k * 10**8
            bag.write("/cam/image/compressed", stamp, Compressed(
                header=Header(stamp=Time(sec=1, nanosec=k * 10**8), frame_id="cam"),
                format="mono8; jpeg compressed mono8", data=data))
        bag.write("/chatter", 5 * 10**9, String(data="hi"))
    out = tmp_path / "out"
    code = main(["calibrate", "camera", "--bag", str(tmp_path / "bag"), "--left-topic",
                 "/cam/image/compressed", "--board", BOARD, "-o", str(out), "--no-html"])
    assert code == 0, capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert sum(v["used"] for v in report["views"]) == 7
    assert report["views"][0]["file"] == "/cam/image/compressed@1000000000"
    code = main(["calibrate", "camera", "--bag", str(tmp_path / "bag"), "--left-topic", "/chatter",
                 "--board", BOARD, "-o", str(tmp_path / "out2")])
    err = capsys.readouterr().err
    assert code == 1 and "topic /chatter has type std_msgs/msg/String" in err
    assert not (tmp_path / "out2").exists()


def test_atomic_output_dir_leaves_nothing_on_failure(tmp_path: Path) -> None:
    from eye_in_hand.commands.calibrate_camera import atomic_output_dir

    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_output_dir(out) as tmp:
            (tmp / "camera.yaml").write_text("partial")
            raise RuntimeError("boom")
    assert not out.exists() and list(tmp_path.iterdir()) == []
    out.mkdir()
    (out / "keep.txt").write_text("x")
    with pytest.raises(RuntimeError):
        with atomic_output_dir(out, overwrite=True) as tmp:
            (tmp / "camera.yaml").write_text("partial")
            raise RuntimeError("boom")
    assert [p.name for p in out.iterdir()] == ["keep.txt"] and len(list(tmp_path.iterdir())) == 1
    with atomic_output_dir(out, overwrite=True) as tmp:
        (tmp / "camera.yaml").write_text("done")
    assert sorted(p.name for p in out.iterdir()) == ["camera.yaml"]


def test_new_output_folder_gets_normal_permissions(tmp_path: Path) -> None:
    import os

    from eye_in_hand.commands.calibrate_camera import atomic_output_dir

    umask = os.umask(0o022)
    try:
        with atomic_output_dir(tmp_path / "new") as tmp:
            (tmp / "a.txt").write_text("x")
    finally:
        os.umask(umask)
    assert (tmp_path / "new").stat().st_mode & 0o777 == 0o755


def test_a_board_square_in_millimetres_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "cam"
    assert main(["calibrate", "camera", "--images", str(tmp_path / "*.png"),
                 "--board", "chessboard:9x6:25", "-o", str(out)]) != 0
    err = capsys.readouterr().err
    assert "pass 'chessboard:9x6:0.025'" in err and not out.exists()


def test_a_board_given_in_squares_stops_early_with_the_fix(data_dir, tmp_path, capsys):
    """The trap: `10x7` (squares) for a 9x6 board printed a "skipped" line per image and
    failed at the end with no hint."""
    out = tmp_path / "cam"
    assert main(["calibrate", "camera", "--images", str(_images(data_dir) / "left*.jpg"),
                 "--board", "chessboard:10x7:1.0", "-o", str(out)]) != 0
    err = capsys.readouterr().err
    assert ("no board chessboard:10x7:1 found in the first 8 camera images; a 9x6 chessboard "
            "(inner corners) is found in 8 of them") in err
    assert "Pass --board chessboard:9x6:1" in err
    assert "skipped" not in err and not out.exists()
