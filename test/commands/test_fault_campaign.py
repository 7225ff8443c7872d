"""The fault campaign of the reliability page, as tests: one test per case that once ended in a
hang, a traceback or a misreported loss. Each must end within seconds with one line (or an
exact loss report) and no traceback."""
from __future__ import annotations

import subprocess
import sys

import pytest

from eye_in_hand.cli import main


def _one_line_error(err: str) -> str:
    """The one error line of ``err`` (progress bars aside)."""
    lines = [line for line in err.replace("\r", "\n").splitlines()
             if line.strip() and "%|" not in line]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith("eye-in-hand: error: "), err
    return lines[0]


def test_process_refuses_a_huge_worker_count_at_once(tmp_path, capsys):
    for bad in ("100000000", "0", "-3", "nan"):
        with pytest.raises(SystemExit) as exit_info:
            main(["process", str(tmp_path / "no_bag"), "--hand-eye", "x", "-o",
                  str(tmp_path / "o"), "--workers", bad])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert err.splitlines() == [
            "eye-in-hand process: error: argument --workers: " + (
                f"must be an integer within [1, 64], got {bad}" if bad != "nan" else
                "expected an integer, got 'nan'") + " (see eye-in-hand process --help)"], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("text,reason", [
    ("/**/detect_triangulate:\n  ros__parameters:\n    a: &x 5.0\n    b: *x\n",
     "Will not support aliasing at line 4"),
    ("common: &c\n  rate: 5.0\n/**/hand_eye:\n  ros__parameters:\n    <<: *c\n",
     "Cannot have a value before ros__parameters at line 2"),
    ("/**/hand_eye:\n  ros__parameters:\n    a: [1, two, 3.0]\n",
     "Sequence should be of same type"),
])
def test_launch_refuses_a_parameter_file_rcl_cannot_parse(tmp_path, capsys, text, reason):
    """Valid YAML that rcl's parser refuses (anchors, aliases, mixed arrays) is refused before
    any node starts, with rcl's own reason, instead of a crash-looping launch."""
    params = tmp_path / "params.yaml"
    params.write_text(text)
    assert main(["launch", "--params", str(params), "--duration", "1"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert line.startswith(f"eye-in-hand: error: {params}: rcl cannot parse this parameter "
                           "file: "), line
    assert reason in line


def test_launch_accepts_the_shipped_parameter_file():
    from eye_in_hand.launcher import default_params_file
    from eye_in_hand.ros.params import check_parameter_file

    check_parameter_file(default_params_file())   # raises on a file rcl refuses


@pytest.mark.parametrize("command", ["echo", "record"])
def test_a_5000_character_topic_name_is_one_line(tmp_path, capsys, command):
    topic = "/" + "a" * 5000
    argv = (["echo", topic, "--timeout", "0.1"] if command == "echo" else
            ["record", "-o", str(tmp_path / "r"), topic, "-d", "0.1"])
    assert main(argv) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "not a valid topic name (5001 characters as a full name; ROS allows at most 247)" \
        in line
    assert len(line) < 250
    assert not (tmp_path / "r").exists()
    # the longest allowed name is accepted by the check
    from eye_in_hand.ros.names import topic_name_problem

    assert topic_name_problem("/" + "a" * 246) is None
    assert topic_name_problem("a" * 246) is None
    assert topic_name_problem("a" * 247) is not None


@pytest.mark.parametrize("ns,reason", [
    ("//bad", "must not contain repeated '/'"),
    ("/bad/", "must not end with a '/'"),
    ("/" + "n" * 200, "at most 183"),
])
def test_launch_refuses_an_invalid_namespace(capsys, ns, reason):
    assert main(["launch", "--namespace", ns, "--duration", "1"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "not a valid namespace" in line and reason in line, line


# ------------------------------------------------------------------------------------------------
# disk full (a file-size limit, as `ulimit -f`: the system answers EFBIG where a disk says ENOSPC)
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
    from eye_in_hand.sim import World
    from eye_in_hand.sim.output import RenderOptions, write_bag

    root = tmp_path_factory.mktemp("campaign")
    world = World.default().with_image_size(320, 180)
    write_bag(world, root / "loc", scenario="localization", frames=6, seed=1,
              render=RenderOptions(supersample=1))
    save_hand_eye(root / "hand_eye.yaml", HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth"))
    return root / "loc", root / "hand_eye.yaml"


def _limited(argv: list[str], limit: int) -> subprocess.CompletedProcess:
    """``eye-in-hand ARGV`` in a child whose files may not grow beyond ``limit`` bytes."""
    code = ("import resource, sys\n"
            f"resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))\n"
            "from eye_in_hand.cli import main\n"
            f"sys.exit(main({argv!r}))\n")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)


@pytest.mark.parametrize("case", ["process-mcap", "process-sqlite3", "simulate",
                                  "calibrate-camera"])
def test_a_full_disk_names_the_final_output_and_keeps_the_earlier_one(small_bag, tmp_path,
                                                                       case, data_dir):
    bag, hand_eye = small_bag
    out = tmp_path / "out"
    out.mkdir()
    (out / "earlier.txt").write_text("the earlier result\n")
    if case.startswith("process"):
        argv = ["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                "--workers", "1", "--overwrite", "--storage", case.split("-")[1]]
    elif case == "simulate":
        argv = ["simulate", "--scenario", "localization", "--frames", "2", "--size", "320x180",
                "--supersample", "1", "-o", str(out), "--overwrite", "--quiet"]
    else:   # the report's plots are larger than the limit
        argv = ["calibrate", "camera", "--images",
                str(data_dir / "opencv_stereo_chessboard" / "left*"), "--board",
                "chessboard:9x6:1.0", "-o", str(out), "--overwrite", "--detector", "classic"]
    proc = _limited(argv, 4096)
    assert proc.returncode == 1, proc.stderr
    line = _one_line_error(proc.stderr)
    # sqlite3 does not say which of the two it met
    reason = "database or disk is full" if case.endswith("sqlite3") else "File too large"
    assert line.endswith(f": cannot write ({reason}); the earlier {out} is unchanged"), line
    assert f"{out}/" in line and ".partial-" not in line and "Errno" not in line, line
    assert (out / "earlier.txt").read_text() == "the earlier result\n"
    assert sorted(p.name for p in out.iterdir()) == ["earlier.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


# ------------------------------------------------------------------------------------------------
# exact loss accounting
# ------------------------------------------------------------------------------------------------
def _summary(out) -> dict:
    import json

    return json.loads((out / "summary.json").read_text())


def test_repeated_stamps_are_in_the_one_loss_total(small_bag, tmp_path, capsys):
    """A replay right after a run: images whose stamp is not after their side's previous one
    are dropped as stale_stamp, and counted in the loss total that the summary shows."""
    from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages

    bag, hand_eye = small_bag
    replay = tmp_path / "replay"
    info = bag_info(bag)
    repeated = 0
    with BagWriter(replay, "mcap") as out:
        for t in info.topics.values():
            out.add_topic(t.name, t.msgtype)
        for topic, _type, t_ns, raw in iter_messages(bag):
            out.write(topic, t_ns, raw)
            if topic == "/stereo/left/image_raw" and repeated < 3:   # sent twice
                out.write(topic, t_ns + 1, raw)
                repeated += 1
    assert main(["process", str(replay), "--hand-eye", str(hand_eye), "-o", str(tmp_path / "o"),
                 "--quiet", "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    s = _summary(tmp_path / "o")
    c, loss = s["counts"], s["loss"]
    assert loss["of_which_stale_stamp"] == 3 == c["stale_stamp"]
    assert loss["by_cause"]["unpaired_left"] == 3
    assert loss["total"] == c["lost"] == sum(v for v in loss["by_cause"].values())
    # every left image is a result or a loss
    assert c["left_frames"] == c["localized"] + c["no_target"] + loss["total"]
    assert "losses: 3 in total: 3 left and 0 right images without a partner (3 of them with " \
           "a stamp not after the previous one: stale_stamp)" in printed


def test_a_run_that_locates_nothing_exits_3_with_the_reasons(small_bag, tmp_path, capsys):
    bag, hand_eye = small_bag
    params = tmp_path / "params.yaml"
    params.write_text("/**/detect_triangulate:\n  ros__parameters:\n    target_names: [green]\n"
                      "    targets:\n      green:\n        color_space: hsv\n"
                      "        lower: [55, 250, 250]\n        upper: [56, 255, 255]\n"
                      "        radius_m: 0.035\n")
    out = tmp_path / "o"
    assert main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                 "--workers", "1", "--params", str(params)]) == 3
    err = capsys.readouterr().err
    assert "Traceback" not in err
    line = [x for x in err.splitlines() if x.startswith("eye-in-hand: error:")]
    assert line == [f"eye-in-hand: error: nothing located in the base frame in {bag}: 6 stereo "
                    "pairs, 6 without target"], err
    assert _summary(out)["counts"]["localized"] == 0     # the outputs say so too


def test_a_calibration_of_another_resolution_is_refused_before_the_work(small_bag, tmp_path,
                                                                         capsys):
    from eye_in_hand.sim import World

    bag, hand_eye = small_bag
    World.default().with_image_size(640, 360).rig.save(tmp_path / "calib")
    out = tmp_path / "o"
    assert main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                 "--calibration", str(tmp_path / "calib")]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert line.startswith(f"eye-in-hand: error: {tmp_path / 'calib' / 'left.yaml'}: "
                           "image_width x image_height 640x360 disagrees with the bag's "
                           "/stereo/left/image_raw images, 320x180"), line
    assert not out.exists()
    # the two files disagree with each other
    World.default().with_image_size(320, 180).rig.save(tmp_path / "mixed")
    (tmp_path / "mixed" / "right.yaml").write_text(
        (tmp_path / "calib" / "right.yaml").read_text())
    (tmp_path / "mixed" / "stereo.yaml").unlink()
    code = main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                 "--calibration", str(tmp_path / "mixed")])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 1 and "right.yaml" in line and "640x360" in line, line
    assert not out.exists()


@pytest.fixture(scope="module")
def sqlite_bag(tmp_path_factory):
    from eye_in_hand.sim import World
    from eye_in_hand.sim.output import RenderOptions, write_bag

    root = tmp_path_factory.mktemp("campaign_sqlite")
    world = World.default().with_image_size(320, 180)
    write_bag(world, root / "sq", scenario="localization", frames=12, seed=2, storage="sqlite3",
              render=RenderOptions(supersample=1))
    return root / "sq"


def _corrupt_page(db, fraction: float) -> int:
    """Overwrite one 4 KiB page at ``fraction`` of the file with random bytes."""
    import numpy as np

    size = db.stat().st_size
    page = int(size // 4096 * fraction)
    data = bytearray(db.read_bytes())
    data[page * 4096:(page + 1) * 4096] = np.random.default_rng(page).integers(
        0, 256, 4096, dtype=np.uint8).tobytes()
    db.write_bytes(bytes(data))
    return page


def test_a_damaged_sqlite3_page_costs_only_its_rows(sqlite_bag, small_bag, tmp_path, capsys):
    import shutil

    _, hand_eye = small_bag
    bag = tmp_path / "bag"
    shutil.copytree(sqlite_bag, bag)
    _corrupt_page(bag / "sq.db3", 0.5)
    out = tmp_path / "o"
    assert main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                 "--workers", "1"]) == 0
    text = capsys.readouterr()
    assert "Traceback" not in text.err
    s = _summary(out)
    c, loss = s["counts"], s["loss"]
    # one page holds part of one image (or a few small rows): almost every pair survives
    assert c["pairs"] >= 11 and c["localized"] >= 11, c
    assert 0 < c["messages_lost"] <= 3 and loss["complete"]
    assert c["left_frames"] == c["localized"] + c["no_target"] + loss["total"] - \
        loss["by_cause"]["unpaired_right"] - loss["by_cause"]["damaged"] + \
        sum(n for t, n in s["damage"]["by_topic"].items() if t == "/stereo/left/image_raw")
    assert "read on past them row by row" in text.err


def test_a_truncated_mcap_dates_its_lost_tail_from_the_cut_with_counts(small_bag, tmp_path,
                                                                        capsys):
    import shutil

    from eye_in_hand.io.bags import DamageLog, bag_info, iter_messages

    src, hand_eye = small_bag
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    mcap = next(bag.glob("*.mcap"))
    full = {t: i.count for t, i in bag_info(src).topics.items()}
    kept_all = [(t, s) for t, _m, s, _r in iter_messages(src)]
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * 0.6)])
    log = DamageLog()
    got = [(t, s) for t, _m, s, _r in iter_messages(bag, damage=log)]
    assert len(log) == 1
    d = log.records[0]
    assert d.where.startswith("file tail from byte")
    lost = [m for m in kept_all if m not in set(got)]
    # exact: the counts of metadata.yaml less what the file still has, per topic
    by_topic: dict[str, int] = {}
    for t, _s in lost:
        by_topic[t] = by_topic.get(t, 0) + 1
    assert dict(d.topics) == by_topic and d.messages == len(lost) == sum(full.values()) - len(got)
    # the lost range starts at the cut: the first lost message, not the newest one read
    assert d.start_ns == min(s for _t, s in lost)
    assert d.start_ns < max(s for _t, s in got)   # the file is in write order, not time order
    assert d.end_ns == bag_info(src).end_ns
    assert main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(tmp_path / "o"),
                 "--quiet", "--workers", "1"]) in (0, 3)
    s = _summary(tmp_path / "o")
    read = s["damage"]["by_topic"]             # the topics process reads
    assert read and all(by_topic[t] == n for t, n in read.items())
    assert s["loss"]["complete"] and s["counts"]["messages_lost"] == sum(read.values())
    assert s["loss"]["by_cause"]["damaged"] == by_topic["/stereo/left/image_raw"] + \
        by_topic["/stereo/right/image_raw"]


@pytest.mark.parametrize("content,reason", [
    (b"", "is empty"),
    (b"rosbag2_bagfile_information: [: {\n",
     "is not valid YAML at line 1 (expected the node content, but found ':')"),
    (b"rosbag2_bagfile_information:\n  version: 5\n  x: caf\xe9\n",
     "is not UTF-8 text (byte 0xe9 at offset 50)"),
    (b"just: text\n", "has no 'rosbag2_bagfile_information' mapping"),
])
def test_a_damaged_metadata_yaml_is_reported_and_the_bag_scanned(small_bag, tmp_path, capsys,
                                                                   content, reason):
    import shutil

    src, hand_eye = small_bag
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    (bag / "metadata.yaml").write_bytes(content)
    out = tmp_path / "o"
    assert main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                 "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert f"warning: {bag / 'metadata.yaml'}: damaged: {reason}; ignored, the bag is read " \
           "from its storage file(s) (loc.mcap)" in err, err
    s = _summary(out)
    assert s["counts"]["localized"] == 6 and any("metadata.yaml" in n for n in s["notes"])


# ------------------------------------------------------------------------------------------------
# sized work: the estimate up front, refused when it cannot fit unless --force
# ------------------------------------------------------------------------------------------------
def test_simulate_states_its_estimate_and_refuses_what_cannot_fit(tmp_path, capsys,
                                                                  monkeypatch):
    import shutil
    from collections import namedtuple

    out = tmp_path / "sim"
    argv = ["simulate", "--scenario", "localization", "--frames", "100000", "--size",
            "16000x16000", "-o", str(out)]
    assert main(argv) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert line.startswith("eye-in-hand: error: simulate: 100000 stereo pairs at 16000x16000: "
                           "about "), line
    assert "up to 153,600,417 MB uncompressed" in line and "does not fit on the disk" in line
    assert "--force" in line and not out.exists()
    # a run that fits says what it will cost before it starts
    assert main(["simulate", "--scenario", "localization", "--frames", "2", "--size",
                 "64x48", "--supersample", "1", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "simulate: 2 stereo pairs at 64x48: about 3 s and 0.0 MB on disk (up to 0.0 MB " \
        "uncompressed" in err, err
    # a disk that is full: refused, unless --force (which then runs, and succeeds here)
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: usage(1 << 30, 1 << 30, 1000))
    small = ["simulate", "--scenario", "localization", "--frames", "2", "--size", "64x48",
             "--supersample", "1", "-o", str(tmp_path / "s2")]
    assert main(small) == 1
    assert "does not fit on the disk" in _one_line_error(capsys.readouterr().err)
    assert main(small + ["--force"]) == 0
    assert (tmp_path / "s2").is_dir()


def test_record_on_a_full_disk_names_the_bag_and_what_it_kept(tmp_path, capsys, monkeypatch):
    import errno
    import os

    from eye_in_hand.errors import BagError
    from eye_in_hand.io.bags import writing

    real_close = writing.BagWriter.close

    def full(self):
        real_close(self)
        try:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        except OSError as exc:
            raise BagError(f"cannot finish bag {self.path}: {exc}") from exc

    monkeypatch.setattr(writing.BagWriter, "close", full)
    out = tmp_path / "rec"
    assert main(["record", "-o", str(out), "/campaign_chatter", "-d", "0.2"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert line == (f"eye-in-hand: error: {out}: cannot write (No space left on device); what "
                    f"was recorded until then stays in {out} (a bag without its index is read "
                    "by scanning, see docs/bags.md)")
    assert ".partial-" not in line and "Errno" not in line


def test_a_hand_eye_file_of_another_camera_frame_is_named(small_bag, tmp_path, capsys):
    """hand_eye.yaml's child frame is not the frame of the bag's left images: a warning that
    names the file and both frames (offline numbers are unaffected, the live node would refuse
    the points); the same frame gives none."""
    import yaml

    from eye_in_hand.sim import World

    bag, hand_eye = small_bag
    World.default().with_image_size(320, 180).rig.save(tmp_path / "calib")
    other = tmp_path / "hand_eye_other.yaml"
    data = yaml.safe_load(hand_eye.read_text())
    data["child_frame"] = "camera_color_optical_frame"
    other.write_text(yaml.safe_dump(data))
    for he, warned in ((other, True), (hand_eye, False)):
        out = tmp_path / f"o_{warned}"
        main(["process", str(bag), "--hand-eye", str(he), "-o", str(out), "--quiet",
              "--calibration", str(tmp_path / "calib")])
        err = capsys.readouterr().err
        lines = [x for x in err.splitlines() if "child_frame" in x]
        if warned:
            assert len(lines) == 1 and lines[0].startswith(f"warning: {other}: child_frame "
                                                           "'camera_color_optical_frame'"), err
            assert "'camera_left_optical_frame'" in lines[0]
        else:
            assert not lines, err
