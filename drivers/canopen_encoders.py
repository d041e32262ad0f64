"""Read-only CiA 406 encoders on CANopen (see :mod:`drivers.canopen_nodes`)."""
from __future__ import annotations

import math
from collections.abc import Sequence

from drivers.canopen_nodes import CanopenNodes


class CanopenEncoders(CanopenNodes):
    """Read-only CiA 406 encoders: position value 0x6004 (UNSIGNED32) in TPDO1
    (0x1A00:01 = 0x60040020) on SYNC, preset 0x6003. For robots whose own
    controller moves the arm. ``signed=True`` reads counts at or above 2**31 as
    negative (a multi-turn count that wrapped below zero)."""

    profile = 0x0196
    position_object = 0x6004
    tpdo_objects = ((0x6004, 32),)

    def __init__(self, nodes, resolution, *, signed: bool = True, **options):
        super().__init__(nodes, resolution, **options)
        self.signed = bool(signed)

    def _decode(self, raw: int) -> int:
        return raw - (1 << 32) if self.signed and raw >= 1 << 31 else raw

    def preset(self, qm_values: Sequence[float]) -> None:
        """Set each encoder's present position to ``qm_values`` (actuator units) through 0x6003."""
        values = [float(q) for q in qm_values]
        if len(values) != len(self.nodes) or not all(math.isfinite(q) for q in values):
            raise ValueError(f"qm_values: need {len(self.nodes)} finite values, got {list(qm_values)!r}")
        for i, nid in enumerate(self.nodes):
            self.sdo_write(nid, 0x6003, round(values[i] * self.resolution[i]) & 0xFFFFFFFF)
