"""Station configs of the simulated stations for tests: the same devices and wire
protocols as the fixtures (``fixtures/stations/sim-*.toml``), but moves ``speed``
times faster, a shorter snapshot settle and sample period and shorter timeouts.

The simulated axes stop exactly at their target and every simulated reading is
computed from the axes' positions when it is sent, so a settle of a few ms is as
good as the fixtures' 50 ms; the snapshot still discards every frame from before
the settle and each of its samples still waits for a fresh frame (the simulated
inclinometer sends 100 per second: a period of 10 ms is one frame). The devices
answer over 127.0.0.1 within milliseconds, so a lost Modbus answer (the fault
tests drop frames on purpose) is declared lost after ``timeout`` s instead of the
fixtures' 1 s. The CANopen timeout stays (it is also the window of an actuator
reading, within which it sends SYNC after SYNC while TPDOs are lost), and so does
the snapshot's read timeout. The acceleration goes with the square of the speed up to what
a drive takes (increments/s^2 in the 32 bits of object 0x6083). The fixtures, which
the demos and the documentation use, keep their values.
"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

#: what the tests' simulated stations use unless a test asks for other values
SPEED, SETTLE, PERIOD, TIMEOUT = 8.0, 0.01, 0.01, 0.3
#: the largest profile acceleration a drive takes (object 0x6083, increments/s^2, 32 bits)
ACC_MAX = 0xFFFFFFFF


def set_keys(text: str, table: str, **values) -> str:
    """``text`` (a station config) with the keys ``values`` of ``[table]`` replaced
    (a value None: the key is kept); ValueError where the table or a key is not there."""
    m = re.search(rf"^\[{re.escape(table)}\]\n(.*?)(?=^\[|\Z)", text, re.M | re.S)
    if m is None:
        raise ValueError(f"the station config has no [{table}] table")
    body = m.group(1)
    for key, value in values.items():
        if value is None:
            continue
        body, n = re.subn(rf"^{key} = [^#\n]*", f"{key} = {value!r} ", body, count=1,
                          flags=re.M)
        if n != 1:
            raise ValueError(f"[{table}] has no {key} to replace")
    return text[:m.start(1)] + body + text[m.end(1):]


def quick_text(text: str, *, settle: float | None = SETTLE, period: float | None = PERIOD,
               samples: int | None = None, timeout: float | None = TIMEOUT) -> str:
    """A station config's text with the test timing: the snapshot's ``settle``,
    ``period`` and ``samples``, and ``timeout`` for one draw-wire answer (where the
    config has a draw-wire)."""
    text = set_keys(text, "snapshot", settle=settle, period=period, samples=samples)
    if timeout is not None and re.search(r"^\[drawwire\]$", text, re.M):
        text = set_keys(text, "drawwire", timeout=timeout)
    return text


def quick_config(folder: Path, robot: str, *, speed: float = SPEED, truth=None,
                 **timing) -> Path:
    """The simulated ``robot``'s station config (agebot-sm, agebot-pm) with moves
    ``speed`` times faster (velocity x ``speed``, acceleration x ``speed**2`` up to what
    a drive's 32-bit 0x6083 holds; with ``truth``, the envelope of that robot as
    :func:`station.simulation.sessions.fast_config` writes it) and the test timing of
    :func:`quick_text`, written into ``folder``."""
    from station.simulation.sessions import fast_config

    Path(folder).mkdir(parents=True, exist_ok=True)
    path = fast_config(robot, Path(folder), 1.0, truth)
    text = path.read_text()
    can = tomllib.loads(text)["canopen"]
    n = len(can["nodes"])
    res = _per_axis(can["increments_per_unit"], n)
    vel = [v * speed for v in _per_axis(can["profile_velocity"], n)]
    acc = [min(a * speed ** 2, ACC_MAX / r)
           for a, r in zip(_per_axis(can["profile_acceleration"], n), res)]
    text = set_keys(text, "canopen", profile_velocity=vel, profile_acceleration=acc)
    path.write_text(quick_text(text, **timing))
    return path


def _per_axis(v, n: int) -> list[float]:
    return [float(x) for x in v] if isinstance(v, list) else [float(v)] * n
