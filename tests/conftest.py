import os
import sys

import pytest

# small matrices: multithreaded BLAS only adds overhead on the 2-core CI machine
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

# compiled modules cached (__pycache__, git-ignored) even where the environment says
# not to (PYTHONDONTWRITEBYTECODE, as on the CI image): the suite starts some 230
# Python processes (app.py commands, simulators, test workers), and without the
# cache each compiles the project's modules and pytest rewrites each test module again
# (0.35 s of CPU per `app.py run`); a cached module is checked against its source's
# modification time (whole seconds) and size, as Python always does
if os.environ.pop("PYTHONDONTWRITEBYTECODE", None) is not None:
    sys.dont_write_bytecode = False

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


@pytest.hookimpl(optionalhook=True)     # an xdist hook: unknown without xdist
def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject.toml's addopts): two test processes per core. A session
    test spends about half its time waiting for the simulated devices (moves, settles,
    answers, a simulator starting), so two workers a core keep the cores busy: the
    default suite took 15.5 min in one process, 13.9 min with 2 workers and 6.4 min
    with 4 on a 2-core machine with other work beside. ``-n 0`` runs in one process."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:      # not on Linux
        cores = os.cpu_count() or 1
    return min(2 * cores, 16)


@pytest.hookimpl(trylast=True)     # after `-m`'s deselection: the list that is run
def pytest_collection_modifyitems(config, items):
    """Under xdist's ``worksteal`` (pyproject.toml's addopts) each worker is first sent an
    equal, contiguous share of the collected tests, and a worker that runs out steals
    from the end of another's share. The tests marked ``heavy`` (whole sessions of 15 s
    or more on 2 cores) or ``slow`` are dealt round the workers and spread over the first
    half of each share, a few light tests after each: none of them starts late and ends
    the suite alone on one core (a 32 s SIGKILL resume began 300 s into a 330 s run),
    and their waits (moves, kills, timeouts) overlap other workers' computing (with the
    heavy tests all first, the cores were 75-85 % busy while they ran). A module whose
    tests are split so may set up its module-scoped fixtures more than once."""
    workers = getattr(config, "workerinput", {}).get("workercount", 0)    # on a worker
    if workers < 2:
        return

    def is_heavy(item):
        return any(item.get_closest_marker(m) for m in ("heavy", "slow"))

    heavy = [it for it in items if is_heavy(it)]
    light = [it for it in items if not is_heavy(it)]
    ordered, left, taken = [], len(items), 0
    for k in range(workers):        # xdist's first split: left // (workers - k) each
        size = left // (workers - k)
        first = heavy[k::workers]
        if len(first) > size:       # more heavy tests than this share holds: keep the order
            return
        share = light[taken:taken + size - len(first)]
        gap = (size // 2) // max(1, len(first))      # light tests after each heavy one
        for j, item in enumerate(first):
            share.insert(j * (gap + 1), item)
        ordered += share
        taken += size - len(first)
        left -= size
    items[:] = ordered


@pytest.fixture
def quick_retries(monkeypatch):
    """The session's pauses before it retries a failed pose
    (:data:`station.session.device_loss.BACKOFF_S`, 0.25 to 2 s for a real outage to pass) ten
    times shorter: for tests of faults that a pause does not cure (a drive at its
    limit, a device gone, frames lost at random). test_device_loss's short outage
    keeps the real pauses."""
    from station.session import device_loss

    monkeypatch.setattr(device_loss, "BACKOFF_S", tuple(p / 10 for p in device_loss.BACKOFF_S))


@pytest.fixture
def no_report(monkeypatch):
    """Sessions write a one-line placeholder for ``report.html`` (its figures take a
    second or more of CPU a session): for tests of the trace, the parameters and the
    devices. The report is tested by tests/station/test_report.py and by the session
    tests that read it."""
    import station.outputs.report

    def placeholder(path, *args, **kwargs):
        from pathlib import Path

        Path(path).write_text("report\n")
        return Path(path)

    monkeypatch.setattr(station.outputs.report, "write_report", placeholder)
