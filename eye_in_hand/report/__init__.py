"""Self-contained HTML reports (tables, text and matplotlib figures embedded as PNG)."""
from __future__ import annotations

from eye_in_hand.report.html import HtmlReport, new_figure

__all__ = ["HtmlReport", "new_figure"]
