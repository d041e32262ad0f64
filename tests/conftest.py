import os
import sys

import pytest

# small matrices: multithreaded BLAS only adds overhead on the 2-core CI machine
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

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
