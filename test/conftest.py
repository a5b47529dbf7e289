import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
ROOT = Path(__file__).resolve().parent.parent
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw-1")[2:])
"""This process's worker number in a parallel run (pytest-xdist, pyproject's addopts); −1: the run's own."""
TEST_DOMAINS = range(30, 100)
"""The ROS domains test processes take (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: shared by the whole machine)."""


def _claim_a_domain():
    """A ROS domain of TEST_DOMAINS no other test process on this machine holds (this run's other workers, another
    clone's run), held by an exclusive lock on a file until this process ends; (domain, its lock file)."""
    import fcntl
    start = (os.getpid() + WORKER + 1) % len(TEST_DOMAINS)
    for i in range(len(TEST_DOMAINS)):
        domain = TEST_DOMAINS[(start + i) % len(TEST_DOMAINS)]
        lock = open(Path(tempfile.gettempdir()) / f"drive_test_ros_domain_{domain}.lock", "a")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        return domain, lock
    raise RuntimeError(f"every ROS domain {TEST_DOMAINS.start}-{TEST_DOMAINS.stop - 1} is held by a test process")


DOMAIN, DOMAIN_LOCK = _claim_a_domain()
os.environ["ROS_DOMAIN_ID"] = str(DOMAIN)
"""One domain per test process, set before any module starts rclpy: two concurrent runs on one machine (each
worker of a run, or runs in two clones) never share one (a pid-derived domain had collided). ROS tests isolate
from each other by namespace."""
SUITE_BUDGET_S = 9 * 60
"""The default run's time budget on the project's 2-core machine (docs/architecture.md#tests): reported at the
end of every run beside the time taken, never asserted (a slower machine is not a defect of the change)."""
LEFT_BY_BUILDS = ("__pycache__", ".egg-info", ".pytest_cache", ".venv", ".nbi", ".nbc")
"""Untracked paths a test run may create in the repository: build and cache output, never results."""


try:
    from hypothesis import HealthCheck, settings
    from hypothesis.configuration import set_hypothesis_home_dir
    set_hypothesis_home_dir(tempfile.mkdtemp(prefix="hypothesis_"))
    # Fuzz that gives the same examples on every run and never fails for a machine's pace (no deadline, no
    # too-slow check): a red run is a defect in the change.
    settings.register_profile("any_machine", deadline=None, derandomize=True,
                              suppress_health_check=[HealthCheck.too_slow])
    settings.load_profile("any_machine")
except ImportError:
    pass


@pytest.fixture(autouse=True)
def in_a_temporary_directory(tmp_path, monkeypatch):
    """Every test runs in its own temporary directory: what a command writes by default (runs/, plots,
    commissioning files) never lands in the repository. It holds a copy of the repository's
    commissioning/ (both motors commissioned, as a robot builder's working directory would)."""
    shutil.copytree(ROOT / "commissioning", tmp_path / "commissioning")
    monkeypatch.chdir(tmp_path)


def _untracked():
    listed = subprocess.run(["git", "ls-files", "--others", "--directory"], cwd=ROOT, capture_output=True,
                            text=True).stdout.split()
    return {path for path in listed if not any(part in path for part in LEFT_BY_BUILDS)}


MODULE_SECONDS = Counter()
"""Seconds each test module took in this run (setup, call and teardown)."""


def pytest_sessionstart(session):
    session.config.untracked_before = _untracked()
    session.config.started_at = time.monotonic()


def pytest_runtest_logreport(report):
    MODULE_SECONDS[report.nodeid.split("::")[0]] += report.duration


def pytest_terminal_summary(terminalreporter, config):
    """The run's time against the suite's budget, and the modules that took most of it."""
    elapsed = time.monotonic() - config.started_at
    slowest = ", ".join(f"{Path(name).name} {seconds:.0f} s" for name, seconds in MODULE_SECONDS.most_common(4))
    terminalreporter.write_line(f"time budget: {elapsed / 60:.1f} of {SUITE_BUDGET_S / 60:.0f} min "
                                f"(most: {slowest})")


def pytest_sessionfinish(session, exitstatus):
    """Fail the run when a test left a file in the repository (tests write only to temporary
    directories)."""
    left = _untracked() - session.config.untracked_before
    if left:
        print(f"\ntests left files in the repository: {', '.join(sorted(left))}", file=sys.stderr)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.fixture
def small_disk(tmp_path, monkeypatch):
    """A directory on a 256 KiB filesystem (tmpfs, mounted by the test where that is allowed), or, where
    it is not, one where every write past the first 200 messages fails with ENOSPC."""
    import errno
    import subprocess

    mount = tmp_path / "small_disk"
    mount.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)],
                             capture_output=True).returncode == 0
    if not mounted:
        from mcap.writer import Writer
        original, calls = Writer.add_message, [0]

        def add_message(self, *args, **kwargs):
            calls[0] += 1
            if calls[0] > 200:
                raise OSError(errno.ENOSPC, "No space left on device")
            return original(self, *args, **kwargs)
        monkeypatch.setattr(Writer, "add_message", add_message)
    yield mount
    if mounted:
        subprocess.run(["umount", str(mount)], check=True)
