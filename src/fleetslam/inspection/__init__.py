"""Inspection: findings the operator records (anchored to the keyframe they were seen from, shared over the
middleware, persisted with the run) and the inspection report of a run (``report.html`` and ``report.pdf``).

:mod:`~fleetslam.inspection.findings` is pure (the store, validation, files, anchoring);
:mod:`~fleetslam.inspection.node` shares it over the middleware; :mod:`~fleetslam.inspection.report` renders the
report. Names are loaded on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.inspection.findings import Finding, FindingStore
    from fleetslam.inspection.node import FindingsNode
    from fleetslam.inspection.report import InspectionReport, write_inspection_report

__all__ = ["Finding", "FindingStore", "FindingsNode", "InspectionReport", "write_inspection_report"]

if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "findings": ["Finding", "FindingStore"],
            "node": ["FindingsNode"],
            "report": ["InspectionReport", "write_inspection_report"],
        },
    )
