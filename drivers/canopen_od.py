"""CANopen object dictionary and code tables the station's CANopen devices share.

:func:`standard_od` is the dictionary of the standard objects the master reads
and writes (CiA 301, 402, 406), so no vendor EDS is needed; :func:`emcy_text`
and :data:`EMCY_TEXT` name EMCY error codes; :func:`state_name` gives the CiA 402
state of a statusword.
"""
from __future__ import annotations

import canopen
from canopen.objectdictionary import (INTEGER8, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32,
                                      ObjectDictionary, ODRecord, ODVariable)

#: EMCY error codes (CiA 301 / CiA 402) the station names; others show as hex.
EMCY_TEXT = {
    0x0000: "error reset / no error", 0x1000: "generic error",
    0x2310: "continuous over-current", 0x2320: "short circuit at motor side",
    0x3210: "DC link over-voltage", 0x3220: "DC link under-voltage",
    0x4210: "excess temperature device", 0x4310: "drive temperature too high",
    0x5530: "non-volatile memory (EEPROM) error", 0x6320: "parameter error",
    0x7305: "incremental sensor 1 fault", 0x8110: "CAN overrun (objects lost)",
    0x8130: "life guard or heartbeat error", 0x8611: "following error",
    0x8612: "reference limit", 0xFF00: "device specific",
}
NMT_OPERATIONAL = 5                       # NMT state code in heartbeats


def emcy_text(code: int) -> str:
    """Text of an EMCY error code; unknown codes as ``unknown EMCY 0x1234 (<class>)``."""
    if code in EMCY_TEXT:
        return EMCY_TEXT[code]
    cls = canopen.emcy.EmcyError(code, 0, b"", 0).get_desc()
    return f"unknown EMCY 0x{code:04X}" + (f" ({cls.lower()})" if cls else "")


def state_name(sw: int) -> str:
    """CiA 402 state of a statusword."""
    for mask, value, name in ((0x4F, 0x00, "NOT READY TO SWITCH ON"), (0x4F, 0x40, "SWITCH ON DISABLED"),
                              (0x6F, 0x21, "READY TO SWITCH ON"), (0x6F, 0x23, "SWITCHED ON"),
                              (0x6F, 0x27, "OPERATION ENABLED"), (0x6F, 0x07, "QUICK STOP ACTIVE"),
                              (0x4F, 0x0F, "FAULT REACTION ACTIVE"), (0x4F, 0x08, "FAULT")):
        if sw & mask == value:
            return name
    return f"UNKNOWN (0x{sw:04X})"


def standard_od() -> ObjectDictionary:
    """The standard objects the station uses (CiA 301, 402, 406); no vendor EDS needed."""
    od = ObjectDictionary()

    def var(index, sub, name, dtype, access="rw"):
        v = ODVariable(name, index, sub)
        v.data_type, v.access_type = dtype, access
        return v
    for index, name, dtype, access in (
            (0x1000, "Device type", UNSIGNED32, "ro"), (0x1001, "Error register", UNSIGNED8, "ro"),
            (0x1017, "Producer heartbeat time", UNSIGNED16, "rw"), (0x603F, "Error code", UNSIGNED16, "ro"),
            (0x6040, "Controlword", UNSIGNED16, "rw"), (0x6041, "Statusword", UNSIGNED16, "ro"),
            (0x6060, "Modes of operation", INTEGER8, "rw"), (0x6061, "Modes of operation display", INTEGER8, "ro"),
            (0x6064, "Position actual value", INTEGER32, "ro"), (0x607A, "Target position", INTEGER32, "rw"),
            (0x6081, "Profile velocity", UNSIGNED32, "rw"), (0x6083, "Profile acceleration", UNSIGNED32, "rw"),
            (0x6003, "Preset value", UNSIGNED32, "rw"), (0x6004, "Position value", UNSIGNED32, "ro")):
        od.add_object(var(index, 0, name, dtype, access))
    comm, mapping = ODRecord("TPDO1 communication parameter", 0x1800), ODRecord("TPDO1 mapping parameter", 0x1A00)
    for sub, name, dtype in ((0, "Highest sub-index", UNSIGNED8), (1, "COB-ID", UNSIGNED32),
                             (2, "Transmission type", UNSIGNED8), (3, "Inhibit time", UNSIGNED16),
                             (5, "Event timer", UNSIGNED16)):
        comm.add_member(var(0x1800, sub, name, dtype))
    mapping.add_member(var(0x1A00, 0, "Number of mapped objects", UNSIGNED8))
    for sub in range(1, 9):
        mapping.add_member(var(0x1A00, sub, f"Mapped object {sub}", UNSIGNED32))
    od.add_object(comm)
    od.add_object(mapping)
    return od
