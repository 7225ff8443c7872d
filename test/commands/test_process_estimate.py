"""process states its estimated time and disk before the work, and refuses outputs that cannot
fit on the disk unless --force (docs/reliability.md)."""
from __future__ import annotations

import shutil
from collections import namedtuple
from pathlib import Path

import pytest

from eye_in_hand.commands.process import estimate
from eye_in_hand.errors import InputError

Usage = namedtuple("Usage", "total used free")


def test_the_estimate_line_and_the_refusal(tmp_path: Path, monkeypatch) -> None:
    line = estimate(600, tmp_path / "out")
    assert line.startswith("process: 600 stereo pairs: about 4 s, about 2.5 MB of outputs (")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**9, 10**9, 100_000))
    with pytest.raises(InputError, match="the outputs do not fit on the disk of .*--force"):
        estimate(600, tmp_path / "new" / "out")         # a folder not made yet: its parent
    assert "0 MB free" in estimate(600, tmp_path / "out", force=True)


def test_process_refuses_before_the_work_when_the_disk_is_full(tmp_path: Path, monkeypatch,
                                                               capsys) -> None:
    """The whole command: one line, exit 1, nothing written; --force starts anyway."""
    from eye_in_hand.cli import main

    root = Path(__file__).resolve().parents[2]
    bag = root / "bags" / "localization"
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**9, 10**9, 1000))
    hand_eye = tmp_path / "hand_eye.yaml"
    from eye_in_hand.core.transforms import from_rotvec
    from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye

    save_hand_eye(hand_eye, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=from_rotvec([0, 0, 0], [0, 0, 0.1]), method="refined"))
    out = tmp_path / "results"
    code = main(["process", str(bag), "--hand-eye", str(hand_eye), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "the outputs do not fit on the disk" in err, err
    assert err.count("\n") == 1 and not out.exists()
