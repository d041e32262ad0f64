"""A truth file's ``repeatability`` (drivers/sim/repeatability.py, drivers/sim/axis.py):
backlash (the position reached depends on the direction of approach) and a random
positioning error per move, between the motor (its encoder) and the link; off unless the
truth asks for it, and then every simulated robot is as it was."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calibration.errors import ConfigError
from drivers.sim.axis import SimAxis
from drivers.sim.robot import SimulatedAgebot
from drivers.sim.serial_robot import SimulatedSerial, draw_serial_truth
from drivers.sim.truth import load_truth, parse_truth, save_truth, truth_to_dict

ROOT = Path(__file__).resolve().parents[2]
HAYATI = ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml"


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def test_backlash_depends_on_the_direction_of_approach_and_the_encoder_does_not_see_it():
    clock = Clock()
    a = SimAxis(0.0, 1.0, 10.0, clock=clock, backlash=4e-5)
    a.command(1.0)
    clock.t += 10
    from_below = a.link_position()
    a.command(2.0)
    clock.t += 10
    a.command(1.0)
    clock.t += 10
    from_above = a.link_position()
    assert a.position() == 1.0                    # the motor (its encoder): where commanded
    assert from_above - from_below == pytest.approx(4e-5)
    assert from_below == pytest.approx(1.0 - 2e-5)
    a.command(1.0)                                # no motion: the play stays
    assert a.link_position() == pytest.approx(from_above)


def test_the_positioning_error_is_random_per_move_with_its_std():
    clock = Clock()
    a = SimAxis(0.0, 10.0, 100.0, clock=clock, positioning=1e-5,
                rng=np.random.default_rng(3))
    got = []
    for k in range(400):                          # always approached from below
        a.command(-1.0)
        clock.t += 5
        a.command(0.5)
        clock.t += 5
        got.append(a.link_position() - a.position())
    assert np.std(got) == pytest.approx(1e-5, rel=0.15)
    assert abs(np.mean(got)) < 3e-6
    with pytest.raises(ValueError, match="random generator"):
        SimAxis(0.0, positioning=1e-5)


def _serial_truth(tmp_path, repeatability=None):
    t = draw_serial_truth(HAYATI, np.random.default_rng(2), seed=5)
    doc = truth_to_dict(t)
    doc["robot_file"] = str(HAYATI)
    if repeatability is not None:
        doc["repeatability"] = repeatability
    (tmp_path / "t.json").write_text(json.dumps(doc))
    return load_truth(tmp_path / "t.json")


def test_without_the_key_every_simulated_robot_is_as_it_was(tmp_path):
    t = _serial_truth(tmp_path)
    assert t.repeatability is None and "repeatability" not in truth_to_dict(t)
    clock = Clock()
    sim = SimulatedSerial(t, clock=clock)
    q = sim.home_qm + 0.3
    sim.move_to(q)
    clock.t += 30
    assert np.array_equal(sim.qm(), np.array([a.position() for a in sim.axes]))
    assert all(a.play == 0.0 for a in sim.axes)
    agebot = SimulatedAgebot(load_truth(ROOT / "fixtures" / "truth" / "agebot-sm.json"),
                             clock=clock)
    assert all(a.backlash == a.positioning == 0.0 for a in agebot.axes)


def test_a_truth_with_repeatability_moves_the_links_not_the_encoders(tmp_path):
    t = _serial_truth(tmp_path, {"backlash": 2e-5, "positioning": [1e-6] * 6})
    assert t.repeatability["backlash"] == (2e-5,) * 6
    save_truth(t, tmp_path / "again.json")
    assert load_truth(tmp_path / "again.json").repeatability == t.repeatability
    assert json.loads((tmp_path / "again.json").read_text())["repeatability"] == {
        "backlash": 2e-5, "positioning": 1e-6}
    clock = Clock()
    sim = SimulatedSerial(t, clock=clock, seed=1)
    k = np.abs([t.parameters[f"k{i}"] for i in range(1, 7)])
    assert np.allclose([a.backlash for a in sim.axes], 2e-5 / k)     # joint rad -> actuator
    q = sim.home_qm + 0.2
    sim.move_to(q)                     # every axis from below
    clock.t += 30
    motor = np.array([a.position() for a in sim.axes])
    assert np.allclose(motor, q)
    d = (sim.qm() - motor) * k
    assert np.all(np.abs(d + 1e-5) < 6e-6), d          # half the backlash, trailing
    enc = sim.encoder_increments(0, 131072)
    assert enc == round(q[0] * 131072)                  # the encoder reads the motor


def test_bad_repeatability_is_refused_naming_the_key(tmp_path):
    t = _serial_truth(tmp_path)
    doc = truth_to_dict(t)
    doc["robot_file"] = str(HAYATI)
    for bad, *words in (({"backlash": 0.5}, "repeatability.backlash", "not a robot's play"),
                        ({"backlash": [1e-5] * 5}, "repeatability.backlash", "6 values"),
                        ({"positioning": -1e-6}, "repeatability.positioning", ">= 0"),
                        ({"jitter": 1e-6}, "repeatability.jitter", "unknown key")):
        with pytest.raises(ConfigError) as e:
            parse_truth({**doc, "repeatability": bad}, "t.json")
        for w in words:
            assert w in str(e.value), str(e.value)
