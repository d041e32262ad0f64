"""Whole simulated wrist sessions over wrists drawn around the report's (issue 10):
every one completes from the report's nominal, its calibrated IK returns the true
robot's actuator values within 1 unit over +-15 deg, and no recorded orientation
(the true wrist's) lies beyond 25 deg. pm-tilt does not identify the heading about
the vertical: its IK is judged with each orientation's heading taken out, and the
heading error must lie within 4 of the std its parameter file states. Ten wrists:
``python bench/bench_wrist_sessions.py [--method pm-tilt]``."""
from __future__ import annotations

import numpy as np
import pytest

from station.planning.request import PlanRequest
from station.simulation.wrist_sessions import run_wrist_session, wrist_truth

SEEDS = {"pm-fk": range(9350, 9357), "pm-tilt": range(9360, 9366)}  # used by no other test or bench


@pytest.mark.slow
@pytest.mark.parametrize("method", list(SEEDS))
def test_drawn_wrist_sessions_converge_inside_the_box(tmp_path, method):
    scores = [run_wrist_session(wrist_truth(seed), tmp_path / f"s{seed}", seed=seed,
                                method=method,
                                request=PlanRequest(count=20 if method == "pm-fk" else 24,
                                                    validation=4, seed=seed))
              for seed in SEEDS[method]]
    bad = [(s.seed, s.error, round(s.ik_error, 3), round(s.max_deg, 2), round(s.heading_z, 2))
           for s in scores if not s.ok]
    assert not bad, bad
    if method == "pm-tilt":   # the heading is stated, not claimed: its std is not optimistic
        z = np.array([s.heading_z for s in scores])
        assert np.sqrt(np.mean(z * z)) < 2.5, z
