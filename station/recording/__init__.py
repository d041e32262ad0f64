"""Recording: what a calibration is made of, on disk. The trace (JSON Lines, written
line by line and fsynced), the traces imported from a CSV (a robot file's joint values, a
URDF robot's points on the tool and its joint map), what a resumed session redoes, and
the session folder's lock. Imports nothing else of station/."""
