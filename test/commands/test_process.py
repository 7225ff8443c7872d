"""eye-in-hand process: offline localization over a simulated bag."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.core.transforms import transform_distance
from eye_in_hand.io.bags import bag_info, deserialize, iter_messages
from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
from eye_in_hand.sim import World
from eye_in_hand.sim.output import write_bag


@pytest.fixture(scope="module")
def loc_bag(tmp_path_factory):
    """A 12-pair localization bag at 640x360 with ground truth."""
    out = tmp_path_factory.mktemp("bags") / "loc"
    world = World.default().with_image_size(640, 360)
    write_bag(world, out, scenario="localization", frames=12, seed=3)
    return out, world


def _hand_eye(tmp_path, world, T=None):
    path = tmp_path / "hand_eye.yaml"
    save_hand_eye(path, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam if T is None else T, method="ground_truth"))
    return path


def test_process_writes_bag_csv_and_error_stats(loc_bag, tmp_path, capsys):
    bag, world = loc_bag
    out = tmp_path / "out"
    rc = main(["process", str(bag), "--hand-eye", str(_hand_eye(tmp_path, world)), "-o",
               str(out), "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "12 stereo pairs" in text and "RMS" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"]["localized"] == 12
    # True calibration at 640x360, 0.3-0.6 m: a few mm at most.
    assert summary["error"]["rms_mm"] < 4.0
    info = bag_info(out)
    assert info.topics["/target/pose"].count == 12
    assert info.topics["/target/pose_cov"].count == 12
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 12 and all(r["status"] == "ok" for r in rows)
    # The bag and the CSV hold the same numbers.
    poses = [deserialize(raw, mt) for _, mt, _, raw in iter_messages(out, ["/target/pose"])]
    for row, msg in zip(rows, poses, strict=True):
        assert int(row["stamp_ns"]) == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert float(row["x_base"]) == msg.pose.position.x


def test_wrong_hand_eye_shows_in_the_error(loc_bag, tmp_path, capsys):
    bag, world = loc_bag
    from eye_in_hand.core.transforms import compose, from_rotvec
    off = compose(world.ee_T_cam, from_rotvec([0, 0, 0], [0.01, 0.0, 0.0]))  # 10 mm off
    assert transform_distance(off, world.ee_T_cam)[0] == pytest.approx(0.01)
    out = tmp_path / "out"
    assert main(["process", str(bag), "--hand-eye", str(_hand_eye(tmp_path, world, off)),
                 "-o", str(out), "--quiet"]) == 0
    err = json.loads((out / "summary.json").read_text())["error"]
    assert 7.0 < err["rms_mm"] < 13.0


def test_missing_topic_and_existing_output_are_one_line_errors(loc_bag, tmp_path, capsys):
    bag, world = loc_bag
    he = str(_hand_eye(tmp_path, world))
    rc = main(["process", str(bag), "--hand-eye", he, "-o", str(tmp_path / "o1"), "--quiet",
               "--ee-pose-topic", "/robot/pose"])
    err = capsys.readouterr().err
    assert rc == 1 and "/robot/pose" in err and "Traceback" not in err
    (tmp_path / "o2").mkdir()
    (tmp_path / "o2" / "results.csv").write_text("earlier")
    rc = main(["process", str(bag), "--hand-eye", he, "-o", str(tmp_path / "o2"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and "exists" in err and "--overwrite" in err
    rc = main(["process", str(bag), "--hand-eye", str(tmp_path / "nope.yaml"), "-o",
               str(tmp_path / "o3"), "--quiet"])
    assert rc == 1 and "nope.yaml" in capsys.readouterr().err


def test_a_marker_lifetime_no_message_holds_is_refused_before_the_work(loc_bag, tmp_path,
                                                                         capsys):
    bag, world = loc_bag
    params = tmp_path / "params.yaml"
    params.write_text("/**/hand_eye:\n  ros__parameters:\n    marker_lifetime_s: 3.0e9\n")
    rc = main(["process", str(bag), "--hand-eye", str(_hand_eye(tmp_path, world)), "--params",
               str(params), "-o", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err
    assert "hand_eye marker_lifetime_s" in err and "Duration" in err
    assert not (tmp_path / "o").exists()


def test_joint_states_source_matches_ee_pose(loc_bag, tmp_path):
    import yaml
    bag, world = loc_bag
    he = str(_hand_eye(tmp_path, world))
    kin = tmp_path / "arm.yaml"
    kin.write_text(yaml.safe_dump({"arm": world.arm.to_dict()}))
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(a), "--quiet"]) == 0
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(b), "--quiet",
                 "--robot-pose", "joint_states", "--kinematics", str(kin)]) == 0
    ra = list(csv.DictReader((a / "results.csv").open()))
    rb = list(csv.DictReader((b / "results.csv").open()))
    pa = np.array([[float(r[k]) for k in ("x_base", "y_base", "z_base")] for r in ra])
    pb = np.array([[float(r[k]) for k in ("x_base", "y_base", "z_base")] for r in rb])
    assert np.max(np.abs(pa - pb)) < 1e-6


def test_a_corrupt_image_is_counted_and_processing_goes_on(loc_bag, tmp_path, capsys):
    from eye_in_hand.io.bags import BagWriter

    bag, world = loc_bag
    info = bag_info(bag)
    broken = tmp_path / "broken"
    left = "/stereo/left/image_raw"
    seen = 0
    with BagWriter(broken) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, raw in iter_messages(bag):
            if topic == left:
                seen += 1
                if seen == 5:
                    raw = raw[:len(raw) // 2]              # the 5th left image cut in half
            w.write(topic, stamp, raw)
    out = tmp_path / "out"
    rc = main(["process", str(broken), "--hand-eye", str(_hand_eye(tmp_path, world)), "-o",
               str(out), "--quiet"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    counts = json.loads((out / "summary.json").read_text())["counts"]
    assert counts["bad_messages"] == 1
    assert counts["localized"] == 11                     # the other eleven pairs
    assert f"warning: {left} at" in captured.err and "data:" in captured.err


def test_workers_option_changes_nothing_but_speed(loc_bag, tmp_path, capsys):
    bag, world = loc_bag
    he = str(_hand_eye(tmp_path, world))
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(a), "--quiet",
                 "--workers", "1"]) == 0
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(b), "--quiet",
                 "--workers", "2"]) == 0
    ra = list(csv.DictReader((a / "results.csv").open()))
    rb = list(csv.DictReader((b / "results.csv").open()))
    assert ra == rb
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:   # the option's range, before any work
        main(["process", str(bag), "--hand-eye", he, "-o", str(tmp_path / "c"), "--quiet",
              "--workers", "0"])
    assert exit_info.value.code == 2
    assert "argument --workers: must be an integer within [1, 64], got 0" in \
        capsys.readouterr().err


def test_the_summary_gives_the_top_reasons_when_few_are_located(loc_bag, tmp_path, capsys):
    """The trap: "0 located, 12 without target", exit 0, and the reason (a depth far outside
    the plausible range, as with a board square given in mm) only in results.csv."""
    bag, world = loc_bag
    params = tmp_path / "params.yaml"
    params.write_text("/**/detect_triangulate:\n  ros__parameters:\n    min_depth_m: 0.001\n"
                      "    max_depth_m: 0.01\n")
    rc = main(["process", str(bag), "--hand-eye", str(_hand_eye(tmp_path, world)), "-o",
               str(tmp_path / "out"), "--quiet", "--params", str(params)])
    text = capsys.readouterr().out
    assert rc != 0
    assert "why 12 of 12 stereo pairs have no result in the base frame (top reasons):" in text
    line = next(x for x in text.splitlines() if x.startswith("  12 no_target: "))
    assert "puts the pair at depth" in line and "outside 0.001-0.01 m" in line
    rows = list(csv.DictReader((tmp_path / "out" / "results.csv").open()))
    assert line.endswith(rows[0]["reason"])


def test_top_reasons_group_reasons_that_differ_in_numbers_only():
    from eye_in_hand.io.results import FrameResult
    from eye_in_hand.offline import top_reasons

    frames = ([FrameResult(i, "no_target", f"target 'red': depth {500 + i}.5 m, outside "
                                          "0.05-100 m") for i in range(3)]
              + [FrameResult(9, "no_robot_pose", "no pose"), FrameResult(10, "ok")])
    assert top_reasons(frames) == [
        (3, "no_target", "target 'red': depth 500.5 m, outside 0.05-100 m"),
        (1, "no_robot_pose", "no pose")]
