"""The fit-quality gate's verdict (:mod:`station.fitting.gate`): :class:`Quality`, the
parameter file's ``fit.quality`` (outliers left out, each check with its figures, whether
the operator accepted a failed fit), and the errors a calibration raises when a fit does
not converge or fails the gate."""
from __future__ import annotations

from dataclasses import dataclass, field

from calibration.errors import CalibrationError
from station.recording.trace import pose_name


class FitQualityError(CalibrationError):
    """The fit failed the quality gate; ``outcome`` holds it (not written)."""

    def __init__(self, message: str, outcome=None):
        super().__init__(message)
        self.outcome = outcome


class NotConverged(CalibrationError):
    """The calibration did not converge; ``model`` is the measurement model tried."""

    def __init__(self, message: str, model=None):
        super().__init__(message)
        self.model = model


@dataclass
class Quality:
    """The gate's result (``fit.quality`` of the parameter file)."""

    outliers: list[dict] = field(default_factory=list)
    checks: list[dict] = field(default_factory=list)
    accepted: bool = False
    excluded: list[dict] = field(default_factory=list)   # by the operator: pose, reason
    outlier_mode: str = "exclude"    # batch --outliers: exclude, flag or off

    @property
    def passed(self) -> bool:
        return all(c["ok"] for c in self.checks)

    @property
    def failures(self) -> list[str]:
        return [c["message"] for c in self.checks if not c["ok"]]

    def check(self, name: str, ok: bool, message: str, **figures) -> None:
        self.checks.append({"check": name, "ok": bool(ok), "message": message, **figures})

    def as_dict(self) -> dict:
        out = {"passed": self.passed, "accepted": self.accepted,
               "outlier_mode": self.outlier_mode,
               "outliers": [dict(o) for o in self.outliers],
               "checks": [dict(c) for c in self.checks]}
        if self.excluded:
            out["excluded"] = [dict(e) for e in self.excluded]
        return out

    def lines(self) -> list[str]:
        """Human-readable lines (CLI table, GUI)."""
        out = [f"excluded by the operator: pose {e['pose']} ({e['reason']})"
               for e in self.excluded]
        for o in self.outliers:
            if "deleted" in o:      # a pose judged whole (station.fitting.pose_outliers)
                out.append(f"outlier excluded: {describe(o)} ({deleted_text(o)})")
                continue
            res = (f"{o['residual'] * 1e3:.4g} mm from its prediction" if "point" in o
                   else f"residual {o['residual']:.4g}")
            out.append(f"outlier excluded: {describe(o)} ({res}, studentized {o['t']:.3g} > "
                       f"{o['threshold']:.3g})")
        for c in self.checks:
            # passed, but short of what it recommends (fewer poses than eq. 60's): a note
            lead = "FAILED: " if not c["ok"] else "note: " if c.get("short") else "ok: "
            out.append(lead + c["message"])
        if not self.passed:
            out.append("fit quality: FAILED" + (", accepted by the operator (--accept-poor-fit)"
                                                 if self.accepted else ""))
        else:
            out.append("fit quality: passed")
        return out

    def summary(self) -> str:
        """One line: what failed, with its figures."""
        return "; ".join(self.failures) if self.failures else "passed"


#: what the gate does with readings that do not fit the others (batch --outliers)
OUTLIER_MODES = ("exclude", "flag", "off")


def max_outliers(n_poses: int) -> int:
    """At most one pose in ten (at least one) may be excluded as an outlier."""
    return max(1, n_poses // 10)


def describe(o: dict) -> str:
    """``pose 5 marker`` (sm-markers: ``pose 5 point 2``) for an outlier entry."""
    return f"{pose_name(o)} point {o['point']}" if "point" in o else \
        f"{pose_name(o)} {o['channel']}"


def stops_judging(quality, mode: str, entry: dict, said: str, limit: int, what: str) -> bool:
    """The outlier loop's two ends before a reading or a pose is left out: with
    ``--outliers flag`` the worst is named and kept; with ``exclude`` more than ``limit``
    ``what`` (readings, poses) not fitting the others is a failed check. True where the
    loop stops (the check recorded in ``quality``); ``said`` is why ``entry`` does not fit."""
    if mode == "flag":
        quality.check("outliers", True, f"outliers: flagged, kept in the fit (--outliers "
                      f"flag): {describe(entry)} ({said})", flagged=entry)
        return True
    if len(quality.outliers) >= limit:
        named = ", ".join(describe(o) for o in quality.outliers)
        quality.check("outliers", False,
                      f"outliers: more than {limit} {what} do not fit the others "
                      f"({named + ', ' if named else ''}{describe(entry)}: {said})",
                      limit=limit, next=entry)
        return True
    return False


def deleted_text(o: dict) -> str:
    """What a pose judged whole did (an outlier entry with ``deleted``): its error from
    the fit without it, the others' prediction with and without it, its error under
    the final model."""
    lead = "" if o.get("level") is None else f" (beyond {o['level'] * 1e3:.3g} mm)"
    text = (f"{o['deleted'] * 1e3:.4g} mm from the prediction of the fit without it, "
            f"leverage {o['leverage']:.2g}, studentized {o['t']:.3g} > {o['threshold']:.3g}"
            f"{lead}")
    if o.get("others"):
        was, now = o["others"]
        text += f"; the others predicted {was * 1e3:.3g} -> {now * 1e3:.3g} mm without it"
    if o.get("final") is not None:
        text += f"; {o['final'] * 1e3:.4g} mm off the final model"
    return text
