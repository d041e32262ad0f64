"""Mutation testing of the modules where a silent change means a wrong
calibration or lost data, one module at a time (docs/testing.md).

Two parts:

* **mutmut** (the ``mutation`` extra of pyproject.toml) over each module in
  :data:`MODULES`, in a scratch copy of the repository, running only the fast
  tests listed for that module (mutmut then runs, per mutant, only those of
  them that execute the mutated function). Prints killed / survived / no tests
  / timeout per module and the score ``(killed + timeout) / (total - skipped)``.
* **named mutants** (:data:`NAMED`): mutations an audit found surviving (issue
  16), applied as exact text replacements; each must make its tests fail.

    python bench/mutation.py --list
    python bench/mutation.py --named                      # ~1 min
    python bench/mutation.py identifiability trace params_file
    python bench/mutation.py --all                        # every module, ~hours on 2 cores
    python bench/mutation.py methods --sample 300 --seed 1  # a seeded random sample

``--sample N`` scores N mutants drawn at random (``--seed``) from the module's mutants
and reports the score with its 95 % Clopper-Pearson interval: a sample's
score, not the module's. ``--tests`` replaces the module's test list (files or pytest node ids), and
``--tests-at REV`` takes the tests/ folder as it was at git commit REV (on
today's code): a "before" figure on the same mutants. ``--time-limit X`` bounds a mutant's CPU time to 2 X
(its tests' time + 1 s), a timeout counting as killed.

Children: one (``--jobs``), because the machine is small and shared. The
scratch copies live under ``--work`` (default ``$TMPDIR/calstation-mutation``);
``--keep`` keeps mutmut's state there so a second run only retests what changed
(``mutmut results`` / ``mutmut show NAME`` inside ``<work>/<module>``).
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import re
import subprocess
import sys
import tempfile
import random
import time
from pathlib import Path

from scipy.stats import binomtest

ROOT = Path(__file__).resolve().parent.parent
COPY = ("calibration", "cli", "drivers", "station", "tests", "fixtures", "app.py")

# module -> (files to mutate (globs), tests to run (paths), mutant-name globs or None = all)
MODULES = {
    "identifiability": (["calibration/identifiability.py"],
                        ["tests/calibration/test_identifiability.py",
                         "tests/calibration/test_kappa.py",
                         "tests/calibration/test_convergence.py"], None),
    # the solver's own fast tests (closed-form answers, milliseconds each): the
    # session-sized tests that also run it take ~12 s a mutant (docs/testing.md)
    "solver": (["calibration/solver/*.py"],
               ["tests/calibration/test_solver_units.py", "tests/calibration/test_kappa.py"], None),
    # test_serial: the robot-file methods (sm-distance-tilt with its inclinometer,
    # sm-position), 4 s; test_methods_units: registry, sm-plane's start, PM notes
    "methods": (["calibration/methods/*.py"],
                ["tests/calibration/test_sm_model.py", "tests/calibration/test_pm.py",
                 "tests/calibration/test_identifiability.py",
                 "tests/calibration/test_convergence.py", "tests/calibration/test_serial.py",
                 "tests/calibration/test_methods_units.py"], None),
    "trace": (["station/recording/trace.py", "station/recording/trace_writer.py"],
              ["tests/station/test_trace_and_params.py", "tests/station/test_durability.py"], None),
    "params_file": (["station/outputs/params_file.py"],
                    ["tests/station/test_trace_and_params.py", "tests/station/test_durability.py"],
                    None),
    # resume's decisions on synthetic trace events (not whole simulated sessions)
    "session-resume": (["station/recording/resume.py"], ["tests/station/test_resume_units.py"], None),
}

# name -> (file, text, replacement, tests); each must make its tests fail
NAMED = {
    "kappa=0 (solver default)": ("calibration/solver/options.py", "kappa: float = 3.0", "kappa: float = 0.0",
                                 ["tests/calibration/test_kappa.py"]),
    "kappa=0.3 (solver default)": ("calibration/solver/options.py", "kappa: float = 3.0",
                                   "kappa: float = 0.3", ["tests/calibration/test_kappa.py"]),
    "kappa=30 (solver default)": ("calibration/solver/options.py", "kappa: float = 3.0",
                                  "kappa: float = 30.0", ["tests/calibration/test_kappa.py"]),
    "kappa=0 (classify default)": ("calibration/identifiability.py",
                                   "kappa: float = 3.0, return_r", "kappa: float = 0.0, return_r",
                                   ["tests/calibration/test_kappa.py"]),
    "kappa=30 (classify default)": ("calibration/identifiability.py",
                                    "kappa: float = 3.0, return_r", "kappa: float = 30.0, return_r",
                                    ["tests/calibration/test_kappa.py"]),
    "trace append without flush": ("station/recording/trace_writer.py",
                                   "            self._fh.write(_line(rec))\n            self._fh.flush()\n",
                                   "            self._fh.write(_line(rec))\n",
                                   ["tests/station/test_durability.py"]),
    "trace append without fsync": ("station/recording/trace_writer.py",
                                   "            self._fh.flush()\n            os.fsync(self._fh.fileno())\n",
                                   "            self._fh.flush()\n",
                                   ["tests/station/test_durability.py"]),
    "canonical JSON with whitespace": ("station/outputs/params_file.py", 'separators=(",", ":")',
                                       'separators=(", ", ": ")',
                                       ["tests/station/test_durability.py"]),
    "canonical JSON unsorted": ("station/outputs/params_file.py",
                                "json.dumps(obj, sort_keys=True,", "json.dumps(obj, sort_keys=False,",
                                ["tests/station/test_durability.py"]),
}


def _env(extra_path: Path) -> dict:
    env = dict(os.environ)
    env.update(PYTHONPATH=str(extra_path), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               QT_QPA_PLATFORM="offscreen")
    # (tests/conftest.py caches compiled modules whatever PYTHONDONTWRITEBYTECODE says:
    # a mutant's files do not change while its tests run, and a named mutant's edit
    # comes a test run, seconds, after the last compile of the file)
    return env


def _copy_tree(dest: Path) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    for name in COPY:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, dirs_exist_ok=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        elif src.exists():
            shutil.copy2(src, dest / name)


def _toml_list(items) -> str:
    return "[" + ", ".join(json.dumps(str(i)) for i in items) + "]"


def _existing(patterns) -> list[str]:
    out = []
    for p in patterns:
        out += sorted(os.path.relpath(f, ROOT) for f in glob.glob(str(ROOT / p)))
    return out


def run_module(name: str, work: Path, jobs: int, keep: bool, sample: int = 0, seed: int = 0,
               tests=None, tests_at: str | None = None, time_limit: float = 15.0) -> dict:
    files, module_tests, names = MODULES[name]
    tests = tests or module_tests
    files = _existing(files)
    if not files:
        return {"module": name, "error": "no such files"}
    scratch = work / name
    if scratch.exists() and not keep:
        shutil.rmtree(scratch)
    _copy_tree(scratch)
    if tests_at:  # the tests/ folder as it was at that commit, on today's code
        shutil.rmtree(scratch / "tests")
        tar = subprocess.run(["git", "archive", tests_at, "tests"], cwd=ROOT, capture_output=True)
        if tar.returncode:
            return {"module": name, "error": f"git archive {tests_at}: {tar.stderr.decode().strip()}"}
        subprocess.run(["tar", "-x"], cwd=scratch, input=tar.stdout, check=True)
    else:
        tests = _existing(tests)
    base = (ROOT / "pyproject.toml").read_text()
    base = base.split("\n[tool.mutmut]")[0]
    # mutmut maps tests to mutants in its own pytest process: no xdist workers
    base = re.sub(r"^addopts = .*$", lambda m: re.sub(r' (-n|--dist) [^\s"]+', "", m.group(0)),
                  base, flags=re.M)
    (scratch / "pyproject.toml").write_text(
        base + "\n[tool.mutmut]\n"
        f'source_paths = ["calibration", "cli", "drivers", "station", "app.py"]\n'
        f"only_mutate = {_toml_list(files)}\n"
        f'also_copy = ["fixtures"]\n'
        f"pytest_add_cli_args_test_selection = {_toml_list(tests)}\n"
        # a mutant's CPU-time limit: 2 x this x (its tests' time + 1 s)
        f"timeout_multiplier = {time_limit}\n"
        )
    # the folder on PYTHONPATH must exist before Python starts, or its importer
    # caches it as missing (subprocesses of the tests import the mutants from it)
    (scratch / "mutants").mkdir(exist_ok=True)
    cmd = [sys.executable, "-m", "mutmut", "run", "--max-children", str(jobs)]
    t0 = time.monotonic()
    log = scratch / "mutmut.log"
    out = {"module": name, "files": files, "tests": tests, "tests_at": tests_at}
    if sample:
        # mutmut generates every mutant (and learns which test runs which function)
        # before it filters by name; a name that matches nothing stops it there
        with open(scratch / "generate.log", "w") as fh:
            subprocess.run([*cmd, "no-such-mutant-*"], cwd=scratch, env=_env(scratch / "mutants"),
                           stdout=fh, stderr=subprocess.STDOUT)
        pool = _generated(scratch, names)
        if not pool:
            return {**out, "error": f"no mutants generated, see {scratch / 'generate.log'}"}
        names = sorted(random.Random(seed).sample(pool, min(sample, len(pool))))
        out.update(population=len(pool), sample=len(names), seed=seed)
    with open(log, "w") as fh:
        rc = subprocess.run([*cmd, *(names or ())], cwd=scratch, env=_env(scratch / "mutants"),
                            stdout=fh, stderr=subprocess.STDOUT).returncode
    subprocess.run([sys.executable, "-m", "mutmut", "export-cicd-stats"], cwd=scratch,
                   env=_env(scratch / "mutants"), capture_output=True)
    stats_file = scratch / "mutants" / "mutmut-cicd-stats.json"
    out["seconds"] = round(time.monotonic() - t0)
    if rc != 0 or not stats_file.exists():
        out["error"] = f"mutmut exited {rc}, see {log}"
        return out
    stats = json.loads(stats_file.read_text())
    if names:  # only the selected functions count
        stats = _stats_of(scratch, names)
    out.update(stats)
    tested = stats.get("total", 0) - stats.get("skipped", 0)
    caught = stats.get("killed", 0) + stats.get("timeout", 0)
    out["score"] = caught / tested if tested else float("nan")
    if sample and tested:
        ci = binomtest(caught, tested).proportion_ci(0.95, method="exact")
        out["ci95"] = [ci.low, ci.high]
    res = subprocess.run([sys.executable, "-m", "mutmut", "results"], cwd=scratch,
                         env=_env(scratch / "mutants"), capture_output=True, text=True)
    out["survivors"] = [ln.split(":")[0].strip() for ln in res.stdout.splitlines()
                        if ln.strip().endswith("survived")]
    return out


def _generated(scratch: Path, names=None) -> list[str]:
    """Every mutant mutmut generated in ``scratch`` (its ``.meta`` files), or
    those matching the globs ``names``."""
    import fnmatch

    out = []
    for meta in sorted((scratch / "mutants").rglob("*.meta")):
        keys = json.loads(meta.read_text()).get("exit_code_by_key", {})
        out += [k for k in keys if not names or any(fnmatch.fnmatch(k, n) for n in names)]
    return sorted(out)


def _stats_of(scratch: Path, names) -> dict:
    """Counts over the mutants whose names match ``names`` (globs)."""
    import fnmatch

    res = subprocess.run([sys.executable, "-m", "mutmut", "results", "--all", "true"], cwd=scratch,
                         env=_env(scratch / "mutants"), capture_output=True, text=True)
    counts = {"total": 0, "killed": 0, "survived": 0, "no_tests": 0, "timeout": 0, "skipped": 0,
              "suspicious": 0}
    key = {"killed": "killed", "survived": "survived", "no tests": "no_tests",
           "timeout": "timeout", "skipped": "skipped", "suspicious": "suspicious",
           "not checked": "skipped"}
    for ln in res.stdout.splitlines():
        if ":" not in ln:
            continue
        mutant, status = (s.strip() for s in ln.rsplit(":", 1))
        if any(fnmatch.fnmatch(mutant, n) for n in names):
            counts["total"] += 1
            counts[key.get(status, "skipped")] += 1
    return counts


def run_named(work: Path) -> list[tuple[str, bool, str]]:
    """Apply each named mutant to a scratch copy and run its tests: killed = they fail."""
    scratch = work / "named"
    if scratch.exists():
        shutil.rmtree(scratch)
    _copy_tree(scratch)
    shutil.copy2(ROOT / "pyproject.toml", scratch / "pyproject.toml")
    out = []
    for label, (file, old, new, tests) in NAMED.items():
        path = scratch / file
        original = path.read_text()
        if original.count(old) != 1:
            out.append((label, False, f"text to mutate not found once in {file}"))
            continue
        path.write_text(original.replace(old, new))
        try:
            r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider",
                                *tests], cwd=scratch, env=_env(scratch), capture_output=True,
                               text=True, timeout=900)
        finally:
            path.write_text(original)
        last = (r.stdout.strip().splitlines() or [""])[-1]
        # killed: a test failed. pytest exits 1 then, or 2 where -x stopped the
        # xdist workers after the failure (the project's default -n auto)
        killed = r.returncode == 1 or (r.returncode == 2 and " failed" in last)
        out.append((label, killed, last))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("modules", nargs="*", help=f"any of {', '.join(MODULES)}")
    ap.add_argument("--all", action="store_true", help="every module")
    ap.add_argument("--named", action="store_true", help="the named mutants of issue 16")
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--jobs", type=int, default=1, help="mutmut children (default 1)")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "calstation-mutation")
    ap.add_argument("--keep", action="store_true", help="reuse mutmut's state from the last run")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--sample", type=int, default=0, metavar="N",
                    help="score N mutants drawn at random (a sample, with its 95%% interval)")
    ap.add_argument("--seed", type=int, default=0, help="the sample's seed (default 0)")
    ap.add_argument("--tests", nargs="+", help="run these tests instead of the module's list")
    ap.add_argument("--tests-at", metavar="REV",
                    help="the tests/ folder as it was at git commit REV (a 'before' figure)")
    ap.add_argument("--time-limit", type=float, default=15.0, metavar="X",
                    help="a mutant's CPU-time limit: 2 X (its tests' time + 1 s); default 15")
    a = ap.parse_args(argv)
    if a.list:
        for name, (files, tests, names) in MODULES.items():
            print(f"{name:16s} {', '.join(_existing(files)) or '(none)'}  <- {', '.join(_existing(tests))}"
                  + (f"  [{', '.join(names)}]" if names else ""))
        return 0
    mods = list(MODULES) if a.all else a.modules
    unknown = [m for m in mods if m not in MODULES]
    if unknown:
        ap.error(f"unknown module(s) {unknown}; known: {', '.join(MODULES)}")
    if not mods and not a.named:
        ap.error("name modules, --all or --named")
    report = {}
    failed = False
    if a.named:
        print("named mutants (issue 16): each must be killed")
        rows = run_named(a.work)
        for label, killed, last in rows:
            print(f"  {'killed  ' if killed else 'SURVIVED'}  {label:34s} {last}")
        failed |= not all(k for _, k, _ in rows)
        report["named"] = [{"mutant": lb, "killed": k} for lb, k, _ in rows]
    if mods:
        print(f"{'module':16s} {'mutants':>7s} {'killed':>6s} {'survived':>8s} {'no tests':>8s} "
              f"{'timeout':>7s} {'score':>6s} {'time':>6s}")
    for m in mods:
        r = run_module(m, a.work, a.jobs, a.keep, a.sample, a.seed, a.tests, a.tests_at,
                       a.time_limit)
        report[m] = r
        if "error" in r:
            print(f"{m:16s} error: {r['error']}")
            failed = True
            continue
        print(f"{m:16s} {r['total']:7d} {r['killed']:6d} {r['survived']:8d} {r['no_tests']:8d} "
              f"{r['timeout']:7d} {100 * r['score']:5.1f}% {r['seconds']:5d}s", flush=True)
        if "ci95" in r:
            lo, hi = r["ci95"]
            print(f"{'':16s} a random sample of {r['sample']} of {r['population']} mutants "
                  f"(seed {r['seed']}): 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %", flush=True)
    if a.json:
        a.json.write_text(json.dumps(report, indent=1))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
