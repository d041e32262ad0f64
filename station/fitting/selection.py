"""What each calibrated parameter buys (issue 42, item 3): cross-validation over the fit
poses, every robot parameter held at its start value in turn.

A parameter is worth calibrating where the fit that holds it predicts the poses it has
not seen worse (:mod:`calibration.cross_validation`: each pose's error as the fit
without it predicts it, the two models compared pose by pose, ``p < PREFER_P``). One
whose estimate is within its std of the start value and whose holding predicts those
poses better is named: the data do not need it. Such parameters are stated, not held:
on real arms (TIAGo, an industrial arm's tracker data) holding them changed the
held-out error by under 1 %, and a parameter held at a wrong start biases the others
while one calibrated near its start costs only its variance. The registration (the
base frame in the instrument's) and the instrument's own parameters are not judged.
"""
from __future__ import annotations

import numpy as np

from calibration import cross_validation as cv
from calibration import quality as q

#: above this many residual rows the parameters are not judged (one factorization per
#: parameter)
MAX_ROWS = 20000


def judge(model, result) -> dict | None:
    """``{"poses", "worth": [...], "as_well_held": [...], "parameters": [...]}`` for the
    fit's robot parameters (module doc), None where the rows have no poses or are too
    many."""
    from station.fitting.gate import row_poses

    rp = row_poses(model)
    if rp is None or len(rp) > MAX_ROWS:
        return None
    r, W = model.evaluate(result.x)
    active = np.array([s.identifiable for s in result.status])
    w = q.row_weights(model.row_channel, model.channels, result.sigma)
    extra = set(getattr(model, "extra_names", ()) or ())
    x, x0, std = (np.asarray(v, dtype=float) for v in (result.x, model.x0, result.std))
    judged = [j for j in np.flatnonzero(active)
              if model.names[j] not in extra and not model.names[j].startswith("base_")]
    full = cv.unseen_errors(r, W, w, active, rp)
    held = cv.held_in_turn(r, W, w, active, rp, {j: x0[j] - x[j] for j in judged})
    out = {"poses": len(full), "worth": [], "as_well_held": [], "parameters": []}
    for j in judged:
        c = cv.compare_models(full, held[j])
        if c is None:
            return None
        t = float((x[j] - x0[j]) / std[j]) if std[j] > 0 else float("inf")
        name = model.names[j]
        out["parameters"].append({"name": name, "t": t, "p_held_better": c.p,
                                  "p_held_worse": c.p_worse})
        if c.worse:
            out["worth"].append(name)
        elif c.better and abs(t) < 1.0:
            out["as_well_held"].append(name)
    return out


def statement(sel: dict) -> str:
    """One line for people."""
    n, worth, well = len(sel["parameters"]), sel["worth"], sel["as_well_held"]
    text = (f"cross-validation over {sel['poses']} fit poses, each robot parameter held at "
            f"its start in turn: {len(worth)} of {n} clearly needed (without it the poses "
            f"the fit has not seen are predicted worse, p < {cv.PREFER_P:g})")
    if well:
        text += (f", {len(well)} as well held (estimates within their std of the start: "
                 f"{', '.join(well[:8])}{f' and {len(well) - 8} more' if len(well) > 8 else ''})")
    rest = n - len(worth) - len(well)
    if rest:
        text += f", {rest} undecided by these poses"
    return text + "; all calibrated"
