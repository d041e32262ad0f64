"""The arm's distance sessions planned in rounds, inside the safety envelope.

A robot whose gear ratios differ from the nominal by tens of percent goes
somewhere else than the nominal model says: planned with the nominal, poses of
the report's box end up to 80 deg and 0.4 m outside it. So the arm's plan grows
with what the station has learnt (sm-distance-tilt and sm-distance):

Round 0, the *scout*, steps a little from the reference in actuator space
(:func:`station.planning.arm_plan.plan_sm_scout`: the start values' error is a fraction
of a small motion, whatever the arm's configuration). Round ``r >= 1`` is
planned in the method's box shrunk to ``SCALES[r]`` (30 %, then the whole box;
sm-distance-tilt's box centred on the reference pose as read there, tilt
included; sm-distance's about its middle), with the model fitted to the poses
measured so far, every round after the scout the D-optimal choice given the fit
poses measured. The first two rounds take an eighth of the requested fit poses each
(at least 6) *in addition* to them; the last round the requested fit poses and the
held-out ones, in the whole box: the design a one-shot plan would have, made given
the early poses.

Every move is watched (:func:`station.planning.envelope.watched_move`) against the current
model. Where the live tilt or distance departs by more than the config's
tolerance the arm stops there, that pose is not recorded, the rest of the round
is dropped (``skip`` events) and re-planned with the model refitted on the poses
so far; where nothing new was learnt since the last stop the round's box is
halved first. Below :data:`MIN_SCALE` the session stops and tells the operator
what to do. Everything is in the trace (``plan`` events with ``round`` and
``box_scale``, ``envelope`` events), so a resumed session continues the same way.
"""
from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from calibration.errors import CalibrationError, StationError
from calibration.methods import MethodData, build
from calibration.robots.agebot_sm import wrap
from calibration.robots.base import canonical_result
from calibration.solver import SolverOptions, solve
from calibration.ties import less, tied
from station.fitting.gate_checks import implausible
from station.fitting.pose_count import minimum_count
from station.fitting.start_values import fixed_for_rows, staged_start, told_start
from station.planning.arm_plan import SM_SCOUT_STEP, plan_sm, plan_sm_scout
from station.planning.envelope import ANGLE_CHANNELS, sm_predictor, within_limits
from station.recording import resume

log = logging.getLogger("station.session")

SCALES = (0.1, 0.3, 1.0)  # each round's box, as a fraction of the method's box
SCOUT_SCALE = SCALES[0]
MIN_SCALE = 0.02         # below this the envelope gives up: the start model is too wrong
SCOUT_MIN = 6
EARLY_SHARE = 8          # the scout and the middle round: an eighth of the count each
#: a refit is used where it explains every recorded reading within this share of the
#: envelope's tolerance, or better than the model in use (a model that cannot explain
#: what was measured cannot be trusted to predict where the arm goes next)
EXPLAIN = 0.2
#: what an sm-distance session's planning fit by distance and tilt (in the reference's
#: frame) hands over to the session's model: the parameters that do not depend on the
#: frame, and q2_off, which distances do not see (it turns the reference and the tool
#: alike) and which the canonical form turns by pi with L4's sign
PHYSICAL = ("q2_off", "q3_off", "q4_off", "k1", "k2", "k3", "k4", "L2", "L3", "L4")

#: iterations of a planning refit (a few poses: it may crawl for hundreds as its noise
#: weights wander; judged by what it explains, :meth:`ArmRounds.refit`; of 16 drawn
#: sessions' refits run to 50, every converged one explained as well by its 20th but
#: two, by 29 and 33), and of each stage of a grown start (a start for the next stage)
PLAN_MAX_ITER, STAGE_MAX_ITER = 30, 20


class EnvelopeExhausted(StationError):
    """The arm departs from the model even close to the reference: stop, ask the operator."""


class ArmRounds:
    """The round plan of one arm session (``session``: :class:`station.session.session.Session`)."""

    def __init__(self, session):
        self.s = session
        self.xi = self._start_model()
        self.distance_off = 0.0
        self.learnt_at_stop: int | None = None   # poses measured at the last stop
        self.fitted_on = 0                        # poses the model was last fitted on
        self.prev_xi: np.ndarray | None = None    # the model before the last refit
        self._totals: tuple[int, int] | None = None  # set by a new plan
        self.design: dict | None = None           # the last round's design record

    # -- the model ---------------------------------------------------------------------
    def _start_model(self) -> np.ndarray:
        """The start values, told what the reference showed (:func:`told_start`)."""
        s = self.s
        return told_start(s.method, s.robot, s.nominal, s.reference_qm,
                          (s.reference_record or {}).get("tilt"))

    def refit(self) -> None:
        """The model fitted to the fit poses measured so far and to the readings where
        the envelope stopped the arm (:meth:`_stops`), from the start values and, where
        that fit does not converge explaining every reading within :data:`EXPLAIN`, from
        start values grown with the data (:func:`staged_start`): a function of the
        recorded poses alone, so a resumed session plans as the uninterrupted one
        would. Of the fits the gate finds plausible that explain every recorded reading
        within :data:`EXPLAIN` of the envelope's tolerance, or at least as well as the
        model in use, a converged one first (few poses), then the least residual; where
        none does (a fit of few poses can be wild: it predicted -1.3 m for a draw-wire
        reading 0.02 m, and every move from then on was stopped), planning
        stays with the model it had."""
        s = self.s
        recs = [r for r in s.measured.values() if r.get("use", "fit") == "fit"]
        if len(recs) < 2:
            return
        tilt_ref = self._tilt_ref()
        chans = tuple(s.info.channels)
        if tilt_ref is not None and all("tilt" in r for r in recs):
            chans += ("tilt",)
        stops = self._stops(chans)
        recs += stops
        what = f"{len(recs) - len(stops)} poses" + (f" and {len(stops)} envelope stop(s)"
                                                    if stops else "")
        ref = s.reference_record or {}
        data = MethodData(qm=np.array([r["qm"] for r in recs]),
                          channels={ch: np.array([r[ch] for r in recs]) for ch in chans},
                          reference_qm=s.reference_qm, distance_zero=ref.get("zero", "exact"))
        # sm-distance beside an inclinometer: planned with the fit of distance and tilt
        # (distance alone cannot tell a mirrored arm: seed 9160's middle round went 0.27 m
        # beyond its box with every distance as predicted)
        fit_method = "sm-distance-tilt" if "tilt" in chans and s.method == "sm-distance" \
            else s.method
        start = told_start(fit_method, s.robot, s.nominal, s.reference_qm, ref.get("tilt"))
        def starts():    # grown only where the told start's fit is not converged within
            yield start  # EXPLAIN (where it was, the grown one ended at the same minimum)
            if len(recs) >= 8 and not (best and not best[0][0] and best[4] <= EXPLAIN):
                staged = staged_start(fit_method, s.robot, data, start, max_iter=STAGE_MAX_ITER)
                if staged is not None:
                    yield staged
        best, why, judge = None, "no fit", None
        # what the model in use leaves unexplained: a refit must do at least as well
        bar = max(EXPLAIN, self._unexplained(self.xi, self.distance_off, data))
        for x0 in starts():
            try:
                model = build(fit_method, s.robot, data, x0)
                judge = model if judge is None else judge  # the told start's (the gate's)
                res = solve(model, SolverOptions(max_iter=PLAN_MAX_ITER,
                                                 fixed=fixed_for_rows(model)))
            except (CalibrationError, np.linalg.LinAlgError, ValueError) as e:
                why = str(e)
                continue
            if not np.all(np.isfinite(res.x)):
                why = res.message
                continue
            # a fit of few poses may not meet the solver's step tolerance (the noise
            # weights estimated on a few degrees of freedom wander); for planning it is
            # judged by what it explains, a converged one preferred, never one the gate
            # would refuse (6 poses: L3 a third of nominal, 0.27 m read, 0.05 predicted)
            bad = implausible(judge, canonical_result(model.robot, res, frame_free=True),
                              fit_method, serial=False)
            if bad:
                why = ("it moves " + ", ".join(f"{p['name']} from {p['start']:.4g} to "
                                               f"{p['calibrated']:.4g}" for p in bad)
                       + ", farther than a real robot departs from its start (too few poses)")
                continue
            xi, off = self._model_of(res.x, fit_method)
            worst = self._unexplained(xi, off, data)
            if worst > bar and not tied(worst, bar):   # as well as the model in use: a tie
                why = (f"{'' if res.converged else res.message + '; '}it leaves a recorded reading "
                       f"{worst:.2g} x the envelope's tolerance away from its prediction, the "
                       "model in use less")
                continue
            key = (not res.converged, float(np.sum(np.asarray(res.residual) ** 2)))
            if best is None or less(key, best[0]):   # one minimum from two starts: a tie
                best = (key, xi, off, res, worst)
        self.fitted_on = len(recs)
        if best is None:
            s._event("warning", f"model refit on {what} not used ({why}): planning "
                     "stays with the model it had")
            return
        _, xi, off, res, _ = best
        self.prev_xi = self.xi
        self.xi, self.distance_off = xi, off
        s._event("info", f"model refitted on {what} ({res.n_identifiable} parameters "
                 f"identifiable): {res.message}")

    def _tilt_ref(self) -> float | None:
        """sm-distance at a station with an inclinometer: its reading at the reference
        (the watch predicts the tilt from there, :func:`station.planning.envelope.sm_predictor`);
        else None."""
        s = self.s
        if s.method != "sm-distance" or getattr(s, "serial", False):
            return None
        tilt = (s.reference_record or {}).get("tilt")
        return None if tilt is None else float(tilt)

    def _stops(self, chans) -> list[dict]:
        """Where the envelope stopped the arm: its qm and the sensors' readings at rest
        there (the ``envelope`` events'), rows of the planning refits. The pose was not
        reached and is not recorded for the calibration, but where the arm went instead
        is what the model did not know (a scout of small steps cannot tell a gear ratio
        30 % off from a length; the stop 15 cm off can)."""
        out = []
        for ev in self.s.events:
            got = ev.get("readings") if ev.get("kind") == "envelope" else None
            if got and "qm" in ev and all(ch in got for ch in chans):
                out.append({"qm": ev["qm"], **{ch: float(got[ch]) for ch in chans}})
        return out

    def _model_of(self, x, fit_method: str | None = None) -> tuple[np.ndarray, float]:
        """A solver's ``x`` as the robot's canonical parameters and the distance offset.
        An sm-distance session's fit by distance and tilt (``fit_method``) is in the
        reference's frame: its physical parameters (:data:`PHYSICAL`) go into the
        session's start values, whose frame sm-distance plans in."""
        robot = self.s.robot
        n = robot.n_params
        xi = robot.canonical(np.asarray(x[:n], dtype=float), frame_free=True)[0]
        off = float(x[n]) if len(x) > n else 0.0
        if fit_method is not None and fit_method != self.s.method:
            world = self._start_model()
            idx = [robot.index(name) for name in PHYSICAL]
            world[idx] = xi[idx]
            xi = world
        return xi, off

    def _unexplained(self, xi, distance_off: float, data: MethodData) -> float:
        """The largest departure of a recorded reading from the model's prediction at its
        pose, as a multiple of the envelope's tolerance (the watch's own measure)."""
        s = self.s
        pred = sm_predictor(s.method, s.robot, xi, s.reference_qm, distance_off,
                            self._tilt_ref())(data.qm)
        worst = 0.0
        for ch, tol in s.config.envelope.tolerance.items():
            if ch in pred and ch in data.channels:
                d = np.asarray(data.channels[ch], dtype=float) - pred[ch]
                if ch in ANGLE_CHANNELS:
                    d = (d + math.pi) % (2 * math.pi) - math.pi
                worst = max(worst, float(np.max(np.abs(d))) / tol)
        return worst

    def predictor(self):
        """What the sensors should read at ``qm`` under the current model."""
        s = self.s
        if s.reference_qm is None:
            return None
        if self.fitted_on == 0 and s.measured:     # a resumed session: learn from its poses
            self.refit()
        return sm_predictor(s.method, s.robot, self.xi, s.reference_qm, self.distance_off,
                            self._tilt_ref())

    # -- counts ------------------------------------------------------------------------
    def totals(self) -> tuple[int, int]:
        """Fit and held-out poses of the whole session: as the first plan event recorded
        them (a resumed session keeps its counts), else from the request."""
        if self._totals is not None:
            return self._totals
        for ev in reversed(self.s.events):
            if ev.get("kind") == "plan" and "totals" in ev:
                return int(ev["totals"][0]), int(ev["totals"][1])
        return self._requested()

    def _requested(self) -> tuple[int, int]:
        req = self.s.request
        count = req.count or int(np.ceil(req.margin * minimum_count(self.s.method)))
        n_val = req.validation if req.validation is not None else max(3, count // 5)
        return count, n_val

    def round_targets(self, rnd: int) -> tuple[int, int]:
        """Fit and held-out poses of round ``rnd``: the scout and the middle round
        ``max(SCOUT_MIN, count / EARLY_SHARE)`` fit poses each, *on top of* the requested
        count; the last round the requested count and the held-out poses, in the whole
        box. The early rounds are for safety and learning; the last is the design a
        one-shot plan would have, chosen given the early poses, so the whole is at
        least as informative as the one-shot plan."""
        count, n_val = self.totals()
        if rnd < len(SCALES) - 1:
            return max(SCOUT_MIN, math.ceil(count / EARLY_SHARE)), 0
        return count, n_val

    def fit_total(self) -> int:
        """Fit poses of every round together."""
        return sum(self.round_targets(r)[0] for r in range(len(SCALES)))

    def _measured_in(self, rnd: int, use: str) -> int:
        by_index = {p.index: p for p in self.s.plan_poses}
        return sum(1 for i, r in self.s.measured.items()
                   if i in by_index and by_index[i].round == rnd and r.get("use", "fit") == use)

    # -- planning ----------------------------------------------------------------------
    def _plan(self, rnd: int, scale: float, start_qm) -> list:
        s = self.s
        fit, val = self.round_targets(rnd)
        fit -= self._measured_in(rnd, "fit")
        val -= self._measured_in(rnd, "validation")
        if fit + val <= 0:
            return []
        req = dataclasses.replace(s.request, count=max(fit, 1), validation=val,
                                  seed=s.request.seed + 7919 * rnd + len(s.plan_poses),
                                  # --target-std is met by the last round, in the whole box
                                  target=s.request.target if rnd == len(SCALES) - 1 else None)
        first = max((p.index for p in s.plan_poses), default=-1) + 1
        if rnd == 0:
            return plan_sm_scout(self.xi, s.reference_qm, fit, req.seed,
                                 accept=within_limits(s.config.envelope), first_index=first,
                                 step=np.multiply(SM_SCOUT_STEP, scale / SCOUT_SCALE))
        measured = [r["qm"] for r in s.measured.values() if r.get("use", "fit") == "fit"]
        designs: list = []
        poses = plan_sm(s.method, self.xi, s.reference_qm, req, box_scale=scale,
                        accept=within_limits(s.config.envelope), first_index=first,
                        rnd=rnd, start_qm=start_qm, box_centre=self.box_centre(scale),
                        measured_qm=measured, design_out=designs)
        self.design = designs[0] if designs else None
        if fit <= 0:        # only held-out poses left
            poses = [p for p in poses if p.use == "validation"] or poses[:0]
        return poses

    def _design(self) -> dict:
        """The plan event's design (what it predicts for every fit pose so far), if any."""
        return {"design": self.design} if self.design else {}

    def box_centre(self, scale: float):
        """Where the box is centred: sm-distance-tilt's on the reference pose as read
        there (the base origin and its tilt: a start model far off may have put the
        last link 50 deg from level, and turning it level is a reconfiguration the
        model cannot predict yet); sm-distance's on the box's middle."""
        if self.s.method != "sm-distance-tilt":
            return None
        tilt = (self.s.reference_record or {}).get("tilt", 0.0)
        return np.array([0.0, 0.0, 0.0, float(wrap(tilt))])

    def first_plan(self) -> list:
        """Round 0, the scout (the session records it as its plan, with the session's
        counts from the request)."""
        self._totals = self._requested()
        self.xi = self._start_model()
        return self._plan(0, SCOUT_SCALE, self.s.reference_qm)

    def planned_last(self) -> bool:
        """True once the last round (the whole box) is planned."""
        return max((p.round for p in self.s.plan_poses), default=0) >= len(SCALES) - 1

    def next_round(self) -> bool:
        """Refit and plan the next round; False when the last one is done."""
        s = self.s
        rnd = max((p.round for p in s.plan_poses), default=0) + 1
        while rnd < len(SCALES):
            self.refit()
            poses = self._plan_safely(rnd, SCALES[rnd], s.qm())
            if poses:
                s._set_plan(poses, replace=False, box_scale=SCALES[rnd], **self._design())
                return True
            rnd += 1
        return False

    def _plan_safely(self, rnd: int, scale: float, start_qm) -> list:
        """:meth:`_plan`; where the fitted model reaches too few poses of the box (a fit
        of few poses can be wild), plan in a box half as large, down to the scout's."""
        while True:
            try:
                return self._plan(rnd, scale, start_qm)
            except CalibrationError as e:
                if self.prev_xi is not None:     # a wild refit: plan with the model before it
                    self.s._event("warning", f"round {rnd}: {e} with the refitted model; "
                                  "planning with the model before it")
                    self.xi, self.prev_xi = self.prev_xi, None
                    continue
                if scale <= SCOUT_SCALE:
                    raise
                self.s._event("warning", f"round {rnd}: {e}; planning in a smaller box")
                scale = max(scale / 2, SCOUT_SCALE)

    def replan_after_stop(self, stopped_round: int, scale: float) -> None:
        """The arm was stopped: drop the rest of the round, refit, plan it again (in a
        box half as large where nothing was learnt since the last stop)."""
        s = self.s
        for p in s.pending:
            if p.round == stopped_round:
                s._skip(p, f"pose {p.index} dropped: re-planned after the envelope stop",
                        resume.DROPPED)
        learnt = len(s.measured)
        if self.learnt_at_stop is not None and learnt <= self.learnt_at_stop:
            scale *= 0.5            # nothing learnt since the last stop: closer in
        self.learnt_at_stop = learnt
        if scale < MIN_SCALE:
            raise EnvelopeExhausted(
                "the arm departs from the model's prediction even within "
                f"{100 * scale:.0f} % of the box around the reference: the start values are too "
                "far from this robot. Enter the gear ratios (k1..k4) from the drives' data sheets "
                "and the link lengths as measured (app.py run --nominal k1=...), check the "
                "[envelope.tolerance] of the station config, then start a new session")
        self.refit()
        poses = self._plan_safely(stopped_round, scale, s.qm())
        if poses:
            s._set_plan(poses, replace=False, box_scale=scale, **self._design())

    def scale_of(self, pose) -> float:
        """The box scale the pose's round was planned with (from the plan events)."""
        for ev in reversed(self.s.events):
            if ev.get("kind") == "plan" and any(r["index"] == pose.index
                                                for r in ev.get("poses", ())):
                return float(ev.get("box_scale", SCALES[min(pose.round, len(SCALES) - 1)]))
        return 1.0
