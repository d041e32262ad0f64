"""Fault injection for the simulated devices (a hook of the twin, never a
branch in the driver, house style 2).

One :class:`FaultPlan` is shared by every simulated device of a simulator
process. Tests and the simulator's control port set its fields at run time;
each simulated device consults it where the fault would happen on the wire.
"""
from __future__ import annotations

import math
import random
import threading
from dataclasses import dataclass, field, fields


@dataclass
class FaultPlan:
    """What goes wrong, and how often. All off by default.

    drop_prob:        probability that a frame/answer is not sent at all.
    corrupt_prob:     probability that a frame is sent with a corrupted byte.
    late_s:           extra delay (s) before each answer (a late device).
    silent_nodes:     CANopen node ids that stop talking (no PDO, SDO, heartbeat).
    drive_fault_node: CANopen node id that goes to FAULT (with EMCY) at its next move.
    modbus_exception: Modbus exception code to answer every request with (0: off).
    inclinometer_silent: the inclinometer stops sending frames.
    drawwire_down:    the Modbus server drops its connections and refuses new ones.
    inclinometer_lag_s: the inclinometer's frames show the pose of that many seconds
                      before they are sent (a sensor's filter delay).
    drawwire_unanswered: the next that many Modbus requests to the draw-wire get no
                      answer (a lost answer: the client times out); counts down to 0.
    drawwire_answer_first: how many requests are answered before those (counts down
                      first): a lost answer at an exact request, e.g. in mid-snapshot.
    glitch_qm:        actuator values of a pose whose readings are disturbed while the
                      arm rests there, reached at the configured motion profile (a cable
                      brushing the wire, a knock on the sensor: a measurement again,
                      approached slower, reads the pose as it is); empty: none.
    glitch_distance_m: what the draw-wire then reads more (m).
    glitch_tilt_deg:  what the inclinometer's pitch (the arm's tilt) then reads more (deg).
    glitch_persists:  the disturbance is there however the pose is approached (the wire
                      rubbing on an edge there): measuring again confirms it.
    seed:             seed of the fault random generator.
    """

    drop_prob: float = 0.0
    corrupt_prob: float = 0.0
    late_s: float = 0.0
    silent_nodes: set[int] = field(default_factory=set)
    drive_fault_node: int = 0
    modbus_exception: int = 0
    inclinometer_silent: bool = False
    drawwire_down: bool = False
    inclinometer_lag_s: float = 0.0
    drawwire_unanswered: int = 0
    drawwire_answer_first: int = 0
    glitch_qm: list[float] = field(default_factory=list)
    glitch_distance_m: float = 0.0
    glitch_tilt_deg: float = 0.0
    glitch_persists: bool = False
    seed: int | None = None

    def __post_init__(self):
        self._lock = threading.Lock()
        self._rng = random.Random(self.seed)

    def chance(self, p: float) -> bool:
        if p <= 0:
            return False
        with self._lock:
            return self._rng.random() < p

    def update(self, **changes) -> None:
        """Change fields by name (from the control port or a test). Every value is
        checked before any is set (:func:`checked`): a bad one is a ValueError naming
        its key, and the plan is left as it was; a device thread never meets it."""
        names = {f.name for f in fields(self)}
        for k in changes:
            if k not in names or k == "seed":
                raise KeyError(f"unknown fault {k!r} (known: {', '.join(sorted(names - {'seed'}))})")
        values = {k: checked(k, v) for k, v in changes.items()}
        with self._lock:
            for k, v in values.items():
                setattr(self, k, v)

    def drawwire_answers(self) -> bool:
        """Whether the draw-wire answers the request it has just received (counts
        ``drawwire_answer_first``, then ``drawwire_unanswered``, down)."""
        with self._lock:
            if self.drawwire_unanswered <= 0:
                return True
            if self.drawwire_answer_first > 0:
                self.drawwire_answer_first -= 1
                return True
            self.drawwire_unanswered -= 1
            return False

    def clear(self) -> None:
        self.update(drop_prob=0.0, corrupt_prob=0.0, late_s=0.0, silent_nodes=set(),
                    drive_fault_node=0, modbus_exception=0, inclinometer_silent=False,
                    drawwire_down=False, inclinometer_lag_s=0.0, drawwire_unanswered=0,
                    drawwire_answer_first=0, glitch_qm=[], glitch_distance_m=0.0,
                    glitch_tilt_deg=0.0, glitch_persists=False)

    def as_dict(self) -> dict:
        return {f.name: (sorted(getattr(self, f.name)) if f.name == "silent_nodes"
                         else getattr(self, f.name)) for f in fields(self)}


#: the most a fault may delay an answer or lag a sensor (s): longer is a device gone
MAX_DELAY_S = 60.0
#: the range of each fault field: (kind, low, high)
RANGES = {"drop_prob": ("probability", 0.0, 1.0), "corrupt_prob": ("probability", 0.0, 1.0),
          "late_s": ("seconds", 0.0, MAX_DELAY_S),
          "inclinometer_lag_s": ("seconds", 0.0, MAX_DELAY_S),
          "drive_fault_node": ("node", 0, 127), "modbus_exception": ("code", 0, 255),
          "drawwire_unanswered": ("count", 0, 10 ** 9),
          "drawwire_answer_first": ("count", 0, 10 ** 9),
          "glitch_distance_m": ("metres", -1.0, 1.0),
          "glitch_tilt_deg": ("degrees", -90.0, 90.0)}
FLAGS = ("inclinometer_silent", "drawwire_down", "glitch_persists")


def checked(key: str, value):
    """``value`` of fault ``key`` as the plan holds it, or a ValueError naming the key
    and what it takes (a probability of 0..1, seconds of 0..60, a node id, a count,
    true/false, a list of node ids)."""
    def bad(what):
        return ValueError(f"fault {key}: {value!r} is not {what}")

    if key == "silent_nodes":
        if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__iter__"):
            raise bad("a list of node ids (1..127)")
        nodes = list(value)
        if any(isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 127
               for n in nodes):
            raise bad("a list of node ids (1..127)")
        return set(nodes)
    if key == "glitch_qm":
        if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__iter__"):
            raise bad("a list of actuator values")
        qm = list(value)
        if any(isinstance(q, bool) or not isinstance(q, (int, float)) or not math.isfinite(q)
               for q in qm):
            raise bad("a list of actuator values")
        return [float(q) for q in qm]
    if key in FLAGS:
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    kind, lo, hi = RANGES[key]
    if kind in ("probability", "seconds", "metres", "degrees"):
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not lo <= value <= hi:       # NaN fails too
            raise bad(f"a number of {kind} from {lo:g} to {hi:g}")
        return float(value)
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        what = {"node": "a node id (0: none, 1..127)", "code": "a Modbus exception code "
                "(0: none, 1..255)", "count": "a count of requests (0 or more)"}[kind]
        raise bad(what)
    return value
