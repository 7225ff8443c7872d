"""eye-in-hand process with several targets, the distances command, and eye-to-hand process."""
from __future__ import annotations

import csv
import dataclasses
import itertools
import json

import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.io.bags import bag_info, deserialize, iter_messages
from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
from eye_in_hand.sim import World
from eye_in_hand.sim.output import write_bag
from eye_in_hand.sim.world import Target

# four spheres of four colours; the parameter file names them in another order than the world
# (ground truth comes in world order: the ids are matched to it by position)
TARGETS = (Target("red", [0.46, 0.14, 0.02], 0.02, (40, 40, 210)),
           Target("green", [0.56, 0.15, 0.02], 0.02, (40, 170, 40)),
           Target("blue", [0.47, 0.25, 0.02], 0.02, (200, 80, 30)),
           Target("yellow", [0.57, 0.24, 0.02], 0.02, (30, 200, 210)))
PARAMS = """/**/detect_triangulate:
  ros__parameters:
    target_names: [yellow, red, green, blue]
    targets:
      red: {lower: [170, 100, 40], upper: [10, 255, 255], radius_m: 0.02}
      green: {lower: [35, 60, 30], upper: [85, 255, 255], radius_m: 0.02}
      blue: {lower: [100, 100, 30], upper: [130, 255, 255], radius_m: 0.02}
      yellow: {lower: [18, 100, 40], upper: [35, 255, 255], radius_m: 0.02}
"""
FRAMES = 8


def _only(names: list[str]) -> str:
    """PARAMS with target_names ``names`` and only their sections (a section for a target
    not in target_names is an unknown parameter)."""
    lines = [line for line in PARAMS.splitlines(keepends=True)
             if not line.startswith("      ") or line.split(":")[0].strip() in names]
    return "".join(lines).replace("[yellow, red, green, blue]", f"[{', '.join(names)}]")


@pytest.fixture(scope="module")
def multi(tmp_path_factory):
    """A small four-target localization bag (640x360, 8 pairs), processed once."""
    root = tmp_path_factory.mktemp("multi")
    world = dataclasses.replace(World.default().with_image_size(640, 360), targets=TARGETS)
    write_bag(world, root / "bag", scenario="localization", frames=FRAMES, seed=3)
    params = root / "params.yaml"
    params.write_text(PARAMS)
    he = root / "hand_eye.yaml"
    save_hand_eye(he, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth"))
    out = root / "out"
    assert main(["process", str(root / "bag"), "--hand-eye", str(he), "--params", str(params),
                 "-o", str(out), "--quiet", "--workers", "1"]) == 0
    return world, root, out


def _true_distance(a: str, b: str) -> float:
    c = {t.name: t.center_base for t in TARGETS}
    return float(np.linalg.norm(c[a] - c[b]))


def test_rows_per_frame_and_target_and_distances_against_truth(multi, capsys):
    world, root, out = multi
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == FRAMES * 4
    assert [r["target"] for r in rows[:4]] == ["yellow", "red", "green", "blue"]
    assert all(r["status"] == "ok" for r in rows)
    centres = {t.name: t.center_base for t in TARGETS}
    for r in rows:   # each id got its own true target (matched by position, not by order)
        gt = np.array([float(r[k]) for k in ("gt_x", "gt_y", "gt_z")])
        assert np.allclose(gt, centres[r["target"]]), r["target"]
        assert float(r["error_mm"]) < 4.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"]["localized"] == FRAMES          # first-target figures as before
    assert summary["error"]["frames"] == FRAMES
    assert set(summary["targets"]) == {"red", "green", "blue", "yellow"}
    for tid, t in summary["targets"].items():
        assert t["located"] == t["localized"] == FRAMES and t["rms_mm"] < 3.0
        assert t["truth_index"] == [x.name for x in TARGETS].index(tid)
    pairs = summary["distances"]
    assert len(pairs) == 6
    for p in pairs:
        assert p["frames"] == FRAMES and p["truth_source"] == "ground_truth"
        assert p["truth_m"] == pytest.approx(_true_distance(p["a"], p["b"]), abs=1e-9)
        assert p["error_mm"] == pytest.approx(1000 * (p["mean_m"] - p["truth_m"]), abs=1e-6)
        assert abs(p["error_mm"]) < 3.0 and 0 < p["std_mm"] < 3.0
        # an independent per-frame check from the CSV
        d = []
        for k in range(FRAMES):
            pa, pb = (np.array([float(r[c]) for c in ("x_base", "y_base", "z_base")])
                      for r in rows[4 * k:4 * k + 4] if r["target"] in (p["a"], p["b"]))
            d.append(np.linalg.norm(pa - pb))
        assert p["mean_m"] == pytest.approx(np.mean(d), abs=1e-12)
        assert p["std_mm"] == pytest.approx(1000 * np.std(d, ddof=1), abs=1e-9)
    # the output bag carries every target
    info = bag_info(out)
    for tid in ("red", "green", "blue", "yellow"):
        assert info.topics[f"/target/{tid}/pose"].count == FRAMES
        assert info.topics[f"/targets/{tid}/point"].count == FRAMES
        assert info.topics[f"/target/{tid}/ground_truth"].count == FRAMES
    assert info.topics["/target/pose"].count == FRAMES        # the first target, as before
    first = [deserialize(raw, mt) for _, mt, _, raw in iter_messages(out, ["/target/pose"])]
    yellow = [deserialize(raw, mt) for _, mt, _, raw in
              iter_messages(out, ["/target/yellow/pose"])]
    assert [m.pose.position.x for m in first] == [m.pose.position.x for m in yellow]


def test_distances_command_on_csv_folder_and_bag_agrees_with_process(multi, capsys):
    _world, _root, out = multi
    summary = json.loads((out / "summary.json").read_text())
    capsys.readouterr()
    for source in (out / "results.csv", out):
        assert main(["distances", str(source), "--json"]) == 0
        got = json.loads(capsys.readouterr().out)
        assert got["distances"] == summary["distances"] and got["frames"] == FRAMES
        assert got["truth"] == "ground_truth"
    # the output bag (its per-target topics, no CSV): same pairs
    bag_only = _root / "bag_only"
    bag_only.mkdir()
    for f in out.iterdir():
        if f.name not in ("results.csv", "summary.json"):
            (bag_only / f.name).write_bytes(f.read_bytes())
    assert main(["distances", str(bag_only), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    for a, b in zip(got["distances"], summary["distances"], strict=True):
        assert (a["a"], a["b"], a["frames"]) == (b["a"], b["b"], b["frames"])
        assert a["mean_m"] == pytest.approx(b["mean_m"], abs=1e-12)
        assert a["error_mm"] == pytest.approx(b["error_mm"], abs=1e-9)
    assert main(["distances", str(out)]) == 0
    text = capsys.readouterr().out
    assert "4 targets over 8 frames" in text and "yellow - red" in text


def test_distances_with_a_truth_file(multi, tmp_path, capsys):
    _world, _root, out = multi
    truth = tmp_path / "known.yaml"
    truth.write_text("distances:\n  - {a: blue, b: red, m: 0.1100}\n"
                     "  - {a: green, b: yellow, m: 0.0905}\n")
    assert main(["distances", str(out), "--truth", str(truth), "--json"]) == 0
    got = {(p["a"], p["b"]): p for p in json.loads(capsys.readouterr().out)["distances"]}
    rb = got[("red", "blue")]
    assert rb["truth_source"] == "known" and rb["truth_m"] == 0.11
    assert rb["error_mm"] == pytest.approx(1000 * (rb["mean_m"] - 0.11), abs=1e-9)
    assert got[("yellow", "green")]["truth_m"] == 0.0905
    assert got[("yellow", "red")]["truth_source"] == "ground_truth"   # the others keep theirs


@pytest.mark.parametrize("content, message", [
    ("distances:\n  - {a: red, b: blue, m: -0.1}\n", "distances[0]: m must be a positive"),
    ("distances:\n  - {a: red, b: red, m: 0.1}\n", "the same target"),
    ("distances:\n  - {a: red, m: 0.1}\n", "exactly the keys a, b, m"),
    ("distances:\n  - {a: red, b: blue, m: 0.1}\n  - {a: blue, b: red, m: 0.1}\n", "twice"),
    ("pairs: []\n", "a 'distances' list"),
    ("distances:\n  - {a: red, b: purple, m: 0.1}\n", "no target pair red - purple"),
])
def test_bad_truth_files_are_one_line_errors(multi, tmp_path, capsys, content, message):
    _world, _root, out = multi
    truth = tmp_path / "known.yaml"
    truth.write_text(content)
    assert main(["distances", str(out), "--truth", str(truth)]) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_bad_results_inputs_are_one_line_errors(tmp_path, capsys):
    cases = []
    cases.append((tmp_path / "nope.csv", "not found"))
    one = tmp_path / "one.csv"
    one.write_text("stamp_ns,status,x_base,y_base,z_base,target\n1,ok,0,0,0,red\n"
                   "2,ok,0,0,0.1,red\n")
    cases.append((one, "one target (red): no distances"))
    old = tmp_path / "old.csv"
    old.write_text("stamp_ns,status,x_base,y_base,z_base\n1,ok,0,0,0\n")
    cases.append((old, "no 'target' column"))
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    cases.append((other, "not a results.csv"))
    garbled = tmp_path / "garbled.csv"
    garbled.write_text("stamp_ns,status,x_base,y_base,z_base,target\n1,ok,0,zero,0,red\n")
    cases.append((garbled, "garbled.csv:2: not a number"))
    folder = tmp_path / "empty_dir"
    folder.mkdir()
    cases.append((folder, "neither a results.csv nor a readable output bag"))
    for path, message in cases:
        assert main(["distances", str(path)]) == 1, path
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_process_with_a_truth_file_and_a_single_target(multi, tmp_path, capsys):
    world, root, out = multi
    truth = tmp_path / "known.yaml"
    truth.write_text("distances:\n  - {a: red, b: green, m: 0.1005}\n")
    o = tmp_path / "o"
    assert main(["process", str(root / "bag"), "--hand-eye", str(root / "hand_eye.yaml"),
                 "--params", str(root / "params.yaml"), "-o", str(o), "--quiet",
                 "--truth", str(truth)]) == 0
    text = capsys.readouterr().out
    assert "truth from" in text and "red - green" in text
    s = json.loads((o / "summary.json").read_text())
    rg = next(p for p in s["distances"] if {p["a"], p["b"]} == {"red", "green"})
    assert rg["truth_source"] == "known" and rg["truth_m"] == 0.1005
    assert s["distances_truth"] == str(truth)
    # one configured target: no distance table, distances empty, the rows as before
    single = tmp_path / "single.yaml"
    single.write_text(_only(["red"]))
    o2 = tmp_path / "o2"
    assert main(["process", str(root / "bag"), "--hand-eye", str(root / "hand_eye.yaml"),
                 "--params", str(single), "-o", str(o2), "--quiet"]) == 0
    assert "mean (m)" not in capsys.readouterr().out
    s = json.loads((o2 / "summary.json").read_text())
    assert s["distances"] == [] and list(s["targets"]) == ["red"]
    assert len(list(csv.DictReader((o2 / "results.csv").open()))) == FRAMES


def _static_camera_bag(world: World, q: np.ndarray, out, frames: int) -> None:
    """Images of a camera that does not move (eye-to-hand): images, camera_info and ground
    truth only, no robot topic."""
    from eye_in_hand.io.bags import BagWriter
    from eye_in_hand.sim.output import _Msgs

    rig = world.rig.rectified()
    with BagWriter(out) as w:
        m = _Msgs(w.typestore)
        for topic, typ in (("/stereo/left/image_raw", "sensor_msgs/msg/Image"),
                           ("/stereo/right/image_raw", "sensor_msgs/msg/Image"),
                           ("/stereo/left/camera_info", "sensor_msgs/msg/CameraInfo"),
                           ("/stereo/right/camera_info", "sensor_msgs/msg/CameraInfo"),
                           ("/ground_truth/target", "geometry_msgs/msg/PointStamped")):
            w.add_topic(topic, typ)
        for k in range(frames):
            ns = 1_700_000_000_000_000_000 + k * 33_333_333
            fr = world.render(q, seed=k, noise_sigma=2.0)
            w.write("/stereo/left/image_raw", ns, m.image(fr.left, ns, "left"))
            w.write("/stereo/right/image_raw", ns, m.image(fr.right, ns, "right"))
            w.write("/stereo/left/camera_info", ns, m.camera_info(rig.left, ns, "left"))
            w.write("/stereo/right/camera_info", ns, m.camera_info(rig.right, ns, "right"))
            for c in fr.truth.targets_base:
                w.write("/ground_truth/target", ns, m.point_stamped(c, ns, "base_link"))


def test_eye_to_hand_process_needs_no_robot_topic(multi, tmp_path, capsys):
    from eye_in_hand.core.localization import target_in_base
    from eye_in_hand.core.transforms import compose, from_rotvec
    from eye_in_hand.sim.scenarios import localization_trajectory

    world, root, _out = multi
    q = localization_trajectory(world, 0.1, 30.0, seed=3)[0][1]
    bag = tmp_path / "static"
    _static_camera_bag(world, q, bag, 4)
    base_T_cam = world.base_T_cam(q)
    cov = np.diag([1e-8, 2e-8, 3e-8, 1e-7, 1e-7, 2e-7])
    he = tmp_path / "eye_to_hand.yaml"
    save_hand_eye(he, HandEyeCalibration(
        setup="eye_to_hand", parent_frame="base_link", child_frame="camera_left_optical_frame",
        transform=base_T_cam, method="ground_truth", covariance=cov))
    out = tmp_path / "out"
    assert main(["process", str(bag), "--hand-eye", str(he), "--params",
                 str(root / "params.yaml"), "-o", str(out), "--quiet"]) == 0, \
        capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["counts"]["localized"] == 4 and s["counts"]["no_robot_pose"] == 0
    for t in s["targets"].values():
        assert t["localized"] == 4 and t["rms_mm"] < 3.0
    assert all(abs(p["error_mm"]) < 3.0 for p in s["distances"])
    rows = list(csv.DictReader((out / "results.csv").open()))
    r = rows[0]
    p_cam = np.array([float(r[k]) for k in ("x_cam", "y_cam", "z_cam")])
    p_base = np.array([float(r[k]) for k in ("x_base", "y_base", "z_base")])
    assert np.allclose(p_base, (base_T_cam @ np.append(p_cam, 1.0))[:3], atol=1e-12)
    # the covariance holds the mount's: its sigma exceeds the camera's alone
    _, cov_mount = target_in_base(np.eye(4), base_T_cam, p_cam, cov_hand_eye=cov)
    sig = np.array([float(r[k]) for k in ("sigma_x_mm", "sigma_y_mm", "sigma_z_mm")]) / 1000
    assert np.all(sig ** 2 >= np.diag(cov_mount) - 1e-15)
    # a mount 10 mm off shows as a 10 mm error (the transform is used, not the truth)
    off = compose(from_rotvec([0, 0, 0], [0.01, 0, 0]), base_T_cam)
    save_hand_eye(he, HandEyeCalibration(
        setup="eye_to_hand", parent_frame="base_link", child_frame="camera_left_optical_frame",
        transform=off, method="ground_truth"))
    assert main(["process", str(bag), "--hand-eye", str(he), "--params",
                 str(root / "params.yaml"), "-o", str(tmp_path / "off"), "--quiet"]) == 0
    s = json.loads((tmp_path / "off" / "summary.json").read_text())
    assert 8.0 < s["error"]["rms_mm"] < 12.0
    # an eye-in-hand calibration on this bag needs the robot: one error line naming the topic
    he_in = tmp_path / "eye_in_hand.yaml"
    save_hand_eye(he_in, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth"))
    capsys.readouterr()
    assert main(["process", str(bag), "--hand-eye", str(he_in), "-o", str(tmp_path / "x"),
                 "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "/ee_pose" in err and "Traceback" not in err


def test_pairs_cover_every_combination_once(multi):
    _world, _root, out = multi
    pairs = json.loads((out / "summary.json").read_text())["distances"]
    ids = ["yellow", "red", "green", "blue"]
    assert [(p["a"], p["b"]) for p in pairs] == list(itertools.combinations(ids, 2))


def test_a_first_target_never_seen_keeps_its_rows_and_the_others_are_localized(multi, tmp_path,
                                                                               capsys):
    _world, root, _out = multi
    params = tmp_path / "params.yaml"
    params.write_text(_only(["purple", "red", "green"])
                      .replace("    targets:\n", "    targets:\n      purple: {lower: [140, 100, "
                               "40], upper: [160, 255, 255], radius_m: 0.02}\n"))
    out = tmp_path / "o"
    assert main(["process", str(root / "bag"), "--hand-eye", str(root / "hand_eye.yaml"),
                 "--params", str(params), "-o", str(out), "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["counts"]["located"] == 0 and s["counts"]["no_target"] == FRAMES
    assert s["error"] is None                       # first-target figures: nothing located
    assert s["targets"]["purple"]["located"] == 0
    assert s["targets"]["red"]["localized"] == s["targets"]["green"]["localized"] == FRAMES
    (rg,) = [p for p in s["distances"] if p["frames"]]
    assert (rg["a"], rg["b"]) == ("red", "green") and abs(rg["error_mm"]) < 3.0
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert [r["target"] for r in rows[:3]] == ["purple", "red", "green"]
    purple = [r for r in rows if r["target"] == "purple"]
    assert len(purple) == FRAMES and all(r["status"] == "no_target" and r["reason"]
                                         for r in purple)
    assert info_count(out, "/target/pose") == 0 and info_count(out, "/target/red/pose") == FRAMES


def info_count(bag, topic: str) -> int:
    t = bag_info(bag).topics.get(topic)
    return 0 if t is None else t.count
