"""The session: one calibration of one robot at the station, from the reference step
through planning, measuring (with its retry policy) to the calibration and its files
(:class:`station.session.session.Session`). No Qt: the wizard (station/gui/) and the
headless run (station/headless.py) are its two faces."""
