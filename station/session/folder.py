"""A session's folder: the files a session writes there (its lock aside,
:mod:`station.recording.lock`), and what a folder holds (:func:`summarize_folder`, for the
resume question)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

TRACE, PARAMS, REPORT = "trace.jsonl", "params.json", "report.html"
URDF = "calibrated.urdf"     # a robot file's session


@dataclass(frozen=True)
class TraceSummary:
    """What a session folder holds (for the resume question)."""

    folder: Path
    robot: str
    method: str
    measured: int
    skipped: int
    pending: int
    planned: int
    exported: bool
    error: str | None = None
    robot_file: dict | None = None   # a robot file's session: the header's robot_file
    truth: str | None = None         # a simulated session: its simulator's truth file

    @property
    def unfinished(self) -> bool:
        return self.error is None and not self.exported

    def sentence(self) -> str:
        if self.error:
            return f"{self.folder} holds a trace that cannot be read: {self.error}"
        return (f"{self.folder} holds a {self.robot} {self.method} session: {self.measured} "
                f"poses recorded, {self.skipped} skipped, {self.pending} of {self.planned} "
                f"planned still to measure"
                + ("; its parameter file was written" if self.exported else ""))


def summarize_folder(folder) -> TraceSummary | None:
    """The session in ``folder`` (None if it holds no trace)."""
    from station.recording.resume import recorded_plan
    from station.recording.trace import read_trace

    folder = Path(folder)
    path = folder / TRACE
    if not path.exists():
        return None
    try:
        tr = read_trace(path)
    except Exception as e:  # noqa: BLE001 - said to the operator
        return TraceSummary(folder, "", "", 0, 0, 0, 0, False, str(e))
    plan, skipped, measured = recorded_plan(tr)
    planned = {p.index for p in plan}
    exported = any(ev.get("kind") == "export" for ev in tr.events)
    pending = len(planned - set(measured) - skipped)
    sim = (tr.header.get("station") or {}).get("simulator") or {}
    return TraceSummary(folder, tr.robot, tr.method, len(measured), len(skipped), pending,
                        len(planned), exported, robot_file=tr.header.get("robot_file"),
                        truth=sim.get("truth"))
