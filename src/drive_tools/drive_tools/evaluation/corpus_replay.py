"""``drive bench replay CORPUS [--workers N | --cluster ADDRESS]``: every bag of a corpus replayed, in this
process, in N local worker processes, or on a Dask distributed cluster (issue 55 item 2; docs/recordings.md
"A corpus on many processes or machines"). One bag is one task: the same function replays it wherever it
runs, so the per-bag results do not depend on where (the samples-per-second figures aside). A worker lost
mid-corpus costs only its bags: the scheduler gives them to another worker (up to ALLOWED_FAILURES times);
a bag whose workers all died is reported skipped, never the run.

Dask distributed, not Ray: ~25 MB installed with its dependencies against Ray's 79 MB wheel alone; a local
cluster starts in 1-3 s; it retries the tasks of a lost worker by itself and names a bag that killed its
workers (KilledWorker) (docs/recordings.md)."""
import time
from typing import NamedTuple

from drive_common.contract.errors import DriveError
from hf_estimator import registry  # noqa: F401 - registers every estimator in a worker process too

from .recording import read_recording
from .replay import replay

ALLOWED_FAILURES = 3
"""A bag whose worker died is given to another this many times before it is reported lost."""


class ReplayOptions(NamedTuple):
    """What every bag of a corpus is replayed with: the estimators' names and what the command line gives
    for the pieces a bag may not say (recording.read_recording: motor, sample period [s], commissioning,
    scoring windows [(t0, t1) s])."""

    estimators: tuple
    motor: object = None
    sample_period_s: object = None
    commissioning: object = None
    windows: object = None


def replay_bag(bag, options):
    """One bag replayed with ``options`` (ReplayOptions): {"path", "report": the recording's report with
    its ``results``} or {"path", "skipped": the one-line reason} for a path that is not a replayable bag."""
    try:
        recording = read_recording(bag, motor=options.motor, sample_period_s=options.sample_period_s,
                                   commissioning=options.commissioning, windows=options.windows)
        entries, _ = replay(recording, list(options.estimators))
    except DriveError as error:
        return {"path": bag, "skipped": str(error)}
    return {"path": bag, "report": {**recording.report(), "results": entries}}


class Engine(NamedTuple):
    """Where a corpus runs: ``workers`` local processes (0: this process) or the Dask scheduler at
    ``cluster`` (an address, e.g. tcp://127.0.0.1:8786)."""

    workers: int = 0
    cluster: str = ""


IN_THIS_PROCESS = Engine()


def replay_corpus(bags, options, engine=IN_THIS_PROCESS, progress=None):
    """Replay every bag of ``bags`` (paths) with ``options`` on ``engine``; ``progress(line)`` hears of each
    bag done. → (outcomes in the order of ``bags``: replay_bag's dicts, the engine's facts: where it ran, its
    workers, wall time, tasks retried)."""
    start = time.perf_counter()
    if not engine.workers and not engine.cluster:
        outcomes = []
        for i, bag in enumerate(bags):
            outcomes.append(replay_bag(bag, options))
            _told(progress, outcomes[-1], i + 1, len(bags), start)
        return outcomes, {"engine": "this process", "workers": 1, "wall_time_s": time.perf_counter() - start}
    return _distributed(bags, options, engine, progress, start)


def _told(progress, outcome, done, total, start):
    if progress:
        elapsed = time.perf_counter() - start
        what = "skipped" if "skipped" in outcome else "replayed"
        progress(f"[{done}/{total}] {outcome['path']}: {what} ({elapsed:.0f} s, about "
                 f"{elapsed / done * (total - done):.0f} s left)")


def _distributed(bags, options, engine, progress, start):
    """replay_corpus on Dask distributed: a local cluster of ``engine.workers`` processes on the loopback
    address, or the scheduler at ``engine.cluster``."""
    import dask
    from distributed import Client, LocalCluster, as_completed
    from distributed.scheduler import KilledWorker

    cluster = None
    with dask.config.set({"distributed.scheduler.allowed-failures": ALLOWED_FAILURES,
                          "distributed.worker.daemon": False}):
        if engine.cluster:
            client = Client(engine.cluster, timeout="20s")
        else:
            cluster = LocalCluster(n_workers=engine.workers, threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address=None)
            client = Client(cluster)
        try:
            workers = len(client.scheduler_info()["workers"])
            ready = time.perf_counter()
            futures = client.map(replay_bag, bags, options=options, pure=False)
            index = {future.key: i for i, future in enumerate(futures)}
            outcomes = [None] * len(bags)
            for done, future in enumerate(as_completed(futures), 1):
                i = index[future.key]
                try:
                    outcomes[i] = future.result()
                except KilledWorker:
                    outcomes[i] = {"path": bags[i], "skipped": f"its worker died {ALLOWED_FAILURES + 1} times "
                                                               f"replaying it (lost, not retried further)"}
                _told(progress, outcomes[i], done, len(bags), start)
            retried = _retried(client)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    return outcomes, {"engine": "dask distributed", "address": engine.cluster or "local cluster (127.0.0.1)",
                      "workers": workers, "start_up_s": ready - start, "wall_time_s": time.perf_counter() - start,
                      "retried": retried}


def _retried(client):
    """How many tasks the scheduler gave to another worker after theirs died (its suspicious-task count)."""
    def count(dask_scheduler):
        return sum(getattr(task, "suspicious", 0) for task in dask_scheduler.tasks.values())
    try:
        return int(client.run_on_scheduler(count))
    except Exception:  # noqa: BLE001 - a figure of the report only; a scheduler that will not say is None
        return None
