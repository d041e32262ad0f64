"""Bench: calibration.solver.solve (Algorithm 2) against scipy.optimize.least_squares.

Per problem (sm-full-pose, sm-distance with the plain residual, sm-distance-tilt;
each noise-free and noisy, the same poses for both; and sm-distance on the same arm
written as a robot file, the generic serial model a user's arm gets:
``bench/_common.py`` ``make_robot_file_problems``; at the default sizes also that
robot file over the fixture trace ``fixtures/traces/sm-distance.jsonl`` from its
nominal, a fit that swings: ``make_fixture_problem``) it runs

* ``ours``       ``solve(model)`` with the default ``SolverOptions`` (the robot
  file's problems: its ``fixed`` and the stated sigma, as the station runs a trace);
* ``lm-jac``     ``least_squares(method='lm')``, analytic Jacobian ``-W``;
* ``lm-2pt``     ``least_squares(method='lm')``, finite differences ('2-point');
* ``trf-jac``, ``trf-2pt``  the same with ``method='trf'``;
* ``lm-jac-w``, ``trf-jac-w``  (noisy multi-channel problems only) the station's
  own mode, sigma estimated: least_squares on the plain residual, then the
  per-channel sigma estimated there as ours does (eq. 51, leverage degrees of
  freedom, one sensor's channels pooled where their noise is equal) and the
  residual weighted by ``1/sigma`` per channel solved again from that solution,
  until no channel's sigma moves by more than 5 % (ours' rounds and stopping
  rule, at most 6 rounds); the estimation is timed with the run. The plain
  runs converge to the unweighted optimum, which differs by O(std) when the
  channels' noise differs;
* ``lm-jac-given-w`` (information only, not in the ratio): lm handed the
  sigma *our* solver used in its last round, i.e. the last weighted problem
  only, with no weight estimation;
* ``*-dtol``     (information only, not in the ratio) the fastest analytic run
  again with scipy's *default* tolerances (1e-8), to show where they stop.

All scipy runs start from the method's ``x0``, move only the parameters our
solver found identifiable (the others stay at ``x0``), use
``xtol = ftol = gtol = 1e-12`` and ``x_scale='jac'`` by default (the analogue of
the column scaling H; ``--x-scale 1`` for none); ours stops when the largest
step component is below 1e-10 (parameter units). The analytic runs share one
``model.evaluate`` between ``fun`` and ``jac`` at the same point; the
finite-difference runs evaluate the residual by forward kinematics only (no
observation matrix), a residual identical to ``model.evaluate(x)[0]``.

Timing: every runner is called ``--repeats`` times, the runners interleaved
round by round (load on the machine hits all alike); the best (shortest) time
counts, the median is shown beside it. BLAS runs single-threaded (the
``*_NUM_THREADS`` variables are set to 1 before numpy loads; ``--blas-threads``
to change). The bench fails (exit 1) if a scipy run on the problem ours solves
does not converge to our optimum, or if ours ends in a spurious minimum (a sum of
squares, weighted by ours' final sigma per channel, above 1.5 times the truth's): then that problem has no ratio (a time to a
wrong answer is no time to the answer), and a scipy run that reached the truth's
minimum there is not counted as failing.

Columns: see bench/README.md. Run from the repository root::

    python bench/bench_solver.py            # full bench (~10 s)
    python bench/bench_solver.py --quick    # fewer repeats
    python bench/bench_solver.py --profile all
    python bench/bench_solver.py --poses 30 300 3000 --no-fd    # other sizes
"""
from __future__ import annotations

import os
import sys


def _blas_threads(argv) -> str:
    """``--blas-threads N`` from the command line (default 1), exported before
    numpy is imported (it is read when the BLAS library loads)."""
    n = "1"
    for i, a in enumerate(argv):
        if a == "--blas-threads" and i + 1 < len(argv):
            n = argv[i + 1]
        elif a.startswith("--blas-threads="):
            n = a.split("=", 1)[1]
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = n
    return n


BLAS_THREADS = _blas_threads(sys.argv[1:]) if __name__ == "__main__" else None

import argparse  # noqa: E402
import cProfile  # noqa: E402
import math  # noqa: E402
import pstats  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import scipy  # noqa: E402
from _common import (METHODS, interleaved_times, make_problems,  # noqa: E402
                     make_fixture_problem, make_robot_file_problems, table)
from scipy.optimize import least_squares  # noqa: E402

from calibration.solver import SIGMA_CHANGE, SIGMA_FLOOR, SolverOptions, solve  # noqa: E402
from calibration.solver import step as _step  # noqa: E402
from calibration.solver.weighting import _homogeneous  # noqa: E402

SCALED_LINE = _step.Scaled.__init__.__code__.co_firstlineno

TOL = 1e-12
SAME_ABS, SAME_STD = 1e-9, 1e-3
EVAL_BATCH = 5


# -- runners --------------------------------------------------------------------
class Counted:
    """The problem's functions for scipy over the identifiable parameters, with
    counters: ``model`` (model.evaluate calls, r and W), ``fk`` (residual-only
    calls) and ``fd`` (calls that differ from the last non-FD point in exactly
    one component: finite-difference probes)."""

    def __init__(self, prob, active, g):
        self.prob, self.active, self.g = prob, active, g
        self.x0 = np.array(prob.model.x0, dtype=float)
        self.n = int(active.sum())
        self.reset()

    def reset(self):
        self.model_calls = self.fk_calls = self.fd_calls = 0
        self._key = None
        self._rW = None
        self._base = None

    def full(self, z):
        x = self.x0.copy()
        x[self.active] = z
        return x

    def _eval(self, z):
        key = z.tobytes()
        if key != self._key:
            self.model_calls += 1
            self._key, self._rW = key, self.prob.model.evaluate(self.full(z))
        return self._rW

    def fun_jac(self, z):  # fun of the analytic runs
        r = self._eval(z)[0]
        return r if self.g is None else self.g * r

    def jac(self, z):
        W = self._eval(z)[1][:, self.active]
        return -W if self.g is None else -(self.g[:, None] * W)

    def fun_fk(self, z):  # fun of the finite-difference runs
        self.fk_calls += 1
        if self._base is not None and np.count_nonzero(z != self._base) == 1:
            self.fd_calls += 1
        else:
            self._base = z.copy()
        r = self.prob.residual(self.full(z))
        return r if self.g is None else self.g * r


def run_scipy(prob, active, g, method, analytic, x_scale, tol=TOL):
    """``(counter, once)``: ``once()`` runs least_squares; ``g`` (per-row
    weights of the residual) None for the plain residual; ``tol`` None for
    scipy's default tolerances."""
    c = Counted(prob, active, g)
    z0 = c.x0[active]
    tols = {} if tol is None else {"xtol": tol, "ftol": tol, "gtol": tol}

    def once():
        c.reset()
        if analytic:
            return least_squares(c.fun_jac, z0, jac=c.jac, method=method, x_scale=x_scale,
                                 **tols)
        return least_squares(c.fun_fk, z0, jac="2-point", method=method, x_scale=x_scale,
                             **tols)

    return c, once


def channel_sigma(c, z, g):
    """Per-channel sigma at ``z`` (eq. 51), estimated as our solver does
    (:meth:`calibration.solver.weighting.Weighting.channel_sigma`): each
    channel's residual sum of squares over its degrees of freedom, its rows less
    the sum of their leverages (diagonal of the hat matrix of ``G W_R``, ``g`` the
    weights the round was solved with), the channels of one sensor pooled where
    Bartlett's test finds their noise equal. What a scipy user needs to weight
    the channels as the station does; timed as part of the run."""
    model = c.prob.model
    r, W = c._eval(z)
    A = W[:, c.active] if g is None else W[:, c.active] * g[:, None]
    Q = np.linalg.qr(A / np.sqrt(np.einsum("ij,ij->j", A, A)))[0]
    rc = np.asarray(model.row_channel)
    nch = len(model.channels)
    rss = np.bincount(rc, weights=r * r, minlength=nch)
    dof = np.bincount(rc, minlength=nch) - np.bincount(rc, weights=np.einsum("ij,ij->i", Q, Q),
                                                       minlength=nch)
    sig = {ch: max(math.sqrt(s / d), SIGMA_FLOOR) for ch, s, d in zip(model.channels, rss, dof)}
    est = {ch: (s, d) for ch, s, d in zip(model.channels, rss, dof)}
    for group in getattr(model, "noise_groups", ()):
        sub = [est[ch] for ch in group if ch in est]
        if len(sub) > 1 and _homogeneous(sub):
            s = max(math.sqrt(sum(a for a, _ in sub) / sum(d for _, d in sub)), SIGMA_FLOOR)
            sig.update(dict.fromkeys(group, s))
    return sig


def run_scipy_reweighted(prob, active, method, x_scale, tol=TOL):
    """``(counter, once)`` for the station's own mode, sigma estimated: ``once()``
    runs least_squares on the plain residual (one sigma for all rows: the same
    optimum), estimates the per-channel sigma there (:func:`channel_sigma`),
    and while a channel's sigma moves by more than ``SIGMA_CHANGE`` (5 %) from the
    weights of the last round solves again on the residual weighted by
    ``1 / sigma`` per channel, from the last solution: our solver's rounds and
    stopping rule (at most 6 rounds). Returns the last OptimizeResult with
    ``nfev``/``njev`` summed over the rounds and ``sigma``/``rounds`` set."""
    c = Counted(prob, active, None)
    z0 = c.x0[active]
    model = prob.model
    tols = {} if tol is None else {"xtol": tol, "ftol": tol, "gtol": tol}
    rc = np.asarray(model.row_channel)

    def once():
        c.reset()
        c.g = None
        res = least_squares(c.fun_jac, z0, jac=c.jac, method=method, x_scale=x_scale, **tols)
        nfev, njev = res.nfev, res.njev
        r = c._eval(res.x)[0]
        pooled = max(math.sqrt(float(r @ r) / (len(r) - c.n)), SIGMA_FLOOR)
        old = dict.fromkeys(model.channels, pooled)
        rounds = 1
        while rounds < 6:
            sig = channel_sigma(c, res.x, c.g)
            floor = all(v <= 10 * SIGMA_FLOOR for v in sig.values())
            if floor or not any(abs(sig[ch] / old[ch] - 1) > SIGMA_CHANGE for ch in sig):
                break
            c.g = 1.0 / np.array([sig[ch] for ch in model.channels])[rc]
            res = least_squares(c.fun_jac, res.x, jac=c.jac, method=method, x_scale=x_scale,
                                **tols)
            nfev, njev, old, rounds = nfev + res.nfev, njev + res.njev, sig, rounds + 1
        res.nfev, res.njev, res.sigma, res.rounds = nfev, njev, old, rounds
        return res

    return c, once


def summarize_scipy(c, res, analytic, method):
    if analytic:
        iters, nfev, calls = res.njev, res.nfev, c.model_calls
    else:
        iters = res.njev if res.njev is not None else int(round(c.fd_calls / max(c.n, 1)))
        # lm (MINPACK) counts the FD probes in nfev, trf does not
        nfev = c.fk_calls - c.fd_calls
        calls = c.fk_calls
    return iters, nfev, calls, c.full(res.x), bool(res.success), res.status


# -- profile ----------------------------------------------------------------------
def profile_ours(prob, n):
    """Where one ``solve`` spends its time: cProfile over ``n`` solves, grouped."""
    pr = cProfile.Profile()
    pr.enable()
    for _ in range(n):
        solve(prob.model, prob.options)
    pr.disable()
    stats = pstats.Stats(pr).stats  # (file, line, func) -> (cc, nc, tt, ct, callers)

    def find(pred):
        return [(k, v) for k, v in stats.items() if pred(k)]

    def cum(pred, caller_pred=None):
        t = 0.0
        calls = 0
        for _k, v in find(pred):
            if caller_pred is None:
                t += v[3]
                calls += v[1]
            else:
                for ck, cv in v[4].items():
                    if caller_pred(ck):
                        t += cv[3]
                        calls += cv[1]
        return t, calls

    solver_dir = os.path.join("calibration", "solver", "")
    in_solver = lambda k: solver_dir in k[0]  # noqa: E731
    in_step = lambda k: k[0].endswith(os.path.join("solver", "factored.py"))  # noqa: E731
    in_ident = lambda k: k[0].endswith("identifiability.py")  # noqa: E731
    groups = [
        ("model.evaluate (r and W)", cum(lambda k: k[2] == "evaluate"
                                         and "calibration" in k[0] and "methods" in k[0])),
        ("identifiability (classify, or read off a QR)", cum(
            lambda k: (k[2] == "classify" and in_ident(k))
            or (k[2] == "clearly_identifiable" and in_step(k)))),
        ("Scaled: QR of [G W H, G r], sing. values", cum(lambda k: in_step(k)
                                                          and k[1] == SCALED_LINE)),
        ("Scaled.step (damped step, eq. 48)", cum(lambda k: k[2] == "step" and in_solver(k))),
        ("Scaled.variance_scaled (eq. 52 history)", cum(lambda k: k[2] == "variance_scaled"
                                                         and in_solver(k))),
        ("_covariance (final eq. 52, cond.)", cum(lambda k: k[2] == "_covariance"
                                                  and in_solver(k))),
        ("sigma / weights (eq. 51, L)", cum(lambda k: k[2] in (
            "channel_sigma", "_pooled_sigma", "row_weights", "_set_weights") and in_solver(k))),
    ]
    solve_t = cum(lambda k: k[2] == "solve" and in_solver(k))[0]
    parts = [(name, calls / n, 1e3 * t / n) for name, (t, calls) in groups]
    rest = solve_t - sum(t for _name, (t, _c) in groups)
    parts.append(("rest (loop, records, checks, result)", None, 1e3 * rest / n))
    parts.append(("total solve (under cProfile)", None, 1e3 * solve_t / n))
    top = sorted(stats.items(), key=lambda kv: -kv[1][2])[:12]
    trows = [(f"{os.path.basename(k[0])}:{k[1]}({k[2]})", f"{v[1] / n:.1f}",
              f"{1e3 * v[2] / n:.3f}", f"{1e3 * v[3] / n:.3f}") for k, v in top]
    return parts, table(trows, ["function", "calls/solve", "tottime ms", "cumtime ms"],
                        ["<", ">", ">", ">"])


def profile_report(probs, n):
    """One table, a column per problem: ms per solve (calls per solve) of each part."""
    cols, tops = [], []
    for prob in probs:
        parts, top = profile_ours(prob, n)
        cols.append(parts)
        tops.append(top)
    rows = []
    for i, (name, _c, _t) in enumerate(cols[0]):
        row = [name]
        for parts in cols:
            _n, calls, t = parts[i]
            tot = parts[-1][2]
            row.append(f"{t:.2f} ({100 * t / tot:.0f}%)" + (f" x{calls:.0f}" if calls else ""))
        rows.append(row)
    heads = ["part of solve(): ms/solve (%) x calls"] + [
        p.name.split(" (")[0].replace("sm-", "") for p in probs]
    out = table(rows, heads, ["<"] + [">"] * len(probs))
    k = int(np.argmax([c[-1][2] for c in cols]))
    out += (f"\n\ntop functions by own time, {probs[k].name} (the slowest):\n" + tops[k])
    return out


# -- bench ------------------------------------------------------------------------
def best_times(fns, repeats: int, warmup: int = 1):
    """``(best, median)`` seconds of each of ``fns`` over ``repeats`` interleaved rounds."""
    return [(min(t), statistics.median(t)) for t in interleaved_times(fns, repeats, warmup)]


def bench_problem(prob, repeats, x_scale, fd=True):
    model, opts = prob.model, prob.options
    res = solve(model, opts)
    active = np.array([s.identifiable for s in res.status])
    std = res.std[active]
    x_ours = res.x

    def plain_cost(x):
        r = model.evaluate(x)[0]
        return 0.5 * float(r @ r)

    def same(x):
        # same optimum: every calibrated parameter within max(1e-9, 1e-3 std) of ours
        # (std: ours, eq. 52; ~1e-14 noise-free, so the absolute 1e-9 decides there)
        dx = np.abs(x - x_ours)
        ok = bool(np.all(dx[active] <= np.maximum(SAME_ABS, SAME_STD * std))
                  and np.all(dx[~active] == 0))
        return dx.max(), float(np.nanmax(dx[active] / std)), ok

    rows = [dict(runner="ours", conv=res.converged, iters=res.iterations, nfev=res.nfev,
                 calls=res.nfev, analytic=True, cost=plain_cost(x_ours),
                 dx=0.0, dxs=0.0, same=True, scipy=False, target=True, info=False)]
    timed = [lambda: solve(model, opts)]
    runs = [(f"{m}-{'jac' if a else '2pt'}", m, a, None) for m in ("lm", "trf")
            for a in ((True, False) if fd else (True,))]
    weighted = prob.noisy and len(model.channels) > 1
    if weighted:
        # the station's mode: scipy estimates the per-channel sigma too, by the
        # same reweighting rounds around least_squares (run_scipy_reweighted)
        runs += [(f"{m}-jac-w", m, True, "reweight") for m in ("lm", "trf")]
        # information: lm handed the weights of ours' last round
        # (history[-1].sigma), i.e. only the last weighted problem, not timed
        # against ours
        last = res.history[-1].sigma
        sig = np.array([last[ch] for ch in model.channels])[model.row_channel]
        runs += [("lm-jac-given-w", "lm", True, 1.0 / sig)]
    # the default-tolerance runs (information): lm, analytic, on ours' problem
    runs += [(("lm-jac-w" if weighted else "lm-jac") + "-dtol", "lm", True,
              "reweight" if weighted else None)]
    for name, method, analytic, g in runs:
        dtol = name.endswith("-dtol")
        if isinstance(g, str):
            c, once = run_scipy_reweighted(prob, active, method, x_scale,
                                           tol=None if dtol else TOL)
        else:
            c, once = run_scipy(prob, active, g, method, analytic, x_scale,
                                tol=None if dtol else TOL)
        sres = once()
        iters, nfev, calls, x, ok, status = summarize_scipy(c, sres, analytic, method)
        if isinstance(g, str):
            status = f"{status}, {sres.rounds} rounds"
        dx, dxs, is_same = same(x)
        timed.append(once)
        given = name.endswith("-given-w")
        # the runs on the problem ours solves: the reweighted ones where ours
        # estimates per-channel weights, else the plain ones
        target = analytic and not dtol and not given and (name.endswith("-w") == weighted)
        rows.append(dict(runner=name, conv=f"{ok} ({status})", ok=ok, iters=iters, nfev=nfev, x=x,
                         calls=calls, analytic=analytic, cost=plain_cost(x), dx=dx, dxs=dxs,
                         same=is_same, scipy=True, target=target, info=dtol or given))
    # cost of one call, model.evaluate (r and W) and r by fk only, timed in the
    # same interleaved rounds as the runners
    x0 = model.x0
    timed += [lambda: [model.evaluate(x0) for _ in range(EVAL_BATCH)],
              lambda: [prob.residual(x0) for _ in range(EVAL_BATCH)]]
    times = best_times(timed, repeats)
    t_model, t_fk = times[-2][0] / EVAL_BATCH, times[-1][0] / EVAL_BATCH
    for r, (t, tmed) in zip(rows, times):
        r["t"], r["t_med"] = t, tmed
        r["t_eval"] = r["calls"] * (t_model if r.pop("analytic") else t_fk)
    return res, rows, (t_model, t_fk)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=25, help="timed runs per runner (best counts)")
    ap.add_argument("--quick", action="store_true", help="5 repeats")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--x-scale", default="jac", help="least_squares x_scale: 'jac' or 1")
    ap.add_argument("--poses", type=int, nargs="+",
                    help="pose counts to run every problem at (default: the report's 17, 45, 33)")
    ap.add_argument("--no-robot-file", action="store_true",
                    help="leave out sm-distance on AGEBOT's robot file")
    ap.add_argument("--no-fd", action="store_true",
                    help="skip the finite-difference runs (slow at thousands of poses)")
    ap.add_argument("--blas-threads", default="1",
                    help="BLAS threads (exported before numpy loads; default 1)")
    ap.add_argument("--profile", choices=("auto", "all", "none"), default="auto",
                    help="cProfile our solver: where it is slower than scipy (auto), always, never")
    ap.add_argument("--profile-runs", type=int, default=20)
    args = ap.parse_args(argv)
    repeats = 5 if args.quick else args.repeats
    x_scale = args.x_scale if args.x_scale == "jac" else float(args.x_scale)
    t_start = time.perf_counter()
    threads = {v: os.environ.get(v, "unset") for v in ("OPENBLAS_NUM_THREADS",
                                                       "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    print(f"numpy {np.__version__}, scipy {scipy.__version__}, python {sys.version.split()[0]}; "
          f"seed {args.seed}; wall = best of {repeats} interleaved runs (median beside it); "
          f"BLAS threads {threads}")
    print(f"stopping: ours max|step| < {SolverOptions().epsilon:g} (absolute, parameter units); "
          f"scipy xtol = ftol = gtol = {TOL:g} (relative), x_scale={args.x_scale!r}; "
          f"'*-dtol': scipy's default tolerances (1e-8), information only\n"
          f"ours: default SolverOptions() = {SolverOptions()}")
    problems = [p for n in (args.poses or [None])
                for p in make_problems(args.seed, tuple(args.methods), poses=n)
                + (make_robot_file_problems(args.seed, poses=n)
                   if "sm-distance" in args.methods and not args.no_robot_file else [])]
    if not args.poses and "sm-distance" in args.methods and not args.no_robot_file:
        problems.append(make_fixture_problem())     # its own 45 poses
    summary = []
    to_profile = []
    failures = []
    spurious = []
    for prob in problems:
        res, rows, (t_model, t_fk) = bench_problem(prob, repeats, x_scale, fd=not args.no_fd)
        t_ours = rows[0]["t"]
        st = [s for s in res.status if not s.identifiable]
        print(f"\n=== {prob.name}: {res.n_identifiable} identifiable"
              + (f"; fixed at x0: {', '.join(s.name for s in st)}" if st else "")
              + f"; ours: {res.message}; max|x_ours - truth| = "
              f"{np.abs(res.x - prob.truth)[[s.identifiable for s in res.status]].max():.2e}"
              f"\n    one call: model.evaluate (r, W) {1e3 * t_model:.3f} ms, "
              f"r by fk only {1e3 * t_fk:.3f} ms")
        # a spurious minimum: a sum of squares well above the truth's (a minimum has at
        # most the truth's); scipy may end there too and count as "the same optimum".
        # Weighted as ours weighs in the end (its final sigma per channel): with the
        # channels' noise unequal the plain sum of squares of ours' minimum can exceed
        # the truth's (sm-full-pose at 10 poses)
        r_t = prob.residual(prob.truth)
        sig = np.array([res.sigma[ch] for ch in prob.model.channels])[
            np.asarray(prob.model.row_channel)]
        rw, rw_t = res.residual / sig, r_t / sig
        ss, ss_t = float(rw @ rw), float(rw_t @ rw_t)
        ss_limit = 1.5 * ss_t + 1e-20 * float(np.sum(sig ** -2.0))
        ours_spurious = ss > ss_limit

        def weighted_ss(x, sig=sig, prob=prob):
            rw = prob.residual(x) / sig
            return float(rw @ rw)
        if ours_spurious:
            print(f"--> WARNING: ours ends at a weighted sum of squares {ss:.3g}, the "
                  f"truth's {ss_t:.3g}: a spurious minimum")
        out = []
        for r in rows:
            out.append((r["runner"], r["conv"], r["iters"], r["nfev"], r["calls"],
                        f"{1e3 * r['t']:.3f}", f"{1e3 * r['t_med']:.3f}",
                        f"{1e3 * r['t_eval']:.2f}",
                        f"{1e3 * (r['t'] - r['t_eval']):.2f}", f"{r['cost']:.6e}", f"{r['dx']:.2e}",
                        f"{r['dxs']:.1e}", "yes" if r["same"] else "NO",
                        f"{r['t'] / t_ours:.2f}"))
        print(table(out, ["runner", "converged (status)", "iter", "nfev", "calls", "best ms",
                          "median ms", "eval ms", "rest ms", "cost 0.5|r|^2", "max|x-x_ours|",
                          "/std", "same opt", "t/t_ours"]))
        # a scipy run that ends elsewhere fails, unless ours is the one in a spurious
        # minimum and that run reached the truth's (then ours failed where it did not)
        better = [r["runner"] for r in rows if r["scipy"] and r["target"] and r["ok"]
                  and not r["same"] and ours_spurious and weighted_ss(r["x"]) <= ss_limit]
        bad = [r["runner"] for r in rows if r["scipy"] and r["target"]
               and not (r["ok"] and r["same"]) and r["runner"] not in better]
        if bad:
            failures.append(f"{prob.name}: {', '.join(bad)} did not converge to our optimum")
            print(f"--> ASSERTION: {failures[-1]}")
        if ours_spurious:
            failures.append(f"{prob.name}: ours ends in a spurious minimum (weighted sum of "
                            f"squares {ss:.3g}, the truth's {ss_t:.3g})"
                            + (f"; {', '.join(better)} reached the truth's" if better else ""))
            spurious.append(prob.name)
            print(f"--> OURS FAILED: {failures[-1]}")
        sc = [r for r in rows if r["scipy"] and not r["info"] and r["same"] and r["ok"]]
        anyb = min((r for r in rows if r["scipy"] and not r["info"]), key=lambda r: r["t"])
        if ours_spurious:
            # no ratio: a time to a wrong answer is not a time to the answer
            best, ratio, ratio_med = None, float("nan"), float("nan")
            print("--> no ratio: ours failed (above)" + (
                f"; scipy at the same wrong point: {', '.join(r['runner'] for r in sc)}"
                if sc else ""))
        elif sc:
            best = min(sc, key=lambda r: r["t"])
            ratio = best["t"] / t_ours
            ratio_med = best["t_med"] / rows[0]["t_med"]
            print(f"--> best scipy at the same optimum: {best['runner']} {1e3 * best['t']:.3f} ms; "
                  f"ratio wall(best scipy)/wall(ours) = {ratio:.2f} "
                  f"({'ours faster' if ratio > 1 else 'SCIPY FASTER'}; medians {ratio_med:.2f}); "
                  f"fastest scipy of all: {anyb['runner']} ({anyb['t'] / t_ours:.2f})")
        else:
            best, ratio, ratio_med = None, float("nan"), float("nan")
            print("--> no scipy run reached our optimum")
        info = [r for r in rows if r["info"]]
        for r in info:
            if r["runner"].endswith("-given-w"):
                print(f"    {r['runner']}: handed the weights ours ended on (no sigma "
                      f"estimated), {r['nfev']} evaluations, {1e3 * r['t']:.3f} ms "
                      f"({r['t'] / t_ours:.2f} x ours), information only")
                continue
            print(f"    {r['runner']}: scipy's default tolerances stop after {r['nfev']} "
                  f"evaluations, {1e3 * r['t']:.3f} ms ({r['t'] / t_ours:.2f} x ours), "
                  + ("at the same optimum" if r["same"] else
                     f"{r['dxs']:.1e} std (max {r['dx']:.1e}) from ours: earlier than ours, "
                     f"not the same optimum"))
        summary.append((prob.name, res.nfev, f"{1e3 * t_ours:.3f}",
                        best["runner"] if best else "-", best["calls"] if best else "-",
                        f"{1e3 * best['t']:.3f}" if best else "-",
                        "ours failed" if ours_spurious else f"{ratio:.2f}",
                        "-" if ours_spurious else f"{ratio_med:.2f}"))
        if args.profile == "all" or (args.profile == "auto" and not ours_spurious
                                     and not ratio > 1):
            to_profile.append(prob)
    print("\n=== summary: ratio = wall(best scipy at the same optimum) / wall(ours), best of "
          f"{repeats}; > 1: ours faster")
    print(table(summary, ["problem", "ours nfev", "ours ms", "best scipy", "calls", "scipy ms",
                          "ratio", "(medians)"]))
    if to_profile:
        print(f"\n=== cProfile of ours ({args.profile_runs} solves per problem; the profiler "
              f"inflates many small Python calls, read the shares)")
        print(profile_report(to_profile, args.profile_runs))
    if spurious:
        print("\nours ends in a spurious minimum (sum of squares above the truth's): "
              + "; ".join(spurious))
    print(f"\nbench wall time {time.perf_counter() - t_start:.1f} s")
    if failures:
        print("\nFAILED: " + "; ".join(failures))
        sys.exit(1)


if __name__ == "__main__":
    main()
