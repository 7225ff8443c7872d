"""The fault campaign of the reliability page, as tests: one test per case that once ended in a
hang, a traceback or a misreported loss. Each must end within seconds with one line (or an
exact loss report) and no traceback."""
from __future__ import annotations

import pytest

from eye_in_hand.cli import main


def _one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
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
