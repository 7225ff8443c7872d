"""The debug image of a located stereo pair: both images side by side, the detections drawn.

``detect_triangulate`` publishes it on ``target/debug_image``. OpenCV only.
"""
from __future__ import annotations

import cv2
import numpy as np

from eye_in_hand.core.locator import LocateResult

__all__ = ["draw_located_pair"]


def draw_located_pair(left: np.ndarray, right: np.ndarray, result: LocateResult) -> np.ndarray:
    """Left|right side by side at half size, detections drawn (bbox, centre, 3-D point).

    Args:
        left, right: BGR uint8 images, shape (H, W, 3).
        result: the locator's result for the pair.

    Returns:
        BGR uint8, shape (H // 2, W, 3) (two half-size images side by side).
    """
    h, w = left.shape[:2]
    hw, hh = w // 2, h // 2
    canvas = np.hstack([cv2.resize(left, (hw, hh), interpolation=cv2.INTER_AREA),
                        cv2.resize(right, (hw, hh), interpolation=cv2.INTER_AREA)])
    for t in result.targets:
        for det, px, dx in ((t.left, t.left_px, 0), (t.right, t.right_px, hw)):
            x, y, bw, bh = det.bbox
            cv2.rectangle(canvas, (dx + x // 2, y // 2), (dx + (x + bw) // 2, (y + bh) // 2),
                          (0, 255, 0), 1)
            c = (int(round(dx + px[0] / 2)), int(round(px[1] / 2)))
            cv2.drawMarker(canvas, c, (255, 255, 0), cv2.MARKER_CROSS, 10, 1)
        x, y, _, _ = t.left.bbox
        label = (f"{t.name} [{t.point_m[0]:+.3f} {t.point_m[1]:+.3f} {t.point_m[2]:.3f}] m "
                 f"r={t.residual_px:.2f}px")
        cv2.putText(canvas, label, (max(0, x // 2), max(12, y // 2 - 4)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    for name, reason in result.rejected.items():
        cv2.putText(canvas, f"{name}: {reason}", (5, hh - 8 - 14 * list(result.rejected).index(
            name)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 255), 1, cv2.LINE_AA)
    return canvas
