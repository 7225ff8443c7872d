"""HTML reports of camera and stereo calibrations (plots embedded as PNG, matplotlib Agg).

:func:`camera_report` and :func:`stereo_report` turn the results of
:func:`eye_in_hand.core.calibration.calibrate_camera` / ``calibrate_stereo`` into an
:class:`~eye_in_hand.report.html.HtmlReport`: summary and quality checks, parameters with their
standard deviations, per-view error bars, residual scatter, coverage map, and for a stereo rig one
rectified pair with epipolar lines.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from matplotlib import colormaps

from eye_in_hand.report.html import HtmlReport, new_figure, value_and_std

__all__ = ["camera_report", "stereo_report", "per_view_figure", "residual_figure",
           "coverage_figure", "rectified_pair_image"]

_DIST = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def per_view_figure(names: Sequence[str], rms: Sequence[float], used: Sequence[bool],
                    outlier: Sequence[bool], threshold: float, overall: float,
                    title: str = "Per-view RMS reprojection error"):
    """Bar chart of per-view RMS (blue used, red outlier, grey unused) with the threshold."""
    fig = new_figure(max(6.0, 0.28 * len(names) + 2.0), 3.4)
    ax = fig.add_subplot(1, 1, 1)
    vals = np.array([np.nan if r is None else float(r) for r in rms])
    colors = ["#c62828" if o else ("#1f77b4" if u else "#9e9e9e")
              for u, o in zip(used, outlier, strict=True)]
    x = np.arange(len(names))
    ax.bar(x, np.nan_to_num(vals), color=colors)
    if np.isfinite(threshold):
        ax.axhline(threshold, color="#c62828", ls="--", lw=1, label=f"outlier threshold "
                   f"{threshold:.3f} px")
    ax.axhline(overall, color="k", ls=":", lw=1, label=f"overall RMS {overall:.3f} px")
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=70, ha="right", fontsize=7)
    ax.set_ylabel("RMS [px]")
    ax.set_title(title)
    ax.legend(fontsize=8)
    return fig


def residual_figure(residual_sets: Sequence[tuple[str, Sequence[np.ndarray]]]):
    """Scatter of reprojection residuals (dx, dy) per camera, one panel each."""
    fig = new_figure(4.2 * len(residual_sets), 4.0)
    for k, (label, sets) in enumerate(residual_sets):
        ax = fig.add_subplot(1, len(residual_sets), k + 1)
        allres = [np.asarray(r) for r in sets if r is not None and len(r)]
        if allres:
            cmap = _cmap(len(allres))
            for i, r in enumerate(allres):
                ax.scatter(r[:, 0], r[:, 1], s=3, color=cmap(i), alpha=0.7)
            cat = np.concatenate(allres)
            lim = max(0.5, float(np.nanpercentile(np.abs(cat), 99.5)) * 1.15)
            rms = float(np.sqrt(np.nanmean(np.sum(cat ** 2, axis=1))))
            circle = np.linspace(0, 2 * np.pi, 100)
            ax.plot(rms * np.cos(circle), rms * np.sin(circle), "k--", lw=1,
                    label=f"RMS {rms:.3f} px")
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.legend(fontsize=8, loc="upper right")
        ax.set_aspect("equal")
        ax.axhline(0, color="#999", lw=0.5)
        ax.axvline(0, color="#999", lw=0.5)
        ax.set_xlabel("dx [px]")
        ax.set_ylabel("dy [px]")
        ax.set_title(f"{label}: residuals (observed - reprojected)")
    return fig


def _cmap(n: int):
    base = colormaps["tab20"]
    return lambda i: base(i % 20)


def coverage_figure(panels: Sequence[tuple[str, np.ndarray, tuple[int, int],
                                           Sequence[np.ndarray], float]]):
    """Coverage maps: boards per image region, with the used corners; one panel per camera.

    Args:
        panels: ``(label, counts (h, w), (width, height), corner sets, fraction)``.
    """
    fig = new_figure(5.6 * len(panels), 3.6)
    for k, (label, counts, size, corners, frac) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1)
        im = ax.imshow(counts, extent=(0, size[0], size[1], 0), cmap="viridis",
                       interpolation="nearest")
        for c in corners:
            ax.plot(c[:, 0], c[:, 1], ".", ms=1.5, color="w", alpha=0.6)
        ax.set_xlim(0, size[0])
        ax.set_ylim(size[1], 0)
        ax.set_title(f"{label}: {100 * frac:.0f} % of the image covered")
        fig.colorbar(im, ax=ax, fraction=0.035, label="boards")
    return fig


def rectified_pair_image(rig: Any, left: np.ndarray, right: np.ndarray,
                         left_corners: np.ndarray | None = None,
                         right_corners: np.ndarray | None = None,
                         line_step: int = 32, max_width: int = 1400) -> np.ndarray:
    """Side-by-side rectified images with horizontal epipolar lines (BGR uint8).

    Args:
        rig: a rectified :class:`StereoRig`.
        left, right: raw images (gray or BGR).
        left_corners, right_corners: optional raw corner pixels, drawn after rectification.
        line_step: pixels between the drawn epipolar lines.
        max_width: the output is scaled down to at most this width.
    """
    out = []
    for cam, img, corners, colour in ((rig.left, left, left_corners, (0, 0, 255)),
                                      (rig.right, right, right_corners, (255, 0, 0))):
        img = np.asarray(img)
        if img.dtype != np.uint8:
            img = cv2.convertScaleAbs(img, alpha=255.0 / max(1.0, float(img.max())))
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        m1, m2 = cv2.initUndistortRectifyMap(cam.K, cam.dist, cam.R, cam.P[:3, :3], cam.size,
                                             cv2.CV_32FC1)
        rect = cv2.remap(img[:, :, :3], m1, m2, cv2.INTER_LINEAR)
        if corners is not None and len(corners):
            for x, y in cam.rectify_points(corners):
                cv2.circle(rect, (int(round(x)), int(round(y))), 3, colour, 1, cv2.LINE_AA)
        out.append(rect)
    pair = np.hstack(out)
    for y in range(line_step // 2, pair.shape[0], line_step):
        cv2.line(pair, (0, y), (pair.shape[1] - 1, y), (0, 200, 0), 1, cv2.LINE_AA)
    if pair.shape[1] > max_width:
        scale = max_width / pair.shape[1]
        pair = cv2.resize(pair, (max_width, int(round(pair.shape[0] * scale))),
                          interpolation=cv2.INTER_AREA)
    return pair


def _param_rows(cam: Any, std: dict) -> list[list[Any]]:
    vals = {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
    vals.update({n: float(v) for n, v in zip(_DIST, cam.dist, strict=False)})
    return [[n, *value_and_std(v, std.get(n))] for n, v in vals.items()]


def _skipped_table(report: HtmlReport, skipped: Sequence[dict]) -> None:
    if skipped:
        report.add_heading(f"Images without a usable board ({len(skipped)})")
        report.add_table([[s["file"], s["reason"]] for s in skipped], header=["image", "reason"],
                         row_classes=["warn"] * len(skipped))


def camera_report(cal: Any, source: Any, board: Any, sample_image: np.ndarray | None = None,
                  skipped: Sequence[dict] | None = None) -> HtmlReport:
    """The report of a mono calibration.

    Args:
        cal: a :class:`CameraCalibration`.
        source: the command's image source (``kind``, ``description``, ``frames``).
        board: the board.
        sample_image: one input image, shown undistorted next to the original.
        skipped: images without a board (``file``, ``reason``); default: from ``source``.
    """
    cam = cal.camera
    if skipped is None:
        skipped = [{"file": f.name, "reason": f.detection.reason}
                   for f in source.frames if not f.detection.found]
    report = HtmlReport("Camera calibration",
                        f"board {board}; input: {source.kind} {source.description}")
    report.add_section("Summary")
    outliers = [v.name for v in cal.views if v.outlier]
    report.add_table([
        ["images", len(source.frames)],
        ["views used", len(cal.used_views)],
        ["images without a board", len(skipped)],
        ["overall RMS [px]", cal.rms_px],
        ["outlier threshold [px]", cal.outlier_threshold_px],
        ["outliers", ", ".join(outliers) or "none"],
        ["rejected (--reject-outliers)", ", ".join(cal.rejected) or "none"],
        ["image coverage", f"{100 * cal.coverage:.0f} %"],
        ["image size", f"{cam.width} x {cam.height}"],
        ["distortion model", cam.distortion_model],
    ], header=["quantity", "value"])
    report.add_status("reprojection RMS below 0.5 px", cal.rms_px < 0.5, f"{cal.rms_px:.4f} px")
    report.add_status("boards cover at least half of the image", cal.coverage >= 0.5,
                      f"{100 * cal.coverage:.0f} %; add views near the image borders and corners"
                      if cal.coverage < 0.5 else f"{100 * cal.coverage:.0f} %")
    report.add_section("Parameters (1-sigma from the Jacobian)")
    report.add_table(_param_rows(cam, cal.std), header=["parameter", "value", "std"])
    report.add_section("Per-view errors")
    views = list(cal.views)
    report.add_figure(per_view_figure([v.name for v in views], [v.rms_px for v in views],
                                      [v.used for v in views], [v.outlier for v in views],
                                      cal.outlier_threshold_px, cal.rms_px))
    report.add_table([[v.name, v.n_points, v.rms_px, v.used, v.outlier] for v in views],
                     header=["view", "corners", "RMS [px]", "used", "outlier"],
                     row_classes=["bad" if v.outlier else "" for v in views])
    _skipped_table(report, skipped)
    report.add_section("Residuals")
    report.add_figure(residual_figure([("camera", [v.residuals for v in cal.used_views])]))
    report.add_section("Coverage")
    report.add_figure(coverage_figure([("camera", cal.coverage_map, cam.size,
                                        [v.corners for v in cal.used_views], cal.coverage)]))
    if sample_image is not None:
        report.add_section("Undistortion example")
        img = sample_image
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        und = cv2.undistort(img, cam.K, cam.dist)
        pair = np.hstack([img[:, :, :3], und[:, :, :3]])
        if pair.shape[1] > 1400:
            s = 1400 / pair.shape[1]
            pair = cv2.resize(pair, (1400, int(pair.shape[0] * s)), interpolation=cv2.INTER_AREA)
        report.add_image_array(pair, "first image: original (left) and undistorted (right)")
    return report


def stereo_report(cal: Any, names: Sequence[tuple[str, str]], board: Any, description: str,
                  skipped: Sequence[dict],
                  pair_images: tuple[np.ndarray, np.ndarray] | None = None,
                  pair_corners: tuple[np.ndarray, np.ndarray] | None = None,
                  pair_name: str = "") -> HtmlReport:
    """The report of a stereo calibration.

    Args:
        cal: a :class:`StereoCalibration`.
        names: ``(left, right)`` image names per pair.
        board: the board.
        description: where the images came from.
        skipped: images without a board (``file``, ``reason``).
        pair_images: one raw ``(left, right)`` pair to show rectified with epipolar lines.
        pair_corners: its detected corners ``(left (N,2), right (N,2))``.
        pair_name: its name.
    """
    rig = cal.rig
    d = cal.to_dict()
    report = HtmlReport("Stereo calibration", f"board {board}; input: {description}")
    _stereo_summary(report, cal, d["stereo"], len(names), board, len(skipped))
    _stereo_parameters(report, cal, d)
    _stereo_pairs(report, cal, skipped)
    views = list(cal.views)
    report.add_section("Residuals")
    report.add_figure(residual_figure([
        ("left", [v.left_residuals for v in views if v.used]),
        ("right", [v.right_residuals for v in views if v.used])]))
    report.add_section("Coverage")
    report.add_figure(coverage_figure([
        ("left", cal.left.coverage_map, rig.left.size,
         [v.corners for v in cal.left.used_views], cal.left.coverage),
        ("right", cal.right.coverage_map, rig.right.size,
         [v.corners for v in cal.right.used_views], cal.right.coverage)]))
    if pair_images is not None:
        report.add_section("Rectified pair")
        lc, rc = pair_corners if pair_corners is not None else (None, None)
        img = rectified_pair_image(rig, pair_images[0], pair_images[1], lc, rc)
        report.add_image_array(img, f"{pair_name}: rectified left and right images; corners "
                                    "of a good calibration sit on the same green line")
    return report


def _stereo_summary(report: HtmlReport, cal: Any, st: dict, n_pairs: int, board: Any,
                    n_skipped: int) -> None:
    """The summary table of a stereo calibration (``st``: its ``to_dict()["stereo"]``) and
    the three checks of a good one."""
    rig, q = cal.rig, cal.quality
    report.add_section("Summary")
    report.add_table([
        ["image pairs", n_pairs],
        ["pairs used (board in both images)", st["n_pairs_used"]],
        ["images without a usable board", n_skipped],
        ["joint RMS [px]", cal.rms_px],
        ["left / right RMS in the joint fit [px]",
         f"{cal.side_rms('left'):.4f} / {cal.side_rms('right'):.4f}"],
        ["baseline |T| [mm]", " ± ".join(value_and_std(rig.baseline, cal.std["baseline"],
                                                        1000.0))],
        ["T (X_right = R X_left + T) [mm]", " ".join(f"{1000 * v:.3f}" for v in rig.T)],
        ["rotation between cameras [deg]", st["rotation_deg"]],
        ["epipolar error mean / max [px]",
         f"{q.epipolar_error_px:.4f} / {q.epipolar_error_max_px:.3f}"],
        ["rectified |dy| mean / max [px]",
         f"{q.rectified_dy_mean_px:.4f} / {q.rectified_dy_max_px:.3f}"],
        ["square measured by triangulation (mean ± std) [mm]",
         " ± ".join(value_and_std(q.square_measured_mean, q.square_measured_std, 1000.0))
         + f" (board: {1000 * board.square:g})"],
        ["joint refinement", f"{cal.method}" + (" (intrinsics fixed)" if cal.fix_intrinsics
                                                 else " (all parameters free)")],
        ["rectification alpha", cal.alpha],
        ["outliers", ", ".join(st["outliers"]) or "none"],
        ["rejected (--reject-outliers)", ", ".join(cal.rejected) or "none"],
    ], header=["quantity", "value"])
    rel = abs(q.square_measured_mean - board.square) / board.square
    report.add_status("rectified rows agree (mean |dy| <= 0.5 px)", q.rectified_dy_mean_px <= 0.5,
                      f"{q.rectified_dy_mean_px:.3f} px")
    report.add_status("square length measured back within 1 %", rel <= 0.01, f"{100 * rel:.2f} %")
    report.add_status("joint RMS below 0.5 px", cal.rms_px < 0.5, f"{cal.rms_px:.4f} px")


def _stereo_parameters(report: HtmlReport, cal: Any, d: dict) -> None:
    """Each camera's parameters and the extrinsic, with their standard deviations."""
    rig = cal.rig
    report.add_section("Parameters (1-sigma from the joint fit's Jacobian)")
    for side, cam in (("left", rig.left), ("right", rig.right)):
        report.add_heading(f"{side} camera")
        report.add_table(_param_rows(cam, d[side]["std"]), header=["parameter", "value", "std"])
    report.add_heading("extrinsic")
    ext = [[f"T.{a} [mm]", *value_and_std(rig.T[i], cal.std[f"T.{a}"], 1000.0)]
           for i, a in enumerate("xyz")]
    rv = _rvec(rig.R)
    ext += [[f"R.r{a} (rotation vector) [deg]",
             *value_and_std(np.degrees(rv[i]), np.degrees(cal.std[f"R.r{a}"]))]
            for i, a in enumerate("xyz")]
    ext.append(["baseline [mm]", *value_and_std(rig.baseline, cal.std["baseline"], 1000.0)])
    report.add_table(ext, header=["parameter", "value", "std"])


def _stereo_pairs(report: HtmlReport, cal: Any, skipped: Sequence[dict]) -> None:
    """Every pair's RMS in the joint fit (a figure and a table), and the skipped images."""
    report.add_section("Per-pair errors (joint fit)")
    views = list(cal.views)
    report.add_figure(per_view_figure([v.name for v in views], [v.rms_px for v in views],
                                      [v.used for v in views], [v.outlier for v in views],
                                      cal.outlier_threshold_px, cal.rms_px,
                                      "Per-pair RMS reprojection error (both cameras)"))
    report.add_table([[v.name, v.right_name, v.left_found, v.right_found, v.n_points, v.rms_px,
                       v.used, v.paired, v.outlier] for v in views],
                     header=["left", "right", "board left", "board right", "corners", "RMS [px]",
                             "used", "paired", "outlier"],
                     row_classes=["bad" if v.outlier else ("warn" if not v.used else "")
                                  for v in views])
    _skipped_table(report, skipped)


def _rvec(R: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel()
