"""eye_in_hand.io.atomic: outputs appear whole or not at all, never replace results silently."""
from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from eye_in_hand.io import atomic
from eye_in_hand.io.atomic import (
    OutputError,
    OutputExistsError,
    OutputWriteError,
    atomic_file,
    atomic_output_dir,
    atomic_write_text,
    check_output_dir,
    remove_stale_partials,
)


def _tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*"))
            if p.is_file()}


def _leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".partial-" in p.name or ".old-" in p.name)


def _old(tmp_path: Path) -> Path:
    out = tmp_path / "out"
    out.mkdir()
    (out / "hand_eye.yaml").write_text("old")
    (out / "report.html").write_text("old report")
    return out


def test_new_folder_appears_in_one_piece_with_its_own_name_inside(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "out"  # parents are created
    with atomic_output_dir(out) as tmp:
        assert tmp.name == "out" and tmp.parent.name == f".out.partial-{os.getpid()}"
        assert not out.exists()
        (tmp / "a.txt").write_text("A")
        (tmp / "d").mkdir()
        (tmp / "d" / "b.txt").write_text("B")
    assert _tree(out) == {"a.txt": "A", "d/b.txt": "B"}
    assert _leftovers(out.parent) == []


def test_existing_output_is_refused_and_kept(tmp_path: Path) -> None:
    out = _old(tmp_path)
    with pytest.raises(OutputExistsError, match=r"-o .*out: exists already \(give --overwrite"):
        check_output_dir(out)
    with pytest.raises(OutputExistsError):
        with atomic_output_dir(out) as tmp:
            (tmp / "hand_eye.yaml").write_text("new")
    assert _tree(out) == {"hand_eye.yaml": "old", "report.html": "old report"}
    assert _leftovers(tmp_path) == []


def test_output_created_meanwhile_is_refused_at_the_rename(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(OutputExistsError):
        with atomic_output_dir(out) as tmp:
            (tmp / "x").write_text("mine")
            out.mkdir()
            (out / "theirs").write_text("theirs")  # another run finished first
    assert _tree(out) == {"theirs": "theirs"}


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two-renames"])
def test_overwrite_replaces_the_folder_whole(tmp_path: Path, monkeypatch, exchange) -> None:
    if not exchange:
        monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    out = _old(tmp_path)
    with atomic_output_dir(out, overwrite=True) as tmp:
        (tmp / "hand_eye.yaml").write_text("new")  # no report.html this time (--no-html)
    assert _tree(out) == {"hand_eye.yaml": "new"}  # never the old report beside the new file
    assert _leftovers(tmp_path) == []


def test_an_output_holding_an_input_is_refused_even_with_overwrite(tmp_path: Path) -> None:
    out = _old(tmp_path)
    with pytest.raises(OutputError, match=r"-o .*out: holds the input .*hand_eye.yaml; choose "
                                          r"another output"):
        check_output_dir(out, overwrite=True, inputs=[None, out / "hand_eye.yaml"])
    with pytest.raises(OutputError, match="holds the input"):
        check_output_dir(tmp_path / "." / "out", overwrite=True, inputs=[out])
    assert check_output_dir(out, overwrite=True, inputs=[tmp_path / "elsewhere"]) == out


def test_empty_folder_counts_as_absent_and_a_file_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    with atomic_output_dir(out) as tmp:
        (tmp / "x").write_text("1")
    assert _tree(out) == {"x": "1"}
    f = tmp_path / "file"
    f.write_text("data")
    with pytest.raises(OutputError, match="exists and is not a folder"):
        with atomic_output_dir(f, overwrite=True):
            pass
    assert f.read_text() == "data"


def test_failure_inside_keeps_the_old_output(tmp_path: Path) -> None:
    out = _old(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        with atomic_output_dir(out, overwrite=True) as tmp:
            (tmp / "hand_eye.yaml").write_text("half")
            raise KeyboardInterrupt
    assert _tree(out) == {"hand_eye.yaml": "old", "report.html": "old report"}
    assert _leftovers(tmp_path) == []


def test_full_disk_is_one_error_naming_the_file_and_the_old_output_stays(
        tmp_path: Path, monkeypatch) -> None:
    out = _old(tmp_path)
    real_open = open

    def full_open(file, mode="r", *args, **kwargs):
        if "w" in mode and str(file).endswith("report.json"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(file))
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr("builtins.open", full_open)
    with pytest.raises(OutputWriteError) as info:
        with atomic_output_dir(out, overwrite=True) as tmp:
            (tmp / "hand_eye.yaml").write_text("new")
            with open(tmp / "report.json", "w") as fh:
                fh.write("{}")
    msg = str(info.value)
    # the file under its final name, the reason, and what was kept; one line
    assert msg == (f"{out / 'report.json'}: cannot write (No space left on device); the earlier "
                   f"{out} is unchanged"), msg
    assert _tree(out) == {"hand_eye.yaml": "old", "report.html": "old report"}
    assert _leftovers(tmp_path) == []


def test_full_disk_in_a_write_names_the_file_being_written(tmp_path: Path, monkeypatch) -> None:
    real_fsync = os.fsync

    def fsync(fd):  # ENOSPC surfaces at the flush (delayed allocation), without a file name
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    out = tmp_path / "out"
    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(OutputWriteError, match=r"out/results.csv: cannot write \(No space left "
                                               r"on device\); nothing was written to"):
        with atomic_output_dir(out) as tmp:
            (tmp / "results.csv").write_text("rows")
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert not out.exists() and _leftovers(tmp_path) == []


def test_stale_leftovers_of_dead_runs_are_removed_live_ones_kept(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead_pid = int(dead.stdout)
    out = tmp_path / "out"
    stale = tmp_path / f".out.partial-{dead_pid}"
    (stale / "out").mkdir(parents=True)
    (stale / "out" / "results.csv").write_text("cut")
    live = tmp_path / f".out.partial-{os.getppid()}"  # a running process (pytest's parent)
    live.mkdir()
    other = tmp_path / f".other.partial-{dead_pid}"  # another output's: not ours to touch
    other.mkdir()
    old = tmp_path / f".out.old-{dead_pid}"  # killed between the two renames: the old result
    old.mkdir()
    (old / "hand_eye.yaml").write_text("old")
    done = remove_stale_partials(out)
    assert sorted(p.name for p in done) == sorted([stale.name, old.name])
    assert not stale.exists() and live.exists() and other.exists()
    assert _tree(out) == {"hand_eye.yaml": "old"}  # restored, since out was missing
    # a rerun is not blocked by leftovers
    with atomic_output_dir(out, overwrite=True) as tmp:
        (tmp / "hand_eye.yaml").write_text("new")
    assert _tree(out) == {"hand_eye.yaml": "new"}


def test_atomic_file_replaces_or_keeps(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "hand_eye.yaml"
    atomic_write_text(path, "one")
    atomic_write_text(path, "two")
    assert path.read_text() == "two"
    with pytest.raises(RuntimeError):
        with atomic_file(path) as fh:
            fh.write("half")
            raise RuntimeError("boom")
    assert path.read_text() == "two"

    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(OutputWriteError, match=r"hand_eye.yaml: cannot write \(No space left on "
                                               r"device\); the earlier file is unchanged"):
        atomic_write_text(path, "three")
    assert path.read_text() == "two"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hand_eye.yaml"]


def _can_mount_tmpfs(where: Path) -> bool:
    try:
        return subprocess.run(["unshare", "-Urm", "sh", "-c",
                               'mount -t tmpfs -o size=64k tmpfs "$0"', str(where)],
                              capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def test_a_real_full_disk(tmp_path: Path) -> None:
    """On a 64 KiB tmpfs (mounted in a user namespace): the old output survives ENOSPC."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if not _can_mount_tmpfs(disk):
        pytest.skip("cannot mount a tmpfs in a user namespace here")
    script = f"""
import os, sys
sys.path.insert(0, {str(Path(__file__).resolve().parents[2])!r})
from eye_in_hand.io.atomic import atomic_output_dir, OutputWriteError
out = os.path.join({str(disk)!r}, "out")
with atomic_output_dir(out) as tmp:
    (tmp / "hand_eye.yaml").write_text("old")
try:
    with atomic_output_dir(out, overwrite=True) as tmp:
        (tmp / "hand_eye.yaml").write_text("new")
        (tmp / "big.bin").write_bytes(b"x" * 200_000)
except OutputWriteError as exc:
    print("ERROR", exc)
print(sorted(os.listdir({str(disk)!r})), open(os.path.join(out, "hand_eye.yaml")).read())
"""
    res = subprocess.run(["unshare", "-Urm", "sh", "-c",
                          f"mount -t tmpfs -o size=64k tmpfs '{disk}' && exec \"$0\" -c \"$1\"",
                          sys.executable, script], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0] == (f"ERROR {disk / 'out' / 'big.bin'}: cannot write (No space left on "
                        f"device); the earlier {disk / 'out'} is unchanged"), res.stdout
    assert lines[1] == "['out'] old", res.stdout
