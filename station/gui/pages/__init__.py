"""The wizard's pages, one module each, over the one session (house style 9)."""
from __future__ import annotations

from enum import IntEnum


class PageId(IntEnum):
    SETUP = 0
    REFERENCE = 1
    PLAN = 2
    EXECUTE = 3
    CALIBRATE = 4
    EXPORT = 5
    ACCURACY = 6
    OFFLINE = 7


TITLES = {
    PageId.SETUP: "1  Setup",
    PageId.REFERENCE: "2  Reference",
    PageId.PLAN: "3  Plan",
    PageId.EXECUTE: "4  Execute",
    PageId.CALIBRATE: "5  Calibrate",
    PageId.EXPORT: "6  Export",
    PageId.ACCURACY: "7  Accuracy",
    PageId.OFFLINE: "Offline: a recorded trace",
}
