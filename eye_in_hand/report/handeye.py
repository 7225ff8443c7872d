"""The files of a hand-eye calibration: ``hand_eye.yaml``, ``report.json`` and ``report.html``.

Shared by ``eye-in-hand calibrate handeye`` and the ``hand_eye`` node's ``hand_eye/save``
service, so both write the same files.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from eye_in_hand.io.atomic import atomic_output_dir
from eye_in_hand.report.html import HtmlReport, format_cell, new_figure

__all__ = ["write_outputs", "save_outputs"]


def _html(result: Any, report: dict[str, Any], path: Path) -> None:
    """``report.html``: the result, the input, each method against the others, the samples,
    the board in the fixed frame and the motion diagnostics."""
    rep = HtmlReport("Hand-eye calibration", f"setup {result.setup}, selected method "
                                            f"{result.selected}")
    _html_result(rep, result, report)
    for w in report["warnings"]:
        rep.add_status("warning", False, w)
    _html_input(rep, report.get("input") or {})
    _html_truth(rep, report)
    _html_budget(rep, report)
    _html_methods(rep, result, report)
    _html_average(rep, report)
    _html_motion_residuals(rep, report, result.selected)
    _html_method_differences(rep, result)
    _html_samples(rep, result, report)
    _html_board(rep, result, report)
    _html_diagnostics(rep, report["diagnostics"])
    rep.save(path)


def _html_result(rep: Any, result: Any, report: dict[str, Any]) -> None:
    """The selected X, its uncertainty, why it was selected and the samples, as a table."""
    rep.add_section("Result")
    sel = report["methods"][result.selected]
    noise = result.robot_pose_noise
    rep.add_table([["translation (mm)", " ".join(f"{1000 * v:.3f}" for v in sel["translation"])],
                   ["quat_xyzw", " ".join(f"{v:.6f}" for v in sel["quat_xyzw"])],
                   ["1-sigma", f"{format_cell(sel['std_mm'], 2)} mm, "
                               f"{format_cell(sel['std_deg'], 2)} deg"],
                   ["selected because", result.selection_reason],
                   ["robot pose noise (1 sigma per axis)",
                    "not estimated" if noise is None else
                    f"{1000 * noise['translation_sigma_m']:.3f} mm, "
                    f"{np.degrees(noise['rotation_sigma_rad']):.4f} deg"],
                   ["samples used", len(result.sample_names)],
                   ["samples rejected", ", ".join(r.name for r in result.rejected) or "none"],
                   ["samples skipped", ", ".join(s["name"] for s in report["skipped"]) or
                    "none"]], header=["quantity", "value"])


def _html_methods(rep: Any, result: Any, report: dict[str, Any]) -> None:
    """Every method's selection score, held-out figures, residuals and uncertainty."""
    rep.add_section("Method comparison")
    rows = []
    for name in result.methods:
        s = report["methods"][name]
        r = s["residuals"]
        h = s["held_out"] or {}
        rows.append([name + (" (selected)" if name == result.selected else ""),
                     result.selection_scores.get(name), h.get("px_rms"), h.get("mm_rms"),
                     h.get("deg_rms"), r["axxb_rot_deg_rms"], r["axxb_trans_mm_rms"],
                     r["board_spread_mm_rms"], r["board_spread_deg_rms"], r["reproj_px_rms"],
                     s["std_mm"], s["std_deg"]])
    rep.add_table(rows, header=["method", "selection score", "held-out px", "held-out mm",
                                "held-out deg", "AX=XB rot deg", "AX=XB trans mm",
                                "board spread mm", "board spread deg", "reproj px", "sigma mm",
                                "sigma deg"], precision=PRECISION)


def _html_method_differences(rep: Any, result: Any) -> None:
    """A figure: each method's X from the selected one (mm, deg)."""
    names = list(result.methods)
    sel_X = result.X
    fig = new_figure(7.0, 3.2)
    ax1, ax2 = fig.subplots(1, 2)
    fig.subplots_adjust(wspace=0.35)
    for i, name in enumerate(names):
        X = result.methods[name].X
        dmm = 1000.0 * np.linalg.norm(X[:3, 3] - sel_X[:3, 3])
        c = np.clip((np.trace(sel_X[:3, :3].T @ X[:3, :3]) - 1) / 2, -1, 1)
        ax1.bar(i, dmm)
        ax2.bar(i, np.degrees(np.arccos(c)))
    for ax, lab in ((ax1, "mm from selected"), (ax2, "deg from selected")):
        ax.set_xticks(range(len(names)), names, rotation=45, ha="right", fontsize=8)
        ax.set_ylabel(lab)
    rep.add_figure(fig, "difference of each method's X from the selected one")


def _html_samples(rep: Any, result: Any, report: dict[str, Any]) -> None:
    """The selected method's per-sample residuals (a figure), and every sample's row: used,
    rejected or skipped."""
    rep.add_section("Per-sample residuals")
    m = result.methods[result.selected]
    fig = new_figure(7.0, 3.2)
    ax1, ax2 = fig.subplots(1, 2)
    fig.subplots_adjust(wspace=0.35)
    x = np.arange(len(result.sample_names))
    ax1.bar(x, m.axxb_trans_mm, label="AX=XB trans (mm)")
    ax1.plot(x, m.board_dev_mm, "k.", label="board dev (mm)")
    ax1.legend(fontsize=7)
    ax2.bar(x, m.axxb_rot_deg, label="AX=XB rot (deg)")
    ax2.plot(x, m.board_dev_deg, "k.", label="board dev (deg)")
    ax2.legend(fontsize=7)
    for ax in (ax1, ax2):
        ax.set_xticks(x, result.sample_names, rotation=90, fontsize=6)
    rep.add_figure(fig, f"per-sample residuals ({result.selected})")
    header = ["sample", "used", "AX=XB deg", "AX=XB mm", "board mm", "board deg",
              "reproj px", "LOO mm", "LOO deg"]
    rows, classes = [], []
    for row in report["samples"]:
        if row["used"]:
            rows.append([row["name"], "yes", row["axxb_rot_deg"], row["axxb_trans_mm"],
                         row["board_dev_mm"], row["board_dev_deg"], row["reproj_rms_px"],
                         row["loo_mm"], row["loo_deg"]])
            classes.append("")
        else:
            rows.append([row["name"], "rejected: " + row["reason"]] + [""] * 7)
            classes.append("bad")
    for s in report["skipped"]:
        rows.append([s["name"], "skipped: " + s["reason"]] + [""] * 7)
        classes.append("warn")
    rep.add_table(rows, header=header, row_classes=classes, precision=PRECISION)


def _html_board(rep: Any, result: Any, report: dict[str, Any]) -> None:
    """A figure: the board origin in the fixed frame per sample, by each method's X."""
    rep.add_section("Board in the fixed frame")
    # local: core.handeye loads SciPy (~0.35 s), and this module loads at CLI start-up
    from eye_in_hand.core.handeye import board_in_fixed_frame

    names_used = result.sample_names
    fig = new_figure(7.0, 3.2)
    ax1, ax2 = fig.subplots(1, 2)
    fig.subplots_adjust(wspace=0.35)
    for name in result.methods:
        mr = result.methods[name]
        bte = report["_bte"]
        ctb = report["_ctb"]
        Yi = board_in_fixed_frame(mr.X, bte, ctb, result.setup)
        d = 1000.0 * (Yi[:, :3, 3] - mr.Y[:3, 3])
        ax1.plot(d[:, 0], d[:, 1], ".", label=name)
        ax2.plot(d[:, 0], d[:, 2], ".", label=name)
    ax1.set_xlabel("x (mm)")
    ax1.set_ylabel("y (mm)")
    ax2.set_xlabel("x (mm)")
    ax2.set_ylabel("z (mm)")
    ax1.legend(fontsize=6)
    rep.add_figure(fig, f"board origin in the fixed frame per sample minus its mean "
                        f"({len(names_used)} samples)")


#: Significant digits of the report's table cells: the residuals and uncertainties are known to
#: a few per cent at best, so a third digit is already below their own scatter.
PRECISION = 3


def _html_input(rep: Any, meta: dict[str, Any]) -> None:
    """What the calibration read (``report.json`` ``input``), as a table."""
    if not meta:
        return
    rep.add_section("Input")
    label = {"type": "input", "path": "path", "board": "board", "stereo": "stereo",
             "count": "samples in the input", "image_topics": "image topics",
             "pose_source": "robot pose from", "summary": "found"}
    rows = []
    for key, name in label.items():
        value = meta.get(key)
        if value is None:
            continue
        if isinstance(value, dict):
            value = ", ".join(f"{k}: {v}" for k, v in value.items())
        rows.append([name, value])
    rep.add_table(rows, header=["quantity", "value"])


def _html_truth(rep: Any, report: dict[str, Any]) -> None:
    """Each method's distance from the true X, when the input carries ground truth."""
    truth = report.get("ground_truth_error")
    if not truth:
        return
    rep.add_section("Against the ground truth (simulated input)")
    rep.add_table([[name + (" (selected)" if name == report["selected"] else ""), e["mm"],
                    e["deg"]] for name, e in truth.items()],
                  header=["method", "mm from the true X", "deg from the true X"],
                  precision=PRECISION)


def _html_diagnostics(rep: Any, diag: dict[str, Any]) -> None:
    """How well the motions constrain X (``report.json`` ``diagnostics``), as a table (its
    warnings are among the report's, shown at the top)."""
    rep.add_section("Motion diagnostics")
    rot = diag["rotation_deg"]
    rep.add_table([
        ["samples", diag["n_samples"]],
        ["motions with a usable rotation (> 0.5 deg)", diag["n_motions"]],
        ["rotation between samples min / median / max (deg)",
         " / ".join(format_cell(rot[k], PRECISION) for k in ("min", "median", "max"))],
        ["largest angle between two motions' rotation axes (deg)",
         format_cell(diag["axis_spread_deg"], PRECISION)],
        ["motion-axis scatter eigenvalues (1, 0, 0: one axis only)",
         ", ".join(format_cell(v, 2) for v in diag["axis_eigenvalues"])],
        ["condition number, rotation / translation",
         f"{format_cell(diag['rotation_condition'], PRECISION)} / "
         f"{format_cell(diag['translation_condition'], PRECISION)}"],
    ], header=["quantity", "value"])


#: Most motion rows in the HTML table (report.json always has them all).
HTML_MOTION_ROWS = 200


def _html_budget(rep: Any, report: dict[str, Any]) -> None:
    """The error budget table (:mod:`eye_in_hand.core.handeye.budget`), when computed."""
    b = report.get("error_budget")
    if not b:
        return
    rep.add_section("Error budget (held-out board position, mm RMS)")
    label = {"camera_mm": "camera (corners, intrinsics within a view)",
             "robot_mm": "robot and per-pose scatter",
             "estimate_mm": "the estimate (X, Y, robot model) at unseen poses",
             "held_out_mm": "held-out total",
             "robot_systematic_mm": "pose-dependent robot error found by the systematic model"}
    rows = [[label[k], b[k]] for k in label if b.get(k) is not None]
    rows.append(["largest part", f"{b['largest']}: {b['advice']}"])
    rep.add_table(rows, header=["part", "mm"], precision=PRECISION)


def _html_average(rep: Any, report: dict[str, Any]) -> None:
    """The per-motion-pair average's counts and spread."""
    avg = (report["methods"].get("average") or {}).get("average")
    if avg is None:
        return
    rep.add_heading("average: X from each pair of motions, averaged")
    sk, th, sp = avg["skipped"], avg["thresholds"], avg["spread"]
    rep.add_table([
        ["per-pair solver", avg["solver"]],
        ["rotation mean", avg["rotation_mean"]],
        ["motions / pairs of motions", f"{avg['n_motions']} / {avg['n_pairs_candidates']}"],
        ["pairs used", avg["n_pairs_used"]],
        [f"skipped: a robot rotation under {th['min_rotation_deg']:g} deg",
         sk["small_rotation"]],
        [f"skipped: rotation axes within {th['min_axis_angle_deg']:g} deg", sk["parallel_axes"]],
        ["skipped: degenerate per-pair system", sk["degenerate"]],
        [f"not solved (random subset of {th['max_pairs']} kept)", sk["subsampled_out"]],
        ["spread of the per-pair solutions: rotation RMS / max (deg)",
         f"{sp['rot_std_deg']:.4g} / {sp['rot_max_deg']:.4g}"],
        ["spread of the per-pair solutions: translation RMS / max (mm)",
         f"{sp['trans_std_mm']:.4g} / {sp['trans_max_mm']:.4g}"],
    ], header=["quantity", "value"])


def _html_motion_residuals(rep: Any, report: dict[str, Any], selected: str) -> None:
    """Per-method summary and per-motion table of the AX = XB residuals."""
    table = report["motion_residuals"]
    methods = table["methods"]
    rep.add_section("Per-motion AX = XB residuals")
    rep.add_paragraph(f"{len(table['motions'])} motions (every pair of samples); rotation: angle "
                      "of inv(AX) XB (deg); translation: its norm (mm); Frobenius: ||AX - XB|| "
                      "with translations in metres.")
    rows = []
    for name in methods:
        s = table["summary"][name]
        rows.append([name + (" (selected)" if name == selected else "")]
                    + [s[q][k] for q in ("rot_deg", "trans_mm", "frobenius")
                       for k in ("mean", "median", "max")])
    rep.add_table(rows, header=["method"] + [f"{q} {k}" for q in ("rot deg", "trans mm", "Frob")
                                             for k in ("mean", "median", "max")],
                  precision=PRECISION)
    n = len(table["motions"])
    order = list(range(n))
    if n > HTML_MOTION_ROWS:
        key = table["trans_mm"][selected] if selected in table["trans_mm"] else [0.0] * n
        order = sorted(order, key=lambda k: -key[k])[:HTML_MOTION_ROWS]
        rep.add_paragraph(f"the {HTML_MOTION_ROWS} motions with the largest translation "
                          f"residual of {selected} (all {n} in report.json)")
    rows = [[f"{table['motions'][k][0]} - {table['motions'][k][1]}"]
            + [f"{table['rot_deg'][m][k]:.3g} / {table['trans_mm'][m][k]:.3g} / "
               f"{table['frobenius'][m][k]:.3g}" for m in methods] for k in order]
    rep.add_table(rows, header=["motion (samples)"] + [f"{m} deg / mm / Frob" for m in methods])


def write_outputs(out: Path, result: Any, samples: list[Any], *, setup: str, parent_frame: str,
                  child_frame: str, input_meta: dict[str, Any],
                  skipped: list[dict[str, str]] | None = None, notes: list[str] | None = None,
                  ground_truth: dict[str, Any] | None = None, html: bool = True) -> list[Path]:
    """Write ``hand_eye.yaml``, ``report.json`` and (``html``) ``report.html`` into ``out``.

    Shared by ``eye-in-hand calibrate handeye`` and the ``hand_eye`` node's ``hand_eye/save``
    service, so both produce the same files.

    Returns:
        The paths written.
    """
    # local: this module loads at CLI start-up, where core.handeye (SciPy) would cost ~0.35 s
    # and core.transforms with io.config ~6 ms
    from eye_in_hand.core.handeye.residuals import motion_residual_table
    from eye_in_hand.core.transforms import transform_distance
    from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye

    skipped = list(skipped or [])
    out.mkdir(parents=True, exist_ok=True)
    sel = result.methods[result.selected]
    residuals = {k: v for k, v in sel.summary()["residuals"].items()}
    calib = HandEyeCalibration(setup=setup, parent_frame=parent_frame, child_frame=child_frame,
                               transform=result.X, method=result.selected,
                               covariance=result.covariance,
                               sample_count=len(result.sample_names), residuals=residuals,
                               robot_pose_noise=result.robot_pose_noise,
                               # eye-to-hand: X = base_T_cam is used without robot poses
                               robot_pose_correction=(result.pose_correction
                                                      if setup == "eye_in_hand" else None))
    save_hand_eye(out / "hand_eye.yaml", calib)
    report = result.to_report()
    report["input"] = input_meta
    report["skipped"] = skipped
    report["warnings"] = list(notes or []) + report["warnings"]
    report["frames"] = {"parent": parent_frame, "child": child_frame}
    report["covariance_order"] = ["x", "y", "z", "rx", "ry", "rz"]
    by_name = {s.name: s for s in samples}
    used_samples = [by_name[name] for name in result.sample_names]
    report["motion_residuals"] = motion_residual_table(
        {k: v.X for k, v in result.methods.items()},
        np.stack([s.base_T_ee for s in used_samples]),
        np.stack([s.cam_T_board for s in used_samples]), setup, result.sample_names)
    truth = ground_truth or {}
    key = "ee_T_cam" if setup == "eye_in_hand" else "base_T_cam"
    if key in truth:
        report["ground_truth_error"] = {}
        for name, mr in result.methods.items():
            dt, dr = transform_distance(truth[key], mr.X)
            report["ground_truth_error"][name] = {"mm": 1000.0 * dt,
                                                  "deg": float(np.degrees(dr))}
    (out / "report.json").write_text(json.dumps(report, indent=2))
    paths = [out / "hand_eye.yaml", out / "report.json"]
    if html:
        used = set(result.sample_names)
        report["_bte"] = np.stack([s.base_T_ee for s in samples if s.name in used])
        report["_ctb"] = np.stack([s.cam_T_board for s in samples if s.name in used])
        _html(result, report, out / "report.html")
        paths.append(out / "report.html")
    return paths


def save_outputs(out: Path, result: Any, samples: list[Any], skipped: list[tuple[str, str]], *,
                 setup: str, parent_frame: str, child_frame: str, source: str,
                 overwrite: bool = False, option: str = "-o",
                 hint: str = "give --overwrite to replace it") -> list[Path]:
    """:func:`write_outputs` of a live calibration session into the folder ``out``, written
    whole under a temporary name, then renamed into place
    (:func:`eye_in_hand.io.atomic.atomic_output_dir`): ``hand_eye.yaml``, ``report.json`` and
    ``report.html`` (the ``hand_eye`` node's ``hand_eye/save``).

    Args:
        out: the output folder.
        result: the session's :class:`~eye_in_hand.core.handeye.HandEyeResult`.
        samples: its samples; ``skipped``: its ``(name, reason)`` of the captures refused.
        setup, parent_frame, child_frame: X's setup and frames.
        source: what took the samples (``report.json``'s ``input.source``).
        overwrite: replace an existing non-empty ``out``.
        option, hint: how messages name ``out`` and how to allow replacing it.

    Returns:
        The files written, in ``out``.

    Raises:
        OutputError: ``out`` exists and ``overwrite`` is False, or writing failed (``out``
            is then unchanged).
    """
    rows = [{"name": n, "reason": r} for n, r in skipped]
    with atomic_output_dir(out, overwrite=overwrite, option=option, hint=hint) as tmp:
        paths = write_outputs(tmp, result, samples, setup=setup, parent_frame=parent_frame,
                              child_frame=child_frame,
                              input_meta={"source": source, "count": len(samples) + len(rows)},
                              skipped=rows)
    return [Path(out) / p.name for p in paths]
