"""Studies: Monte Carlo calibrations over robots drawn around the nominal, on Dask.

``python app.py study --method M --robots N [--design optimal,random] --out DIR``
draws N robots around the nominal (:func:`drivers.sim.truth.draw_truth`: gear
ratios, lengths and offsets within the given tolerances), simulates a trace of
each with fresh noise for each design (:mod:`station.simulation.tracegen`), calibrates it
(:func:`station.fitting.batch.calibrate`, the one path every caller takes) and compares
with the truth: the normalized errors ``(estimate - truth) / std`` of the
identifiable parameters, the coverage of the reported std, and the error of the
calibrated model on held-out poses the plan never saw.

Every calibration is a task of its own, a pure function of ``(spec, robot index,
design)``: its seeds come from the study's seed and the index, so a study gives
the same figures on a local cluster, on a scheduler across machines, or run in
order. The work goes to ``dask.distributed``: a local cluster by default, an
existing scheduler with ``--scheduler tcp://HOST:PORT``.

Results: ``DIR/study.jsonl`` (one line per calibration, appended as they come)
and ``DIR/summary.json`` (per design), written atomically.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.errors import CalibrationError, StationError

#: parameters the report assumes known where they cannot be identified but bias the
#: others (the method's influence class; their true values go into the nominal)
KNOWN = {"sm-self-redundancy": ("L4",),
         "sm-plane": ("L4", "theta0", "a0", "plane_a", "plane_b", "plane_c"),
         "pm-fk": ("q3_off", "k3"), "pm-ik": ("q3_off", "k3"), "pm-tilt": ("q3_off", "k3")}

#: reading noise of the station's devices (std of one reading, averaged over 5 samples)
STATION_NOISE = {"distance": 1e-5 / math.sqrt(5), "tilt": 1.7e-4 / math.sqrt(5),
                 "pose": [1e-4, 1e-4, 1e-4, 1e-3], "orientation": 1e-3 / math.sqrt(5)}

HELD_OUT = 20


@dataclass(frozen=True)
class StudySpec:
    """What a study runs (every field is JSON; the spec travels to the workers)."""

    method: str
    robots: int
    designs: tuple[str, ...] = ("optimal", "random")
    count: int | None = None
    seed: int = 0
    gear: float = 0.4
    length: float = 0.05
    offset: float = 0.03
    noise: dict = field(default_factory=dict)
    robot: str | None = None      # a robot file's path or a URDF robot (None: the built-in)

    def robot_name(self) -> str:
        from calibration.methods import METHODS
        from calibration.robots import BUILTIN

        return self.robot or BUILTIN[METHODS[self.method].kind]


def is_angle(name: str, robot) -> bool:
    """Whether parameter ``name`` of ``robot`` is an angle (compared modulo 2 pi)."""
    angles = getattr(robot, "angle_params", None)
    if angles is not None:
        return name in angles
    if robot.name == "agebot-sm":
        return name in ("theta0", "q2_off", "q3_off", "q4_off")
    return name.startswith(("theta", "alpha", "beta", "gamma"))


def _truth_vector(method, robot, xi, header, reference, extra_params):
    nom = header["nominal"]
    vec = np.r_[xi, [float(nom.get(k, 0.0)) for k in extra_params]]
    if method == "sm-distance-tilt":
        from calibration.methods.sm_distance_tilt import reframe_nominal

        vec[:robot.n_params] = reframe_nominal(robot, xi, np.array(reference["qm"]))
    return vec


def run_one(spec: dict, index: int, design: str) -> dict:
    """One calibration of the study: robot ``index`` drawn, simulated, calibrated and
    compared with its truth. Never raises for a failed calibration: the record says."""
    from calibration.methods import METHODS, build
    from calibration.robots import BUILTIN, get_robot
    from drivers.sim.truth import draw_truth
    from station.fitting.batch import calibrate
    from station.recording.trace import Trace
    from station.simulation.tracegen import generate

    s = StudySpec(**{**spec, "designs": tuple(spec["designs"])})
    if s.robot is not None:           # a robot file's or URDF robot's arm
        from station.simulation.study_files import run_one as run_file

        return run_file(s, index, design, STATION_NOISE, HELD_OUT)
    mi = METHODS[s.method]
    robot = get_robot(BUILTIN[mi.kind])
    rng = np.random.default_rng([s.seed, index])
    truth = draw_truth(robot.name, rng, gear=s.gear, length=s.length, offset=s.offset)
    xi = truth.xi()
    noise = {k: v for k, v in {**STATION_NOISE, **s.noise}.items() if k in mi.channels}
    out = {"index": index, "design": design, "ok": False,
           "truth": {n: float(v) for n, v in zip(robot.param_names, xi)}}
    t0 = time.perf_counter()
    try:
        header, reference, poses = generate(s.method, xi, noise=noise, seed=[s.seed, index, 1],
                                            count=s.count, known=KNOWN.get(s.method, ()),
                                            design=design)
        trace = Trace(f"<study robot {index}>", header, reference, poses)
        outcome = calibrate(trace)
    except (CalibrationError, StationError) as e:
        out.update(error=str(e), seconds=time.perf_counter() - t0)
        return out
    res = outcome.result
    truth_vec = _truth_vector(s.method, robot, xi, header, reference, mi.extra_params)
    ident = [j for j, st in enumerate(res.status) if st.identifiable]
    diff = res.x - truth_vec
    for j in ident:  # angles compare modulo 2 pi
        if is_angle(res.names[j], robot):
            diff[j] = math.remainder(diff[j], 2 * math.pi)
    z = {res.names[j]: float(diff[j] / res.std[j]) for j in ident}
    err = {res.names[j]: float(diff[j]) for j in ident}
    # held-out: fresh random poses of the true robot, noise-free, never fitted
    hh, hr, hp = generate(s.method, xi, seed=[s.seed, index, 2], count=HELD_OUT,
                          known=KNOWN.get(s.method, ()))
    held = Trace(f"<study robot {index} held out>", hh, hr, hp)
    try:
        data = held.method_data()
        if reference is not None and data.reference_qm is not None:
            data = dataclasses.replace(data, reference_qm=np.array(reference["qm"]))
        hm = build(s.method, robot, data, res.x, **({"plane_given": True}
                                                    if s.method == "sm-plane" else {}))
        r = hm.residuals(res.x)
        held_rms = {ch: float(np.sqrt(np.mean(r[hm.row_channel == k] ** 2)))
                    for k, ch in enumerate(hm.channels)}
    except CalibrationError as e:
        held_rms = {"error": str(e)}
    out.update(ok=True, poses=int(outcome.model.n_poses), iterations=int(res.iterations),
               z=z, error=err, heldout_rms=held_rms, seconds=time.perf_counter() - t0)
    return out


def summarize(records: list[dict], designs) -> dict:
    """Per design: success rate, RMS and worst |error/std|, coverage of 1 and 2 std,
    percentiles of |error| per parameter and of the held-out RMS per channel."""
    out = {}
    for d in designs:
        recs = [r for r in records if r["design"] == d]
        ok = [r for r in recs if r["ok"]]
        zs = np.array([v for r in ok for v in r["z"].values()])
        per = {}
        for name in (ok[0]["z"] if ok else {}):
            e = np.abs([r["error"][name] for r in ok if name in r["error"]])
            per[name] = {"median_abs_error": float(np.median(e)),
                         "p95_abs_error": float(np.percentile(e, 95))}
        held = {}
        for ch in (ok[0]["heldout_rms"] if ok else {}):
            v = [r["heldout_rms"][ch] for r in ok if isinstance(r["heldout_rms"].get(ch), float)]
            if v:
                held[ch] = {"median": float(np.median(v)), "p95": float(np.percentile(v, 95))}
        out[d] = {"calibrations": len(recs), "succeeded": len(ok),
                  "success_rate": len(ok) / len(recs) if recs else math.nan,
                  "rms_z": float(np.sqrt(np.mean(zs ** 2))) if zs.size else math.nan,
                  "max_abs_z": float(np.max(np.abs(zs))) if zs.size else math.nan,
                  "coverage_1std": float(np.mean(np.abs(zs) <= 1)) if zs.size else math.nan,
                  "coverage_2std": float(np.mean(np.abs(zs) <= 2)) if zs.size else math.nan,
                  "poses": int(np.median([r["poses"] for r in ok])) if ok else 0,
                  "parameters": per, "heldout_rms": held,
                  "failures": sorted({r["error"] for r in recs if not r["ok"]})[:5]}
    return out


def _json_safe(v):
    """``v`` with every NaN or infinity as None (JSON has neither: no calibration
    succeeded, so there is no RMS)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_safe(x) for x in v]
    return v


def format_summary(spec: StudySpec, summary: dict) -> str:
    drawn = (f"gear +-{spec.gear:.0%}, lengths +-{spec.length:.0%}, offsets +-{spec.offset:g}"
             if spec.method != "sm-markers" else
             "joint origins by mm and mrad, joint zeros by mrad, an instrument and points on "
             "the tool")
    lines = [f"study {spec.method} on {spec.robots} robots drawn around the nominal of "
             f"{spec.robot_name()} ({drawn}), seed {spec.seed}"]
    lines.append(f"{'design':<9}{'poses':>6}{'success':>9}{'RMS z':>8}{'max |z|':>9}"
                 f"{'in 1 std':>10}{'in 2 std':>10}  held-out RMS (median / 95 %)")
    for d, s in summary.items():
        held = ", ".join(f"{ch} {v['median']:.3g} / {v['p95']:.3g}"
                         for ch, v in s["heldout_rms"].items())
        lines.append(f"{d:<9}{s['poses']:>6}{s['success_rate']:>9.1%}{s['rms_z']:>8.3f}"
                     f"{s['max_abs_z']:>9.2f}{s['coverage_1std']:>10.1%}"
                     f"{s['coverage_2std']:>10.1%}  {held}")
        for f in s["failures"]:
            lines.append(f"  failed ({d}): {f}")
    return "\n".join(lines)


class _Progress:
    """One line on stderr, rewritten in place on a terminal."""

    def __init__(self, total: int):
        self.total, self.done, self.t0 = total, 0, time.monotonic()
        self.tty = sys.stderr.isatty()

    def step(self):
        self.done += 1
        if self.tty or self.done == self.total or self.done % max(1, self.total // 10) == 0:
            n = 30 * self.done // self.total
            el = time.monotonic() - self.t0
            start, end = ("\r", "") if self.tty else ("", "\n")
            sys.stderr.write(f"{start}[{'#' * n}{'.' * (30 - n)}] {self.done}/{self.total} "
                             f"calibrations, {el:.0f} s{end}")
            if self.tty and self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()


def _reachable(scheduler: str, timeout: float = 5.0) -> None:
    """A ``tcp://host:port`` scheduler that refuses the connection (nothing listens
    there: a typo, a scheduler not started) is said at once; Dask's client would retry
    it for its whole 10 s. Other addresses are left to Dask."""
    import socket
    from urllib.parse import urlsplit

    try:
        u = urlsplit(scheduler)
        host, port = u.hostname, u.port
    except ValueError:
        return
    if u.scheme != "tcp" or not host or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except ConnectionRefusedError as e:
        raise StationError(f"cannot reach the Dask scheduler {scheduler}: nothing listens "
                           f"there ({e.strerror or e})") from None
    except OSError:
        return          # (unreachable host, timeout: Dask says so in its own words)


def run_study(spec: StudySpec, out_dir, *, scheduler: str | None = None,
              workers: int | None = None) -> dict:
    """Run the study on Dask and write ``out_dir/study.jsonl`` and ``summary.json``."""
    import logging

    from dask.distributed import Client, LocalCluster, as_completed

    from drivers.atomic import write_atomic

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [(i, d) for i in range(spec.robots) for d in spec.designs]
    spec_d = dataclasses.asdict(spec)
    cluster = None
    logging.getLogger("distributed").setLevel(logging.ERROR)
    if scheduler:
        _reachable(scheduler)
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as e:
            raise StationError(f"cannot reach the Dask scheduler {scheduler}: {e}") from None
    else:
        cluster = LocalCluster(n_workers=workers or max(1, (os.cpu_count() or 1)),
                               threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
        client = Client(cluster)
    records = []
    lines_path = out / "study.jsonl"
    try:
        futures = [client.submit(run_one, spec_d, i, d, pure=False) for i, d in tasks]
        bar = _Progress(len(futures))
        with open(lines_path, "w", encoding="utf-8") as f:
            for fut in as_completed(futures):
                rec = fut.result()
                records.append(rec)
                f.write(json.dumps(rec, sort_keys=True) + "\n")
                f.flush()
                os.fsync(f.fileno())
                bar.step()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    records.sort(key=lambda r: (r["index"], spec.designs.index(r["design"])))
    summary = summarize(records, spec.designs)
    doc = {"spec": spec_d, "summary": _json_safe(summary)}
    write_atomic(out / "summary.json",
                 (json.dumps(doc, indent=2, sort_keys=True, allow_nan=False)
                  + "\n").encode("utf-8"))
    return summary


def _check_file_study(args) -> None:
    """A study of a robot file's or URDF robot's arm: a method it is simulated with."""
    from calibration.robots import get_robot
    from drivers.robot_file import load_robot_file

    robot = get_robot(load_robot_file(args.robot))     # unreadable: one line
    urdf = hasattr(robot.spec, "base_link")
    known = ("sm-markers",) if urdf else ("sm-distance", "sm-distance-tilt")
    if args.method not in known:
        raise StationError(f"a study of {args.robot} simulates {', '.join(known)}, not "
                           f"{args.method}")


def cli(args) -> int:
    """``app.py study``: check the options, run, print the summary."""
    from calibration.methods import METHODS
    from calibration.robots import BUILTIN
    from station.planning.pose_design import DESIGNS
    from station.simulation.tracegen import parse_noise

    from station.fitting.pose_count import NR_P

    if args.method not in METHODS:
        raise StationError(f"unknown method {args.method!r} (known: {', '.join(METHODS)})")
    from drivers.robot_file import is_robot_file

    file_robot = None
    if args.robot and is_robot_file(args.robot):     # a robot file's or URDF robot's arm
        file_robot = args.robot
        _check_file_study(args)
    elif args.method not in NR_P:
        raise StationError(f"study draws AGEBOT's arm and wrist, or a robot file's or URDF "
                           f"robot's arm (--robot FILE): method {args.method} is not one of "
                           f"AGEBOT's (they take {', '.join(NR_P)})")
    robot = BUILTIN[METHODS[args.method].kind]
    if args.robot and not file_robot and args.robot != robot:
        raise StationError(f"method {args.method} is for {robot}, not {args.robot}")
    designs = tuple(d.strip() for d in args.design.split(",") if d.strip())
    bad = [d for d in designs if d not in DESIGNS]
    if bad or not designs:
        raise StationError(f"--design {args.design!r}: expected a comma-separated list of "
                           f"{', '.join(DESIGNS)}")
    if file_robot and args.method != "sm-markers" and "optimal" in designs:
        print("note: a robot file's distance methods are studied with poses drawn at random "
              "(the optimal design is planned by the sessions: app.py run)")
        designs = ("random",)
    if args.robots < 1:
        raise StationError("--robots must be at least 1")
    for name in ("gear", "length", "offset"):
        v = getattr(args, name)
        if not (math.isfinite(v) and 0 <= v < (1 if name != "offset" else math.inf)):
            raise StationError(f"--{name} {v}: expected a tolerance >= 0"
                               + (" and < 1" if name != "offset" else ""))
    from drivers.atomic import check_output_folder

    check_output_folder(args.out, "the study folder (--out)", ("study.jsonl", "summary.json"))
    out = Path(args.out)
    spec = StudySpec(method=args.method, robots=args.robots, designs=designs, count=args.count,
                     seed=args.seed, gear=args.gear, length=args.length, offset=args.offset,
                     noise=parse_noise(args.noise, method=args.method), robot=file_robot)
    summary = run_study(spec, out, scheduler=args.scheduler, workers=args.workers)
    print(format_summary(spec, summary))
    print(f"results written to {out / 'study.jsonl'} and {out / 'summary.json'}")
    return 0
