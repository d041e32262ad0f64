"""One planned pose, as a session plans it and as the trace's ``plan`` events record it
(docs/file-formats.md): what planning makes, what a resumed session reads back."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PlannedPose:
    """One pose to measure: ``qm`` actuator targets, ``target`` the generalized
    coordinates planned, ``use`` ``"fit"`` or ``"validation"``, ``round`` (0; PM scout 0,
    main 1) and ``index`` its place in the session's whole plan. Guided touching:
    ``qm`` is the approach pose, ``target`` the planned contact (sm-plane: on the rough
    plane; pairs: the mark's x, y at this pose's phi) and ``group`` the pair."""

    index: int
    qm: tuple[float, ...]
    target: tuple[float, ...]
    use: str = "fit"
    round: int = 0
    group: int | None = None

    def record(self) -> dict:
        rec = {"index": self.index, "qm": list(self.qm), "target": list(self.target),
               "use": self.use, "round": self.round}
        if self.group is not None:
            rec["group"] = self.group
        return rec

    @classmethod
    def from_record(cls, r: dict) -> "PlannedPose":
        g = r.get("group")
        return cls(int(r["index"]), tuple(r["qm"]), tuple(r["target"]), r.get("use", "fit"),
                   int(r.get("round", 0)), None if g is None else int(g))
