"""Whole simulated wrist sessions over wrists drawn around the report's (issue 10):
every one completes from the report's nominal, its calibrated IK returns the true
robot's actuator values within 1 unit over +-15 deg, and no recorded orientation
lies beyond 25 deg. Ten wrists: ``python bench/bench_wrist_sessions.py``."""
from __future__ import annotations

import pytest

from station.planner import PlanRequest
from station.sim_wrist import run_wrist_session, wrist_truth

SEEDS = range(9350, 9357)        # used by no other test or bench


@pytest.mark.slow
def test_drawn_wrist_sessions_converge_inside_the_box(tmp_path):
    scores = [run_wrist_session(wrist_truth(seed), tmp_path / f"s{seed}", seed=seed,
                                request=PlanRequest(count=20, validation=4, seed=seed))
              for seed in SEEDS]
    bad = [(s.seed, s.error, round(s.ik_error, 3), round(s.max_deg, 2))
           for s in scores if not s.ok]
    assert not bad, bad
