"""The ``hand_eye`` node's calibration-mode files: the cameras read, the folder saved, a load.

:class:`CalibrationFiles` is a part of the calibration mode
(:class:`eye_in_hand.nodes.hand_eye_calibration.CalibrationMode`), built with explicit
arguments and free of ROS: the board (``board``) and the cameras of ``calibration_dir``
(:meth:`~CalibrationFiles.board_and_views`), ``hand_eye/save``'s folder
(:func:`eye_in_hand.report.handeye.save_outputs`: ``hand_eye.yaml``, ``report.json``,
``report.html``, written whole; an existing folder is replaced only when it is this node's
own earlier save, or with ``overwrite``), and ``~/calibration/load``'s ``hand_eye.yaml``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from eye_in_hand.core.calibration import BoardSpec
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.handeye import HandEyeResult
from eye_in_hand.core.handeye.observe import rig_views
from eye_in_hand.core.handeye.samples import CameraView, HandEyeSample
from eye_in_hand.errors import ConfigError, EyeInHandError
from eye_in_hand.io.config import HandEyeCalibration, load_hand_eye
from eye_in_hand.report.handeye import save_outputs

__all__ = ["CalibrationFiles"]


class CalibrationFiles:
    """The calibration mode's files (see the module docstring).

    Args:
        config: the node's configuration (``board``, ``calibration_dir``, ``setup``, the
            frames, ``output_dir``, ``overwrite_output``).
    """

    def __init__(self, config: Any) -> None:
        self.config = config
        self._saved_dir: Path | None = None   # what save wrote (it may replace that)

    def board_and_views(self) -> tuple[BoardSpec, list[CameraView]]:
        """The board of ``board`` and the cameras of ``calibration_dir`` (a stereo rig's
        ``left.yaml`` + ``right.yaml``, or a mono ``camera.yaml``).

        Raises:
            ConfigError: naming the parameter.
        """
        try:
            board = BoardSpec.parse(self.config.board)
        except EyeInHandError as exc:
            raise ConfigError(f"board: {exc}") from exc
        cdir = Path(self.config.calibration_dir)
        try:
            if (cdir / "left.yaml").exists():
                return board, rig_views(rig=StereoRig.load(cdir))
            if (cdir / "camera.yaml").exists():
                return board, rig_views(camera=CameraModel.load_yaml(cdir / "camera.yaml"))
        except ConfigError:
            raise
        except EyeInHandError as exc:
            raise ConfigError(f"calibration_dir: {exc}") from exc
        raise ConfigError(f"calibration_dir: {cdir} has neither left.yaml + right.yaml "
                          "nor camera.yaml")

    def save(self, path: str, overwrite: bool, result: HandEyeResult,
             samples: list[HandEyeSample], skipped: list[tuple[str, str]]
             ) -> tuple[bool, str, list[str]]:
        """Write ``result`` of ``samples`` (and the refused captures) to ``path`` (default
        ``output_dir``): success, one line, the files."""
        cfg = self.config
        out = Path(path or cfg.output_dir)
        own = self._saved_dir is not None and out.absolute() == self._saved_dir
        try:  # written whole under a temporary name, then renamed into place
            paths = save_outputs(
                out, result, samples, skipped, setup=cfg.setup,
                parent_frame=cfg.base_frame if cfg.setup == "eye_to_hand" else cfg.ee_frame,
                child_frame=cfg.camera_frame, source="hand_eye node",
                overwrite=overwrite or cfg.overwrite_output or own,
                option="the save path" if path else "parameter 'output_dir'",
                hint="call save with overwrite: true (or set overwrite_output:=true) to "
                     "replace it")
        except (EyeInHandError, OSError) as exc:
            return False, f"save failed: {exc}", []
        self._saved_dir = out.absolute()
        files = [str(p) for p in paths]
        return True, "wrote " + ", ".join(files), files

    def load(self, path: str) -> tuple[Path, HandEyeCalibration]:
        """A saved calibration (a ``hand_eye.yaml`` or its folder): the file read and its
        calibration.

        Raises:
            EyeInHandError: it cannot be read, or calibrates another setup than ``setup``.
        """
        file = Path(path)
        if file.is_dir():
            file = file / "hand_eye.yaml"
        calib = load_hand_eye(file)
        if calib.setup != self.config.setup:
            raise ConfigError(f"{file}: setup {calib.setup}, but this node calibrates "
                              f"{self.config.setup} (parameter 'setup')")
        return file, calib
