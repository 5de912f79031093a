"""Plotted reports of an offline cleaning (``streamfix report``, ``streamfix eval --report``).

:func:`load_report_data` / :func:`report_from_motions` gather input, cleaned output and an
optional optical reference; :func:`write_report` writes HTML (PNGs embedded) or one PNG
with the figures of :mod:`.figures` and the numbers of :mod:`.summary`. Needs matplotlib
(the ``report`` extra).
"""
from .document import load_report_data, render_png, report_from_motions, write_file_reports, write_report
from .figures import FIGURES, ReportData, choose_joints
from .summary import joint_reference_errors, summarise

__all__ = ["load_report_data", "report_from_motions", "write_report", "write_file_reports", "render_png", "FIGURES", "ReportData",
           "choose_joints", "joint_reference_errors", "summarise"]
