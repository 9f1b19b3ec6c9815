"""The flight report (``report.html``) that ``c3-matcher replay`` and ``eval`` write."""

from c3_matcher_tools.report.html import write_report

__all__ = ["write_report"]
