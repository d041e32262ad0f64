"""What the report's sections and figures share (:class:`ReportContext`, computed once per
report): the outcome's numbers, the parameters' identifiability groups (the report's
Table 3) and the text of a table cell."""
from __future__ import annotations

import copy
import math
import os

import numpy as np

from calibration import identifiability as ident
from station.outputs.params_file import file_sha256
from station.outputs.report_plotting import finite as _finite
from station.outputs.units import MM_DEG, channel_si, param_units
from station.recording.trace import utc_now

IDENT_GROUPS = (
    ("identifiable", "Identifiable",
     "calibrated; the std is the square root of the covariance diagonal (eq. 52)"),
    ("no-influence", "Not identifiable, without influence",
     ("the measurements do not depend on it: kept at its start value, and a wrong start "
      "value does not bias the others")),
    ("influence", "Not identifiable, with influence",
     ("a combination of other columns: kept at its start value, and a wrong start value "
      "biases the others, so it must be known")),
    ("fixed", "Fixed",
     ("held at its given value (the robot file's fixed), not calibrated; where the "
      "measurements depend on it (\"influences the model\") a wrong value biases the others")),
)
# Table 3 symbols
IDENT_SYMBOL = {"identifiable": "\u2713", "no-influence": "\u25cb", "influence": "\u25cf",
                "fixed": "\u25a0"}
CELL_MAX = 300          # characters in one table cell at most


class ReportContext:
    """What the sections and figures share, computed once."""

    def __init__(self, outcome, display=MM_DEG):
        self.outcome = outcome
        self.display = display
        self.trace, self.model, self.res = outcome.trace, outcome.model, outcome.result
        res, model = self.res, self.model
        self.robot = str(self.trace.header.get("robot", ""))
        self.method = str(res.method or getattr(model, "method", ""))
        self.created = utc_now()
        self.names = tuple(res.names)
        self.start = np.asarray(outcome.nominal if outcome.nominal is not None else res.x0,
                                dtype=float)
        self.x = np.asarray(res.x, dtype=float)
        self.std = np.asarray(res.std, dtype=float)
        self.groups = [group_of(st) for st in res.status]
        nom = getattr(model, "nominal", None)
        try:
            nom = np.asarray(nom, dtype=float) if nom is not None else None
        except (TypeError, ValueError):
            nom = None
        # the nominal as given, where the method re-estimated start values from it
        self.given_nominal = (nom if nom is not None and nom.shape == self.start.shape
                              and not np.array_equal(nom, self.start)
                              else None)
        self.units = param_units(self.trace)
        self.trace_path = getattr(self.trace, "path", None)
        self.trace_name = os.path.basename(self.trace_path) if self.trace_path else ""
        self.channels = tuple(model.channels)
        self.row_channel = np.asarray(model.row_channel)
        squared = getattr(model, "residual", "plain") == "squared"
        self.channel_unit = {ch: ("m\u00b2" if ch == "distance" and squared
                                  else channel_si(ch)) for ch in self.channels}
        self.after = np.asarray(res.residual, dtype=float)
        self.before, self.before_error = self._before()
        self.n_active = res.n_identifiable
        self.min_poses = ident.minimum_poses(res.n_identifiable, model.p)

    def _before(self):
        """Residual at the start values, on a copy of the model (some models keep
        state between evaluations, e.g. the PM's assembly mode)."""
        try:
            try:
                model = copy.deepcopy(self.model)
            except Exception:  # noqa: BLE001 - a model that cannot be copied is used as is
                model = self.model
            r, _ = model.evaluate(np.array(self.start, dtype=float))
            r = np.asarray(r, dtype=float)
            if r.shape != self.after.shape:
                return None, f"the start residual has {r.size} rows, the final {self.after.size}"
            return r, None
        except Exception as e:  # noqa: BLE001 - shown in the report, not fatal
            return None, f"{e.__class__.__name__}: {e}"

    def rows_of(self, c: int) -> np.ndarray:
        return self.row_channel == c

    def trace_sha256(self) -> str:
        doc = self.outcome.document or {}
        src = doc.get("source_trace") or {}
        if src.get("sha256"):
            return str(src["sha256"])
        if self.trace_path:
            try:
                return file_sha256(self.trace_path)
            except OSError as e:
                return f"unavailable ({e.strerror or e})"
        return "unavailable"

    def sigma_given(self) -> dict:
        from station.recording.channels import solver_sigma

        try:
            return solver_sigma(self.model, self.trace) or {}
        except Exception:  # noqa: BLE001 - informative only
            return {}

    def sigma_estimated(self) -> dict:
        """Eq. 51 per channel at the solution, with the channel's share of the
        degrees of freedom (as the solver does)."""
        n = max(len(self.after), 1)
        out = {}
        for c, ch in enumerate(self.channels):
            r = self.after[self.rows_of(c)]
            nc = r.size
            if nc == 0:
                continue
            dof = nc - self.n_active * nc / n
            rss = float(np.sum(r ** 2))
            out[ch] = math.sqrt(rss / dof) if dof > 0 else math.sqrt(rss / nc)
        return out


def group_of(st) -> str:
    """The parameter's group of :data:`IDENT_GROUPS` from its status."""
    if st.identifiable:
        return "identifiable"
    if getattr(st, "fixed", False):
        return "fixed"
    return "influence" if st.influences_model else "no-influence"


def number_text(v, fmt=".7g") -> str:
    if not _finite(v):
        return "\u2013"
    from station.outputs.units import unsigned_zero

    return unsigned_zero(format(float(v), fmt))


def short(v, limit: int = CELL_MAX) -> str:
    """A value as table text of at most ``limit`` characters: numbers formatted,
    mappings as ``key: value; ...``, lists comma-separated, the rest cut with an
    ellipsis."""
    if isinstance(v, bool):
        text = str(v)
    elif isinstance(v, (int, np.integer)):
        text = str(int(v))
    elif isinstance(v, (float, np.floating)):
        text = number_text(v, ".4g")
    elif v is None:
        text = "\u2013"
    elif isinstance(v, dict):
        text = "; ".join(f"{k}: {short(x, limit)}" for k, x in v.items())
    elif isinstance(v, (list, tuple)):
        text = ", ".join(short(x, limit) for x in v)
    else:
        text = str(v)
    return text if len(text) <= limit else text[: limit - 1] + "\u2026"
