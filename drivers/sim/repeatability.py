"""A truth file's ``repeatability``: how the simulated drives position, as a real robot's
do (docs: :mod:`drivers.sim.truth`, the play itself: :mod:`drivers.sim.axis`).

``{"backlash": b, "positioning": p}``: each joint's whole backlash and the std of a random
positioning error per move, in the joint's units (rad; m for a prismatic joint or
AGEBOT's rail), one number for every joint or a list of one per joint. Left out, the link
is where the motor is (every simulated session as before).
"""
from __future__ import annotations

import numpy as np

from drivers.config_reader import KeyReader, frozen_map

#: the largest backlash or positioning error a truth file may give (rad, m)
MAX_PLAY = 0.01
KEYS = ("backlash", "positioning")


def parse_repeatability(top: KeyReader, n: int):
    """The ``repeatability`` table of a truth object ``top`` for ``n`` joints, per joint
    (``{"backlash": (n,), "positioning": (n,)}``), or None where it is not given."""
    rr = top.table("repeatability", required=False)
    if rr is None:
        return None
    out = {}
    for key in KEYS:
        vals = rr.float_list(key, length=n, lo=0.0, scalar_ok=True, default=(0.0,) * n)
        for i, v in enumerate(vals):
            if v > MAX_PLAY:
                rr.fail(key, f"{v:g} (joint {i + 1}) is not a robot's play: at most "
                        f"{MAX_PLAY:g} (rad, m; a few arc-seconds is 1e-5)")
        out[key] = tuple(float(v) for v in vals)
    rr.finish()
    return frozen_map(out)


def repeatability_dict(truth) -> dict:
    """The JSON ``repeatability`` of a truth (one number where every joint's is the same)."""
    return {key: (vals[0] if len(set(vals)) == 1 else list(vals))
            for key, vals in truth.repeatability.items()}


def axis_play(truth, model, xi, seed: int | None) -> list[dict]:
    """Per actuator, the :class:`~drivers.sim.axis.SimAxis` keywords of ``truth``'s
    repeatability: ``backlash`` and ``positioning`` in actuator units (the joint's value
    over the true gear ratio ``|k{i}|`` where the model has one) and ``rng``, seeded by
    ``seed`` and the axis (fresh entropy where ``seed`` is None); empty dicts where the
    truth has no repeatability."""
    n = model.n_actuators
    rep = getattr(truth, "repeatability", None)
    if not rep:
        return [{} for _ in range(n)]
    names = list(model.param_names)
    out = []
    for i in range(n):
        k = abs(float(xi[names.index(f"k{i + 1}")])) if f"k{i + 1}" in names else 1.0
        k = k if k > 0 else 1.0
        rng = np.random.default_rng(None if seed is None else [int(seed), 9283, i])
        out.append({key: float(rep[key][i]) / k for key in KEYS} | {"rng": rng})
    return out
