"""A small builder for self-contained HTML reports.

One file, no external resources: figures are rendered with matplotlib's Agg backend and embedded
as base64 PNG ``data:`` URIs, styles are inline. Used by the camera, stereo and hand-eye
calibration reports.

Example::

    report = HtmlReport("Stereo calibration")
    report.add_section("Summary")
    report.add_table([["RMS", "0.21 px"]], header=["quantity", "value"])
    fig = new_figure(6, 3)
    fig.gca().plot([1, 2, 3])
    report.add_figure(fig, caption="something")
    report.save("out/report.html")
"""
from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from eye_in_hand.io.atomic import atomic_write_text

__all__ = ["HtmlReport", "new_figure", "format_cell", "value_and_std"]

_STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;
max-width:1100px;color:#222;line-height:1.4;padding:0 1em}
h1{border-bottom:2px solid #444;padding-bottom:.2em}
h2{border-bottom:1px solid #bbb;padding-bottom:.1em;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0 1.2em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right;font-variant-numeric:tabular-nums}
th{background:#f0f0f0}td.t,th.t{text-align:left}
tr.bad td{background:#fde2e2}tr.warn td{background:#fff4d6}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.9em;color:#555}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.85em}
p.meta{color:#777;font-size:.85em}
.ok{color:#1a7f37;font-weight:600}.fail{color:#c62828;font-weight:600}
"""


def new_figure(width_in: float = 7.0, height_in: float = 4.0, **kwargs: Any):
    """A matplotlib Figure on the Agg canvas, independent of pyplot's global state.

    Args:
        width_in: width in inches.
        height_in: height in inches.
        **kwargs: passed to ``matplotlib.figure.Figure``.

    Returns:
        ``matplotlib.figure.Figure`` (attach axes with ``fig.add_subplot`` or ``fig.subplots``).
    """
    # local: matplotlib costs ~0.6 s, and this module loads at CLI start-up (report.handeye)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), **kwargs)
    FigureCanvasAgg(fig)
    return fig


def format_cell(value: Any, precision: int = 4) -> str:
    """Text of one table cell: floats with ``precision`` significant digits, others via str."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if value != value:  # NaN
            return "–"
        return f"{value:.{precision}g}"
    if isinstance(value, np.floating):
        return format_cell(float(value), precision)
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def value_and_std(value: float, std: float | None, scale: float = 1.0) -> tuple[str, str]:
    """A value and its 1-sigma as table text, to the digits the sigma supports: the sigma with
    two significant digits, the value to the same decimal place (``902.590``, ``0.067``).
    Without a finite sigma, the value with six significant digits and ``–``. ``scale``
    multiplies both (e.g. 1000 for metres shown in mm)."""
    value = float(value) * scale
    if std is None or not np.isfinite(std) or float(std) <= 0.0:
        return format_cell(value, 6), "–"
    std = float(std) * scale
    decimals = max(0, 1 - int(np.floor(np.log10(std))))
    return f"{value:.{decimals}f}", f"{std:.{decimals}f}"


class HtmlReport:
    """Builds one self-contained HTML page section by section.

    Args:
        title: page title and top heading.
        subtitle: optional line under the title (e.g. the command that produced the report).
    """

    def __init__(self, title: str, subtitle: str = "") -> None:
        self.title = str(title)
        self.subtitle = str(subtitle)
        self._parts: list[str] = []

    # -- content --------------------------------------------------------------------------------
    def add_section(self, title: str) -> HtmlReport:
        """Start a new section with a level-2 heading."""
        self._parts.append(f"<h2>{html.escape(str(title))}</h2>")
        return self

    def add_heading(self, title: str, level: int = 3) -> HtmlReport:
        """A heading of level 2..6."""
        level = min(6, max(2, int(level)))
        self._parts.append(f"<h{level}>{html.escape(str(title))}</h{level}>")
        return self

    def add_paragraph(self, text: str) -> HtmlReport:
        """A paragraph of plain text (escaped)."""
        self._parts.append(f"<p>{html.escape(str(text))}</p>")
        return self

    def add_status(self, label: str, ok: bool, detail: str = "") -> HtmlReport:
        """A pass/fail line, e.g. an accuracy check against a threshold."""
        cls, word = ("ok", "PASS") if ok else ("fail", "CHECK")
        self._parts.append(f"<p><span class='{cls}'>{word}</span> {html.escape(label)}"
                           f"{(' — ' + html.escape(detail)) if detail else ''}</p>")
        return self

    def add_preformatted(self, text: str) -> HtmlReport:
        """A block of monospaced text (escaped)."""
        self._parts.append(f"<pre>{html.escape(str(text))}</pre>")
        return self

    def add_table(self, rows: Iterable[Sequence[Any]], header: Sequence[str] | None = None, *,
                  row_classes: Sequence[str] | None = None, precision: int = 4) -> HtmlReport:
        """A table; numbers are right-aligned, the first column left-aligned.

        Args:
            rows: rows of cells (any values; floats are shown with ``precision`` digits).
            header: column titles.
            row_classes: per-row CSS class, ``"bad"`` (red) or ``"warn"`` (yellow) or ``""``.
            precision: significant digits of float cells.
        """
        out = ["<table>"]
        if header is not None:
            cells = "".join(f"<th class='t'>{html.escape(str(h))}</th>" if i == 0 else
                            f"<th>{html.escape(str(h))}</th>" for i, h in enumerate(header))
            out.append(f"<tr>{cells}</tr>")
        for r, row in enumerate(rows):
            cls = row_classes[r] if row_classes is not None and r < len(row_classes) else ""
            cells = "".join(
                ("<td class='t'>" if i == 0 else "<td>") + html.escape(format_cell(v, precision))
                + "</td>" for i, v in enumerate(row))
            out.append(f"<tr class='{cls}'>{cells}</tr>" if cls else f"<tr>{cells}</tr>")
        out.append("</table>")
        self._parts.append("".join(out))
        return self

    def add_image_png(self, png: bytes, caption: str = "", alt: str = "") -> HtmlReport:
        """Embed PNG bytes as a base64 data URI."""
        data = base64.b64encode(png).decode("ascii")
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self._parts.append(f"<figure><img alt='{html.escape(alt or caption)}' "
                           f"src='data:image/png;base64,{data}'/>{cap}</figure>")
        return self

    def add_figure(self, fig, caption: str = "", *, dpi: int = 100) -> HtmlReport:
        """Render a matplotlib figure to PNG (Agg) and embed it.

        Args:
            fig: ``matplotlib.figure.Figure`` (from :func:`new_figure` or pyplot).
            caption: text under the figure.
            dpi: resolution.
        """
        # local: matplotlib costs ~0.6 s, and this module loads at CLI start-up (report.handeye)
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        if not isinstance(fig.canvas, FigureCanvasAgg):
            FigureCanvasAgg(fig)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
        return self.add_image_png(buf.getvalue(), caption)

    def add_image_array(self, image, caption: str = "") -> HtmlReport:
        """Embed an image array (H, W) gray or (H, W, 3) BGR uint8 as PNG."""
        # local: OpenCV costs ~16 ms, and this module loads at CLI start-up (report.handeye)
        import cv2

        ok, png = cv2.imencode(".png", image)
        if not ok:
            raise ValueError("add_image_array: image could not be PNG-encoded")
        return self.add_image_png(png.tobytes(), caption)

    # -- output ---------------------------------------------------------------------------------
    def to_html(self) -> str:
        """The complete page."""
        stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
        sub = f"<p class='meta'>{html.escape(self.subtitle)}</p>" if self.subtitle else ""
        body = "\n".join(self._parts)
        return (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
                f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head>"
                f"<body><h1>{html.escape(self.title)}</h1>{sub}"
                f"<p class='meta'>generated {stamp}</p>\n{body}\n</body></html>\n")

    def save(self, path: str | os.PathLike) -> Path:
        """Write the page atomically (temporary file in the same folder, then rename).

        Returns:
            The path written.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, self.to_html())
        return path
