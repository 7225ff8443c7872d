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
    assert main(["process", str(tmp_path / "no_bag"), "--hand-eye", "x", "-o",
                 str(tmp_path / "o"), "--workers", "100000000"]) == 1
    assert _one_line_error(capsys.readouterr().err) == (
        "eye-in-hand: error: --workers: must be an integer within [1, 64], got 100000000")
    for bad in ("0", "-3"):
        assert main(["process", "b", "--hand-eye", "x", "-o", str(tmp_path / "o"),
                     "--workers", bad]) == 1
        assert "--workers: must be" in _one_line_error(capsys.readouterr().err)
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


@pytest.mark.parametrize("case", ["process-mcap", "process-sqlite3", "simulate"])
def test_a_full_disk_names_the_final_output_and_keeps_the_earlier_one(small_bag, tmp_path,
                                                                       case):
    bag, hand_eye = small_bag
    out = tmp_path / "out"
    out.mkdir()
    (out / "earlier.txt").write_text("the earlier result\n")
    if case.startswith("process"):
        argv = ["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out), "--quiet",
                "--workers", "1", "--overwrite", "--storage", case.split("-")[1]]
    else:
        argv = ["simulate", "--scenario", "localization", "--frames", "2", "--size", "320x180",
                "--supersample", "1", "--out", str(out), "--overwrite"]
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
