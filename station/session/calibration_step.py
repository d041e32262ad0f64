"""The session's calibration step: the recorded trace calibrated, validated and written.

The trace is read back whole and calibrated by the one path every caller takes
(:func:`station.fitting.batch.calibrate`, with the fit-quality gate); the held-out poses
validate it; the parameter file (atomically, with its checksum), the report and, for a
robot file, a URDF of the calibration are written into the session folder.
"""
from __future__ import annotations

import dataclasses

from calibration.errors import ConfigError, StationError
from station.fitting.batch import calibrate
from station.fitting.outcome import BatchOutcome
from station.fitting.validation import validation_errors
from station.fitting.verdict import FitQualityError
from station.outputs.fit_summary import outcome_document
from station.outputs.params_file import write_params
from station.recording.trace import read_trace
from station.recording.trace_writer import TraceWriter
from station.session.folder import PARAMS, REPORT, URDF


class CalibrationStep:
    """The calibration step of a :class:`~station.session.session.Session` (a part of it:
    reads the trace, ``minimum_count``, ``kind``; writes ``outcome``, ``validation``,
    ``exported`` and the session folder's files)."""

    def calibrate(self, callback=None, accept_poor_fit: bool | None = None) -> BatchOutcome:
        """Calibrate the recorded fit poses (Algorithm 2) and pass the fit-quality gate
        (:mod:`station.fitting.gate`; a failed gate raises unless ``accept_poor_fit``,
        default the session's); ``callback(k, iteration)`` after every iteration
        (:class:`calibration.solver.Iteration`: live plots)."""
        if accept_poor_fit is None:
            accept_poor_fit = self.accept_poor_fit
        trace = self.read_own_trace()
        if self.method == "sm-self-redundancy":
            self._drop_lone_poses(trace)
            n_fit = len({p["group"] for p in trace.fit_poses})
            unit = "pairs"
        else:
            n_fit, unit = len(trace.fit_poses), "poses"
        if n_fit < self.minimum_count:
            self._event("warning", f"{n_fit} {unit} recorded; eq. 60 recommends at least "
                        f"{self.minimum_count}")
        self._notify("state", "calibrating")
        try:
            self.outcome = calibrate(trace, callback=callback, accept_poor_fit=accept_poor_fit)
        except FitQualityError as e:
            self._event("fit-quality", str(e))
            raise
        q = self.outcome.quality
        for o in q.outliers:
            self._event("outlier", f"pose {o['pose']} {o['channel']} left out of the fit "
                        f"(studentized residual {o['t']:.3g} > {o['threshold']:.3g})")
        if not q.passed:
            self._event("fit-quality", "accepted by the operator: " + q.summary())
        self._event("calibrated", self.outcome.result.message)
        self._notify("state", "calibrated")
        return self.outcome

    def read_own_trace(self):
        """The session's trace as recorded so far (:func:`station.recording.trace.read_trace`;
        the writer closed for the read and resumed)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        try:
            return read_trace(self.trace_path)
        finally:
            self._writer = TraceWriter.resume(self.trace_path)

    def _drop_lone_poses(self, trace) -> None:
        """Pairs whose partner was skipped: leave the lone pose out of the calibration."""
        count: dict = {}
        current = trace.current_poses
        for p in current:
            key = (p.get("use", "fit"), p["group"])
            count[key] = count.get(key, 0) + 1
        lone = [p for p in current if count[(p.get("use", "fit"), p["group"])] < 2]
        if lone:
            trace.poses[:] = [p for p in trace.poses if p not in lone]
            self._event("warning", "left out of the calibration (their pair partner was not "
                        "recorded): poses " + ", ".join(str(p["index"]) for p in lone))

    def validate(self) -> list[dict]:
        """Errors on the held-out poses before (start values) and after calibration,
        per measured channel."""
        if self.outcome is None:
            raise StationError("calibrate first")
        self.validation = (self.outcome.validation if self.outcome.validation is not None
                           else validation_errors(self.outcome))
        if self.validation:
            from station.outputs.report_sections import validation_headline

            self._event("validated", validation_headline(self.validation, self.units))
        return self.validation

    def export(self) -> dict:
        """Write ``params.json`` (atomically, with checksum) and ``report.html``."""
        if self.outcome is None:
            raise StationError("calibrate first")
        if self.validation is None:
            self.validate()
        o = self.outcome
        doc = outcome_document(o, str(self.trace_path))
        self.kind.export(doc)       # a robot file's calibration keeps it
        doc = _writing(self.out / PARAMS, write_params, self.out / PARAMS, doc)
        self._event("export", f"parameter file {self.out / PARAMS} ({doc['checksum']})")
        urdf = self._export_urdf(doc) if self.kind.urdf else None
        from station.outputs.report import write_report

        o = self.outcome = dataclasses.replace(o, document=doc)
        events = list(self.events)
        _writing(self.out / REPORT, write_report, self.out / REPORT, o,
                 validation=self.validation, events=events, units=self.units,
                 session={"robot": self.robot.name, "method": self.method,
                          "station config": self.config.source or "",
                          "poses measured": len(self.measured),
                          "poses skipped": len(self.skipped)})
        self._event("report", f"report {self.out / REPORT}")
        self.exported = {"params": str(self.out / PARAMS), "report": str(self.out / REPORT),
                         "trace": str(self.trace_path), "checksum": doc["checksum"]}
        if urdf:
            self.exported["urdf"] = urdf
        self._notify("state", "exported")
        return self.exported

    def _export_urdf(self, doc: dict) -> str | None:
        """A robot file's calibration as URDF (``calibrated.urdf``,
        station/outputs/export.py): a URDF robot's own URDF with its joint origins
        calibrated (:func:`station.outputs.export_urdf.calibrated_urdf`, as ``app.py export
        --urdf``; its links, joint names and the rest of the file as written), a robot
        file's chain written as URDF (:func:`~station.outputs.export.urdf_text`). None, said
        in an event, where a calibrated ratio k is not 1."""
        from drivers.atomic import write_atomic
        from station.outputs.export import calibrated_model, urdf_text

        path = self.out / URDF
        try:
            robot, xi = calibrated_model(doc, str(self.out / PARAMS))
            if hasattr(robot, "calibrated_origins"):       # a URDF robot
                from station.outputs.export_urdf import calibrated_urdf

                text = calibrated_urdf(robot, xi)
            else:
                text = urdf_text(robot, xi)
        except ConfigError as e:
            self._event("warning", f"no URDF: {e}")
            return None
        write_atomic(path, text.encode("utf-8"))
        self._event("export", f"URDF {path}")
        return str(path)


def _writing(path, write, *args, **kwargs):
    """``write(*args, **kwargs)`` with an OSError (a full disk) as one line naming ``path``."""
    try:
        return write(*args, **kwargs)
    except OSError as e:
        raise StationError(f"{path}: cannot write: {e.strerror or e}; the trace is intact: "
                           "free space, then run the session again to export") from None
