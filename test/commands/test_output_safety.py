"""Fault suite of the commands: nothing lost, nothing stale, nothing overwritten.

- an existing output is refused (one line naming it and ``--overwrite``); ``--overwrite``
  replaces it whole;
- ``kill -9`` of ``process`` at several moments of its writing leaves the old output or
  nothing, never something that looks done, and a rerun is not blocked;
- a full disk (ENOSPC) is one line naming the file, the old output kept;
- non-UTF-8 file names and file contents, and invalid topic names, are one-line errors or
  just work (no segmentation fault, no traceback);
- a bag's message type never imports an arbitrary Python package.
"""
from __future__ import annotations

import csv
import errno
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.io.bags import bag_info

ROOT = Path(__file__).resolve().parents[2]
NON_UTF8 = os.fsdecode(b"caf\xe9")  # Latin-1 "cafe" with an accent: not valid UTF-8


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def _one_line_error(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("eye-in-hand: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def pairs(data_dir, tmp_path) -> Path:
    """Six robot/board pose pairs of the bundled MoveIt eye-to-hand data (fast to calibrate)."""
    path = tmp_path.parent / f"{tmp_path.name}_pairs.json"
    data = json.loads((data_dir / "moveit_eye_to_hand" / "pose_samples.json").read_text())
    path.write_text(json.dumps(data[:6]))
    return path


# ------------------------------------------------------------------------------------------------
# overwrite
# ------------------------------------------------------------------------------------------------
def test_calibrate_handeye_refuses_then_replaces_whole(pairs, tmp_path, capsys) -> None:
    out = tmp_path / "he"
    argv = ["calibrate", "handeye", "--pairs", str(pairs), "--setup",
            "eye_to_hand", "-o", str(out)]
    assert main(argv) == 0
    assert {p.name for p in out.iterdir()} == {"hand_eye.yaml", "report.json", "report.html"}
    before = _tree(out)
    capsys.readouterr()
    assert main(argv + ["--no-html"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert f"-o {out}: exists already" in line and "--overwrite" in line
    assert _tree(out) == before
    # never replace the folder that holds the input, even with --overwrite
    inside = out / "pairs.json"
    inside.write_bytes(pairs.read_bytes())
    assert main(["calibrate", "handeye", "--pairs", str(inside), "--setup", "eye_to_hand", "-o",
                 str(out), "--overwrite"]) == 1
    assert "holds the input" in _one_line_error(capsys.readouterr().err)
    inside.unlink()
    assert main(argv + ["--no-html", "--overwrite"]) == 0
    # replaced whole: the old report.html does not stay beside the new hand_eye.yaml
    assert {p.name for p in out.iterdir()} == {"hand_eye.yaml", "report.json"}
    assert [p.name for p in tmp_path.iterdir()] == ["he"]


def test_simulate_refuses_then_replaces_whole(tmp_path, capsys) -> None:
    out = tmp_path / "ds"
    argv = ["simulate", "--scenario", "calibration", "--format", "dataset", "--frames", "1",
            "--size", "160x120", "--supersample", "1", "-o", str(out), "--quiet"]
    assert main(argv) == 0
    (out / "mine.txt").write_text("notes")
    capsys.readouterr()
    assert main(argv) == 1
    assert "-o " in _one_line_error(capsys.readouterr().err)
    assert (out / "mine.txt").exists()
    assert main(argv + ["--overwrite"]) == 0
    assert not (out / "mine.txt").exists() and (out / "dataset.yaml").is_file()


def test_record_refuses_an_existing_bag(tmp_path, capsys) -> None:
    out = tmp_path / "bag"
    out.mkdir()
    (out / "metadata.yaml").write_text("earlier recording")
    assert main(["record", "-o", str(out), "/chatter", "-d", "0.1"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "exists already" in line and "--overwrite" in line
    assert (out / "metadata.yaml").read_text() == "earlier recording"


# ------------------------------------------------------------------------------------------------
# kill -9 while process writes
# ------------------------------------------------------------------------------------------------
_KILLER = r"""
import os, signal, sys
point, nth = sys.argv[1], int(sys.argv[2])
calls = [0]

def trip():
    calls[0] += 1
    if calls[0] == nth:
        os.kill(os.getpid(), signal.SIGKILL)

import eye_in_hand.io.atomic as atomic
if point == "bag-message":
    from eye_in_hand.io.bags import BagWriter
    real_write = BagWriter.write
    def write(self, *a, **k):
        trip()
        return real_write(self, *a, **k)
    BagWriter.write = write
elif point == "csv-row":  # results.csv cut at a row boundary
    import csv
    real_writer = csv.writer
    class Rows:
        def __init__(self, fh, *a, **k):
            self.fh, self.w = fh, real_writer(fh, *a, **k)
        def writerow(self, row):
            trip()
            self.w.writerow(row)
            self.fh.flush()
    csv.writer = Rows
elif point == "fsync":
    real_fsync = os.fsync
    def fsync(fd):
        trip()
        return real_fsync(fd)
    os.fsync = fsync
elif point in ("before-swap", "after-swap"):
    real_exchange = atomic._exchange
    def exchange(a, b):
        if point == "before-swap":
            trip()
        done = real_exchange(a, b)
        if point == "after-swap":
            trip()
        return done
    atomic._exchange = exchange
from eye_in_hand.cli import main
sys.exit(main(sys.argv[3:]))
"""


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
    from eye_in_hand.sim import World
    from eye_in_hand.sim.output import RenderOptions, write_bag

    root = tmp_path_factory.mktemp("proc")
    world = World.default().with_image_size(320, 180)
    write_bag(world, root / "loc", scenario="localization", frames=6, seed=1,
              render=RenderOptions(supersample=1))
    save_hand_eye(root / "hand_eye.yaml", HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth"))
    return root / "loc", root / "hand_eye.yaml"


def _complete(out: Path) -> bool:
    """A finished process output: summary.json, every row in results.csv, a readable bag."""
    summary = json.loads((out / "summary.json").read_text())
    rows = list(csv.DictReader((out / "results.csv").open()))
    return len(rows) == summary["counts"]["pairs"] == 6 and "/target/pose" in bag_info(out).topics


@pytest.mark.parametrize("point,nth,old", [
    ("bag-message", 4, False),  # mid-bag, first run
    ("csv-row", 4, True),       # results.csv half written, over an earlier result
    ("before-swap", 1, True),   # complete, about to be renamed into place
    ("after-swap", 1, True),    # renamed into place, the old one not yet deleted
])
def test_kill_9_leaves_the_old_output_or_nothing(small_bag, tmp_path, ros_env, point, nth,
                                                 old) -> None:
    bag, hand_eye = small_bag
    out = tmp_path / "out"
    if old:
        out.mkdir()
        (out / "results.csv").write_text("stamp_ns,status\n1,earlier\n")
        (out / "summary.json").write_text('{"earlier": true}')
    before = _tree(out) if old else None
    argv = ["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
            "--workers", "1", "--overwrite"]
    res = subprocess.run([sys.executable, "-c", _KILLER, point, str(nth), *argv],
                         env=ros_env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == -signal.SIGKILL, res.stderr  # it really died at that point
    if point == "after-swap":
        assert _complete(out)  # the new output, whole
    elif old:
        assert _tree(out) == before  # the old output, untouched
    else:
        assert not out.exists()  # nothing that looks done
    partial = [p.name for p in tmp_path.iterdir() if ".partial-" in p.name]
    assert len(partial) == 1 and partial[0].startswith(".out.partial-")  # recognisable
    # a rerun is not blocked (no --overwrite needed where nothing was there), and cleans up
    assert main(argv if old else argv[:-1]) == 0
    assert _complete(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


# ------------------------------------------------------------------------------------------------
# full disk
# ------------------------------------------------------------------------------------------------
def test_full_disk_while_flushing_keeps_the_old_output(small_bag, tmp_path, capsys,
                                                      monkeypatch) -> None:
    bag, hand_eye = small_bag
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"earlier": true}')

    def fsync(fd):  # delayed allocation: the disk turns out full when the data is flushed
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", fsync)
    assert main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                 "--workers", "1", "--overwrite"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert line.endswith(f": cannot write (No space left on device); the earlier {out} is "
                         "unchanged") and f"{out}/" in line
    assert _tree(out) == {"summary.json": b'{"earlier": true}'}
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_full_disk_keeps_the_old_calibration(pairs, tmp_path, capsys, monkeypatch) -> None:
    out = tmp_path / "he"
    argv = ["calibrate", "handeye", "--pairs", str(pairs), "--setup",
            "eye_to_hand", "-o", str(out), "--no-html"]
    assert main(argv) == 0
    before = _tree(out)
    real_write_text = Path.write_text

    def full(self, *args, **kwargs):
        if self.name == "report.json":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real_write_text(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full)
    capsys.readouterr()
    assert main(argv + ["--overwrite"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert line == (f"eye-in-hand: error: {out / 'report.json'}: cannot write (No space left on "
                    f"device); the earlier {out} is unchanged")
    assert _tree(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["he"]


# ------------------------------------------------------------------------------------------------
# non-UTF-8 names and contents
# ------------------------------------------------------------------------------------------------
_NON_UTF8_RUN = r"""
import os, sys
from eye_in_hand.cli import main
ds = os.fsdecode(b"caf\xe9")
codes = [main(["simulate", "--scenario", "calibration", "--format", "dataset", "--frames", "3",
               "--size", "320x240", "--supersample", "1", "-o", ds, "--quiet"]),
         main(["calibrate", "handeye", ds, "-o", ds + "_he", "--no-html"]),
         main(["tune-color", os.path.join(ds, "left", "0000.png"), "--roi", "10,10,8,8"])]
imgs = os.fsdecode(b"imgs")
os.mkdir(imgs)
for name in sorted(os.listdir(os.path.join(ds, "left"))):  # non-UTF-8 file names too
    os.link(os.path.join(ds, "left", name), os.path.join(imgs, name[:-4] + ds + ".png"))
codes.append(main(["calibrate", "camera", "--images", imgs, "--board", "chessboard:9x6:0.025",
                   "--min-views", "3", "-o", ds + "_cam"]))  # with report.html
print("codes", codes)
"""


def test_non_utf8_file_names_work(tmp_path, ros_env) -> None:
    """simulate, calibrate handeye (OpenCV image I/O) and tune-color with a non-UTF-8 folder
    name: no segmentation fault (a child process, so that one would not end the suite), and
    the name printed with the odd byte as \\xe9."""
    res = subprocess.run([sys.executable, "-c", _NON_UTF8_RUN], cwd=tmp_path, env=ros_env,
                         capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, (res.returncode, res.stderr[-2000:])
    assert "Traceback" not in res.stderr
    assert res.stdout.splitlines()[-1] == "codes [0, 0, 0, 0]", res.stdout + res.stderr
    assert "wrote calibration dataset caf\\xe9/dataset.yaml" in res.stdout
    he = tmp_path / (NON_UTF8 + "_he")
    assert (he / "hand_eye.yaml").is_file()
    report = json.loads((tmp_path / (NON_UTF8 + "_cam") / "report.json").read_text())
    assert report["views"][0]["file"] == "0000caf\\xe9.png"
    assert (tmp_path / (NON_UTF8 + "_cam") / "report.html").is_file()


def test_non_utf8_missing_image_is_one_line(tmp_path, capsys) -> None:
    missing = tmp_path / (NON_UTF8 + ".png")
    assert main(["tune-color", str(missing), "--roi", "0,0,4,4"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "caf\\xe9.png: cannot read" in line  # the odd byte shown, not a crash


def test_non_utf8_yaml_is_one_line_naming_the_file(small_bag, tmp_path, capsys) -> None:
    bag, _ = small_bag
    bad = tmp_path / "hand_eye.yaml"
    bad.write_bytes(b"setup: eye_in_hand\nparent_frame: t\xe9ol0\n")
    assert main(["process", str(bag), "--hand-eye", str(bad), "-o", str(tmp_path / "o")]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert f"{bad}: hand-eye calibration file is not UTF-8 text (byte 0xe9 at offset 34)" in line
    world = tmp_path / "world.yaml"
    world.write_bytes(b"\xff\xfe")
    assert main(["simulate", "--scenario", "calibration", "--world", str(world), "-o",
                 str(tmp_path / "s")]) == 1
    assert "world.yaml: world file is not UTF-8 text" in _one_line_error(capsys.readouterr().err)
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "dataset.yaml").write_bytes(b"board: \xff\n")
    assert main(["calibrate", "handeye", str(ds), "-o", str(tmp_path / "he")]) == 1
    assert "dataset.yaml" in _one_line_error(capsys.readouterr().err)
    assert not (tmp_path / "o").exists() and not (tmp_path / "he").exists()


def test_invalid_topic_names_are_one_line(tmp_path, capsys) -> None:
    assert main(["echo", "bad topic!", "--timeout", "0.1"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "echo TOPIC 'bad topic!': not a valid topic name" in line
    assert main(["record", "-o", str(tmp_path / "r"), "/ok", "/2fast", "-d", "0.1"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "record TOPIC '/2fast': not a valid topic name (token must not start with a " \
           "number)" in line
    assert not (tmp_path / "r").exists()
    assert main(["launch", "--namespace", "robot 1", "--duration", "1"]) == 1
    assert "--namespace 'robot 1': not a valid namespace" in _one_line_error(
        capsys.readouterr().err)


def test_non_utf8_names_passed_to_ros_nodes_are_one_line(tmp_path, capsys) -> None:
    """A ROS parameter or argument is UTF-8 text: a non-UTF-8 bag or parameter file name is
    refused with one line instead of a traceback inside rclpy."""
    odd = tmp_path / NON_UTF8
    assert main(["record", "-o", str(odd), "/chatter", "-d", "0.1"]) == 1
    assert "-o '" in _one_line_error(capsys.readouterr().err)
    from eye_in_hand.io.bags import BagWriter

    with BagWriter(odd):
        pass
    assert main(["play", str(odd)]) == 1
    assert "caf\\xe9': not UTF-8 text" in _one_line_error(capsys.readouterr().err)
    params = tmp_path / (NON_UTF8 + ".yaml")
    params.write_text("/**/hand_eye:\n  ros__parameters: {}\n")
    assert main(["launch", "--params", str(params), "--duration", "1"]) == 1
    assert "--params '" in _one_line_error(capsys.readouterr().err)


def test_recorder_node_names_an_invalid_topic_parameter(tmp_path, ros_context) -> None:
    pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from eye_in_hand.errors import ConfigError
    from eye_in_hand.nodes.bag_recorder import BagRecorder

    with pytest.raises(ConfigError, match=r"parameter 'topics': '/a/' is not a valid topic name "
                                          r"\(must not end with a forward slash\)"):
        BagRecorder(context=ros_context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "bag")),
            Parameter("topics", Parameter.Type.STRING_ARRAY, ["/ok", "/a/"])])
    assert not (tmp_path / "bag").exists()


def test_launch_refuses_a_bad_parameter_file_before_starting_nodes(tmp_path, capsys) -> None:
    bad = tmp_path / "params.yaml"
    bad.write_bytes(b"hand_eye:\n  ros__parameters: {output_dir: \xff}\n")
    assert main(["launch", "--params", str(bad), "--duration", "1"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert f"{bad}: parameter file is not UTF-8 text (byte 0xff at offset 42)" in line
    bad.write_text("hand_eye: [1, 2")
    assert main(["launch", "--params", str(bad), "--duration", "1"]) == 1
    assert "params.yaml: not valid YAML" in _one_line_error(capsys.readouterr().err)


# ------------------------------------------------------------------------------------------------
# message types named by a bag
# ------------------------------------------------------------------------------------------------
def _planted_packages(root: Path) -> Path:
    """Two packages whose import would leave a marker file: one plain, one that looks like an
    interface package (a ``msg`` subpackage) but was not generated by rosidl."""
    for name in ("evilpkg", "fake_msgs"):
        pkg = root / name
        (pkg / "msg").mkdir(parents=True)
        code = f"open({str(root / (name + '.imported'))!r}, 'w').write('x')\n"
        (pkg / "__init__.py").write_text(code)
        (pkg / "msg" / "__init__.py").write_text(code + "class Foo:\n    _TYPE_SUPPORT = 1\n")
    return root


def test_message_types_import_only_interface_packages(tmp_path, monkeypatch) -> None:
    from eye_in_hand.ros.msgtypes import import_message_type, valid_msgtype

    pytest.importorskip("sensor_msgs")
    root = _planted_packages(tmp_path)
    monkeypatch.syspath_prepend(str(root))
    for name in ("evilpkg/msg/Foo", "fake_msgs/msg/Foo", "this/msg/Foo", "os/msg/Path",
                 "evilpkg/Foo", "sensor_msgs/msg/image", "sensor_msgs/srv/Image",
                 "sensor_msgs/msg/Image/x", "../x/msg/Foo"):
        assert import_message_type(name) is None, name
    assert not list(root.glob("*.imported"))  # nothing of them ran
    from sensor_msgs.msg import Image

    assert import_message_type("sensor_msgs/msg/Image") is Image
    assert valid_msgtype("sensor_msgs/Image") and not valid_msgtype("evil pkg/msg/Foo")


def test_play_skips_planted_types_and_invalid_topic_names(tmp_path, ros_context, namespace,
                                                          monkeypatch) -> None:
    pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from eye_in_hand.io.bags import BagWriter, default_typestore, serialize
    from eye_in_hand.nodes.bag_player import BagPlayer

    root = _planted_packages(tmp_path / "pkgs")
    monkeypatch.syspath_prepend(str(root))
    s = default_typestore().types
    with BagWriter(tmp_path / "bag") as bag:
        bag.add_topic(f"{namespace}/ok", "std_msgs/msg/String")
        bag.add_topic(f"{namespace}/evil", "evilpkg/msg/Foo", msgdef="string data\n")
        bag.add_topic(f"{namespace}/fake", "fake_msgs/msg/Foo", msgdef="string data\n")
        bag.add_topic(f"{namespace}/bad name", "std_msgs/msg/String")
        raw = serialize(s["std_msgs/msg/String"](data="x"), "std_msgs/msg/String")
        for topic in ("ok", "evil", "fake", "bad name"):
            bag.write(f"{namespace}/{topic}", 1_000, raw)
    player = BagPlayer(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(tmp_path / "bag"))])
    try:
        assert set(player.skipped_types) == {f"{namespace}/evil", f"{namespace}/fake",
                                             f"{namespace}/bad name"}
        assert set(player.published) == {f"{namespace}/ok"}
    finally:
        player.destroy_node()
    assert not list(root.glob("*.imported"))


def test_images_read_through_bytes(tmp_path) -> None:
    from eye_in_hand.io.images import read_image_file, write_image_file

    img = np.arange(48, dtype=np.uint8).reshape(4, 4, 3)
    path = tmp_path / (NON_UTF8 + ".png")
    write_image_file(path, img)
    assert np.array_equal(read_image_file(path), img)
    (tmp_path / "junk.png").write_bytes(b"not an image")
    from eye_in_hand.errors import InputError

    with pytest.raises(InputError, match="junk.png: not a readable image file"):
        read_image_file(tmp_path / "junk.png")
