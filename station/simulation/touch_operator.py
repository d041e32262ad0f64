"""The simulated operator of guided touching (sm-plane, sm-self-redundancy).

At a real station an operator jogs the tool tip until it touches: the plane
(a feeler gauge tells when), or a mark such as a pin (the eye tells). Headless
(``app.py run --simulate``) nobody watches, so :class:`SimulatedOperator` plays
that part: it is a session's ``touch`` callback that sees the contact through
the simulator's control port (``{"contact": true}``: the true tool tip and its
signed distance from the truth's plane, :mod:`drivers.sim.sim_station`) and moves
the robot only as an operator can, with :meth:`Session.move_to` (multi-axis
jogs in actuator units) from the approach pose. It chooses jog directions with
the session's start model (the nominal Jacobian), which is all an operator's
jog panel knows, and iterates on what it sees:

* **sm-plane**: from the approach pose, along the actuator direction that moves
  the nominal tip towards the rough plane with phi kept, a secant search on
  the true distance until ``|distance| < tol`` (1e-6 m).
* **sm-self-redundancy**: the first pose of a pair touches the mark where the
  tip is (the mark is placed there: its true ``x, y`` are read); at the second
  pose (the other phi) a quasi-Newton iteration on the arm's three actuators
  brings the true tip's ``x, y`` onto the mark, the true ``phi`` held where the
  approach put it (Broyden updates of the nominal Jacobian, steps limited to
  10 cm of predicted tip travel) until within ``tol``; it gives up where the
  tip stops getting closer (a mark the arm cannot reach at that phi, e.g. too
  close to the shoulder for the folded arm). After a restart the mark is
  found again by going back to the pair's recorded first pose.

Where it cannot make the contact (no convergence) it raises
:class:`~station.session.execution.TouchFailed`: the session skips the pose (with its pair).
Nothing here is used at a real station.
"""
from __future__ import annotations

import logging

import numpy as np

from calibration.errors import StationError
from calibration.robots import get_robot
from station.session.execution import TouchFailed

log = logging.getLogger("station.simulation.touch_operator")


class SimulatedOperator:
    """A ``touch(session, pose)`` callback for a simulated station.

    control:   a :class:`drivers.sim.control.SimControl` of the running simulator.
    tol:       contact tolerance, m (plane distance; pair: |x, y| from the mark).
    max_moves: jogs per contact before giving up (TouchFailed).
    step:      largest predicted tip travel per jog, m.
    reach:     farthest predicted tip travel from the approach pose, m.
    patience:  a pair's second pose: jogs without getting closer before giving up.
    """

    def __init__(self, control, *, tol: float = 1e-6, max_moves: int = 40, step: float = 0.1,
                 reach: float = 1.0, patience: int = 6):
        self.control = control
        self.tol, self.max_moves, self.patience = float(tol), int(max_moves), int(patience)
        self.step, self.reach = float(step), float(reach)
        self.robot = get_robot("agebot-sm")
        self.marks: dict[int, np.ndarray] = {}     # group -> true (x, y) of the mark
        self.moves = 0                              # jogs made (all contacts)

    def __call__(self, session, pose) -> None:
        if session.method == "sm-plane":
            self._touch_plane(session, pose)
        elif session.method == "sm-self-redundancy":
            self._touch_mark(session, pose)
        else:
            raise TouchFailed(f"{session.method} is not measured by touching")

    # -- what the operator sees ------------------------------------------------------------
    def contact(self) -> dict:
        return self.control.call(contact=True)["contact"]

    def _jacobian(self, session, qm) -> np.ndarray:
        """d[x, y, z, phi]/d qm of the session's start model (central differences)."""
        h = 1e-5
        J = np.empty((4, len(qm)))
        for j in range(len(qm)):
            e = np.zeros(len(qm))
            e[j] = h
            J[:, j] = (self.robot.fk(qm + e, session.nominal)[0]
                       - self.robot.fk(qm - e, session.nominal)[0]) / (2 * h)
        return J

    def _move(self, session, qm) -> None:
        """Jog to ``qm``, stopping at the station's actuator limits as an operator stops
        short of the end stops (the session refuses a target beyond them)."""
        session.check_abort()
        env = session.config.envelope
        qm = np.asarray(qm, dtype=float)
        if env.qm_min is not None:
            qm = np.maximum(qm, env.qm_min)
        if env.qm_max is not None:
            qm = np.minimum(qm, env.qm_max)
        session.move_to(qm)
        self.moves += 1

    # -- sm-plane ---------------------------------------------------------------------------
    def _touch_plane(self, session, pose) -> None:
        plane = session.plane
        normal = plane / np.linalg.norm(plane)
        q0 = session.qm()
        # actuator direction moving the nominal tip 1 m towards the plane, phi kept
        try:
            d = np.linalg.solve(self._jacobian(session, q0), np.r_[-normal, 0.0])
        except np.linalg.LinAlgError:
            raise TouchFailed("the start model is singular at the approach pose") from None
        r0 = self._distance()
        if abs(r0) < self.tol:
            return
        t_prev, r_prev = 0.0, r0
        t = r0                       # predicted: the distance falls by t along d
        for _ in range(self.max_moves):
            self._move(session, q0 + t * d)
            r = self._distance()
            if abs(r) < self.tol:
                return
            slope = (r - r_prev) / (t - t_prev) if t != t_prev else -1.0
            if not np.isfinite(slope) or slope > -0.05:
                slope = -1.0         # flat or wrong-way reading: trust the model again
            t_prev, r_prev = t, r
            t = t - float(np.clip(r / slope, -self.step, self.step))
            log.debug("plane pose %d: distance %.3g m, next t %.4g", pose.index, r, t)
            if abs(t) > self.reach:
                break
        raise TouchFailed(f"the tip did not reach the plane (last distance {r_prev:.3g} m, "
                          f"{abs(t):.2g} m of predicted travel from the approach pose)")

    def _distance(self) -> float:
        d = self.contact()["distance"]
        if d is None:     # nothing to touch anywhere: a setup error, not one pose's failure
            raise StationError("the simulated robot has no plane to touch: give the truth "
                               "file plane_a, plane_b, plane_c")
        return float(d)

    # -- sm-self-redundancy -------------------------------------------------------------------
    def _touch_mark(self, session, pose) -> None:
        group = session.group_of(pose)
        if pose.index == group[0].index:       # the first pose: the mark is where the tip is
            self.marks[pose.group] = np.array(self.contact()["tip"][:2])
            return
        mark = self.marks.get(pose.group)
        if mark is None:                       # after a restart: find the mark again
            first = session.measured_record(group[0].index)
            if first is None:
                raise TouchFailed(f"the first pose of pair {pose.group} was not recorded")
            self._move(session, first["qm"])
            mark = self.marks[pose.group] = np.array(self.contact()["tip"][:2])
            self._move(session, pose.qm)
        c = self.contact()
        target = np.r_[mark, c["phi"]]          # x, y of the mark; phi where it is now

        def error(c):
            return np.r_[c["tip"][:2], c["phi"]] - target

        q = session.qm()
        f = error(c)
        A = self._jacobian(session, q)[[0, 1, 3]][:, 1:]   # (x, y, phi) by the arm's axes
        best, since_best = np.inf, 0
        for _ in range(self.max_moves):
            miss = float(np.linalg.norm(f[:2]))
            if miss < self.tol:
                return
            if miss < best:
                best, since_best = miss, 0
            else:
                since_best += 1
                if since_best >= self.patience:
                    break            # not getting closer: the mark is out of reach at this phi
            try:
                d = -np.linalg.solve(A, f)
            except np.linalg.LinAlgError:
                break
            travel = float(np.linalg.norm((A @ d)[:2]))
            if travel > self.step:
                d *= self.step / travel
            q_new = q.copy()
            q_new[1:] += d
            self._move(session, q_new)
            q_new = session.qm()
            f_new = error(self.contact())
            dq = q_new[1:] - q[1:]
            if np.linalg.norm(dq) > 1e-4:      # Broyden (steps above the encoder's grain)
                A += np.outer(f_new - f - A @ dq, dq) / (dq @ dq)
            q, f = q_new, f_new
        raise TouchFailed(f"the tip did not reach the mark of pair {pose.group} "
                          f"(closest {best:.3g} m)")
