"""Fitting: a recorded trace to calibrated parameters. The batch calibration (one path
for ``app.py batch``, the session and the wizard), its start values, eq. 60's pose
counts, the fit-quality gate, held-out validation and the compliance comparison. Imports
recording/ and outputs/, never planning/ or the session."""
