"""A calibration's outcome: the trace, its measurement model, the solver's result, the
start values, the parameter file's content once written, the gate's verdict, the held-out
validation and, where offered, the rigid-against-compliant comparison."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.solver import CalibrationResult
from station.fitting.verdict import Quality
from station.recording.trace import Trace


@dataclass(frozen=True)
class BatchOutcome:
    trace: Trace
    model: object
    result: CalibrationResult
    nominal: np.ndarray
    document: dict | None
    quality: Quality | None = None
    validation: list | None = None
    comparison: dict | None = None   # rigid against compliant (station.fitting.compliance)
