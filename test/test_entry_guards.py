"""No traceback reaches a user from any process: the top-level guard of every entry point.

Each entry point runs with a planted exception (a bug, not bad input): the command line, every
node's ``main``, and a worker process. Each must print one line naming the error and the
``--debug`` switch, exit with the documented code (70), and show the traceback only with
``--debug`` / ``EYE_IN_HAND_DEBUG=1``. A worker whose parent is killed exits quietly.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from eye_in_hand import cli
from eye_in_hand.errors import EXIT_UNEXPECTED

NODES = {
    "bag_player": "BagPlayer",
    "bag_recorder": "BagRecorder",
    "hand_eye": "HandEyeNode",
    "stereo_capture": "StereoCaptureNode",
    "detect_triangulate": "DetectTriangulateNode",
    "localize": "LocalizationChain",
}


def _valid_value(kind) -> str:
    for candidate in ("x", "1", "1,1,1,1"):
        try:
            if kind is not None:
                kind(candidate)
        except Exception:  # noqa: BLE001 - try the next one
            continue
        return candidate
    raise AssertionError(f"no valid value for {kind}")


def _boom(*_a, **_k):
    raise ZeroDivisionError("planted")


@pytest.mark.parametrize("words,module", cli.COMMANDS)
def test_every_command_turns_a_planted_exception_into_one_line(words, module, monkeypatch,
                                                                capsys):
    import importlib

    mod = importlib.import_module(module)
    monkeypatch.setattr(mod, "run", _boom)
    monkeypatch.delenv("EYE_IN_HAND_DEBUG", raising=False)
    parser = cli.build_parser()
    # the smallest valid argument list of the command: fill required options with "x"
    argv = words.split()
    sub = parser
    for w in argv:
        sub = next(a for a in sub._actions if a.__class__.__name__ == "_SubParsersAction"
                   ).choices[w]
    for action in sub._actions:
        if action.required or (not action.option_strings and action.nargs not in ("?", "*")):
            value = action.choices[0] if action.choices else _valid_value(action.type)
            argv += ([action.option_strings[0]] if action.option_strings else []) + [str(value)]
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == EXIT_UNEXPECTED, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines == ["eye-in-hand: internal error: ZeroDivisionError: planted (run with "
                     "--debug, or EYE_IN_HAND_DEBUG=1, for the traceback)"], err
    assert "Traceback" not in err


def test_debug_shows_the_traceback(monkeypatch):
    import eye_in_hand.commands.bag_info as mod

    monkeypatch.setattr(mod, "run", _boom)
    monkeypatch.delenv("EYE_IN_HAND_DEBUG", raising=False)
    with pytest.raises(ZeroDivisionError):
        cli.main(["bag", "info", "x", "--debug"])
    monkeypatch.setenv("EYE_IN_HAND_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        cli.main(["--debug", "bag", "info", "x"])
    monkeypatch.delenv("EYE_IN_HAND_DEBUG")


def _run_child(code: str, env: dict[str, str], timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("node", sorted(NODES))
def test_every_node_main_turns_a_planted_exception_into_one_line(node, ros_env):
    env = {k: v for k, v in ros_env.items() if k != "EYE_IN_HAND_DEBUG"}
    code = f"""
        import sys
        import eye_in_hand.nodes.{node} as m
        def boom(*a, **k):
            raise ZeroDivisionError("planted")
        m.{NODES[node]} = boom
        m.main([])
    """
    proc = _run_child(code, env)
    assert proc.returncode == EXIT_UNEXPECTED, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    assert f"{node}: internal error: ZeroDivisionError: planted (run with --debug" in proc.stderr
    env["EYE_IN_HAND_DEBUG"] = "1"
    proc = _run_child(code, env)
    assert "Traceback" in proc.stderr and "ZeroDivisionError" in proc.stderr


@pytest.mark.parametrize("node", sorted(NODES))
def test_every_node_main_prepares_its_process(node, ros_env):
    """The DDS profile and the reused memory blocks (eye_in_hand.memory): set by every node's
    main before rclpy starts, also by those that do not go through run_node."""
    env = {k: v for k, v in ros_env.items() if k != "EYE_IN_HAND_DEBUG"}
    code = f"""
        import eye_in_hand.ros.node_main as nm
        import eye_in_hand.nodes.{node} as m
        nm.reuse_large_buffers = lambda: print("PREPARED memory", flush=True)
        nm.use_large_data_profile = lambda: print("PREPARED dds", flush=True)
        def boom(*a, **k):
            raise ZeroDivisionError("planted")
        m.{NODES[node]} = boom
        m.main([])
    """
    proc = _run_child(code, env)
    assert proc.returncode == EXIT_UNEXPECTED, proc.stderr
    assert "PREPARED memory" in proc.stdout and "PREPARED dds" in proc.stdout, proc.stdout


def test_a_node_with_a_parameter_file_rcl_cannot_parse_says_so_in_one_line(ros_env, tmp_path):
    bad = tmp_path / "anchors.yaml"
    bad.write_text("/**/detect_triangulate:\n  ros__parameters:\n    a: &x 5.0\n    b: *x\n")
    proc = _run_child(f"""
        import eye_in_hand.nodes.detect_triangulate as m
        m.main(["--ros-args", "--params-file", {str(bad)!r}])
    """, {k: v for k, v in ros_env.items() if k != "EYE_IN_HAND_DEBUG"})
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "detect_triangulate: error: rcl:" in proc.stderr and "aliasing" in proc.stderr


def test_a_worker_with_a_planted_exception_prints_one_line(ros_env):
    env = {k: v for k, v in ros_env.items() if k != "EYE_IN_HAND_DEBUG"}
    proc = _run_child("""
        import time
        from eye_in_hand.workers import ProcessPool
        pool = ProcessPool(1, "math:sqrt", ("not a number",))
        deadline = time.monotonic() + 30
        while pool.alive() and time.monotonic() < deadline:
            time.sleep(0.02)
        pool.close()
    """, env)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "internal error" in line]
    assert len(lines) == 1 and "TypeError" in lines[0], proc.stderr


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_workers_exit_quietly_when_their_parent_is_killed(ros_env, tmp_path):
    """SIGKILL of the parent while its workers are busy: each finishes its task, finds the
    channel closed, and exits without a word (the case that printed BrokenPipeError)."""
    err = tmp_path / "stderr.txt"
    env = {k: v for k, v in ros_env.items() if k != "EYE_IN_HAND_DEBUG"}
    script = textwrap.dedent("""
        import os, signal, sys, time
        from eye_in_hand.workers import ProcessPool
        pool = ProcessPool(2, "builtins:len", ((),))
        pool.wait_ready(30)
        futs = [pool.submit("time:sleep", 0.5) for _ in range(6)]
        print(" ".join(str(w.proc.pid) for w in pool._workers), flush=True)
        time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    with open(err, "w") as stderr:
        proc = subprocess.run([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE,
                              stderr=stderr, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL
    pids = [int(p) for p in proc.stdout.split()]
    assert len(pids) == 2
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in pids), "a worker outlived its parent"
    text = err.read_text()
    assert "Traceback" not in text and "Error" not in text, text


def test_the_demo_turns_a_planted_exception_into_one_line(monkeypatch, capsys):
    from eye_in_hand import demo

    monkeypatch.setattr(demo, "main", lambda argv=None: _boom())
    monkeypatch.delenv("EYE_IN_HAND_DEBUG", raising=False)
    assert demo.guarded_main([]) == 70
    err = capsys.readouterr().err
    assert err.startswith("python -m eye_in_hand.demo: internal error: ZeroDivisionError")
    assert err.count("\n") == 1 and "Traceback" not in err
    with pytest.raises(ZeroDivisionError):
        demo.guarded_main(["--debug"])


def test_the_console_script_exits_with_the_commands_code_and_its_files_written(tmp_path):
    """``eye-in-hand`` (cli.console_main: main, then the exit without the interpreter's final
    collections) gives the command's exit code and leaves what the command wrote complete;
    the venv's script calls it."""
    script = Path(sys.executable).with_name("eye-in-hand")
    assert "console_main" in script.read_text()
    missing = subprocess.run([sys.executable, "-m", "eye_in_hand.cli", "bag", "info",
                              str(tmp_path / "missing")], capture_output=True, text=True,
                             timeout=120)
    assert missing.returncode == 1 and "does not exist" in missing.stderr, missing.stderr
    out = tmp_path / "sim"
    made = subprocess.run([str(script), "simulate", "--scenario", "localization", "--frames",
                           "2", "--size", "320x240", "--quiet", "-o", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    from eye_in_hand.io.bags import bag_info

    assert bag_info(out).topics["/stereo/left/image_raw"].count == 2
