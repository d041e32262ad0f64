"""CANopen actuators (CiA 402 drives) and encoders (CiA 406) over python-can + canopen.

Every node is a canopen ``RemoteNode`` on one ``canopen.Network``; SDO, PDO and
NMT are the library's. Positions are sampled together: the master sends one
SYNC and waits for every node's TPDO1 (transmission type 1, mapping the
statusword 0x6041 and position 0x6064, or 0x6004 for an encoder). A TPDO is
attributed to the last SYNC sent before it arrived; a node whose TPDO does not
come in time gives :class:`DeviceTimeout` naming it, never an older value.
Heartbeats (producer time 0x1017, set by the master) are watched: a silent node
is ``"canopen node 3: heartbeat lost ..."``. A drive fault raises
:class:`ProtocolError` carrying the EMCY code and its text.

Units: positions in actuator units ``Qm`` = increments / ``resolution``
(increments per actuator unit, one for all nodes or one per node); velocities
in units/s, accelerations in units/s^2, times in seconds.
"""
from __future__ import annotations

import contextlib
import functools
import threading
import time
from collections.abc import Sequence

import can
import canopen
from canopen.objectdictionary import (INTEGER8, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32,
                                      ObjectDictionary, ODRecord, ODVariable)
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from calibration.errors import ConfigError
from drivers.base import Device, Sample
from drivers.canopen_cia402 import (EMCY_TEXT, emcy_text, state_name)  # noqa: F401  (re-exported)
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
