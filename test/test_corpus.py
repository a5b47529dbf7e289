"""A corpus for estimator authors (issue 55 items 2-3): `drive bag synth` writes varied recordings with ground
truth from the random motors, and `drive bench replay CORPUS` runs them here, in local worker processes or on a
Dask cluster, with the same per-bag results wherever a bag ran, and a worker killed mid-corpus costing nothing."""
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drive_common.config.scenario import load_scenario
from drive_common.contract.estimator_states import ALIGNING, TRACKING
from drive_common.contract.log import COLUMN
from drive_tools.bags.writer import RecorderFlaws, write_run_bag
from drive_tools.evaluation.corpus_replay import Engine, ReplayOptions, replay_corpus
from drive_tools.evaluation.metrics import angle_scores
from drive_tools.evaluation.random_motors import draw_motor
from drive_tools.evaluation.synthetic_corpus import draw_case
from drive_tools.runner.runner import run_scenario
from helpers import drive_in_process

ESTIMATORS = ("injection_frame", "sensored")
BAGS = 4
OPTIONS = ReplayOptions(ESTIMATORS, windows=[(0.25, 0.4)])


def without_timing(outcomes):
    """Per-bag outcomes without the figures that depend on the machine's pace (samples per second)."""
    kept = []
    for outcome in outcomes:
        report = outcome.get("report")
        if report is not None:
            report = {**report, "results": [{k: v for k, v in e.items() if k != "samples_per_second"}
                                            for e in report["results"]]}
        kept.append({**outcome, "report": report})
    return kept


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """(the folder, its paths, their serial replay): BAGS bags of one wang_100rpm run (0.4 s), each with its own
    recorder's flaws (a robot's wall clock, jitter, a share of lost messages), and one path that is not a bag."""
    folder = tmp_path_factory.mktemp("corpus")
    scenario = load_scenario("wang_100rpm")
    import dataclasses
    result = run_scenario(dataclasses.replace(scenario, duration_s=0.4))
    for i in range(BAGS):
        flaws = RecorderFlaws(1.76e9 + i, 2e-6 * i, 0.001 * i, i) if i else RecorderFlaws()
        write_run_bag(result, folder / f"bag_{i}", flaws=flaws)
    (folder / "notes").mkdir()
    (folder / "notes" / "metadata.yaml").write_text("not a bag\n")
    bags = sorted(str(p.parent) for p in folder.rglob("metadata.yaml"))
    return folder, bags, replay_corpus(bags, OPTIONS)


def test_a_synthetic_corpus_is_drawn_the_same_for_any_count_and_varies_what_a_benchmark_needs():
    """Bag i of a seed is drawn from its own generator (the same case in a corpus of any size); over 200 draws
    the cases cover every estimator, sampling period and profile, loads on about half, a robot's recorder on
    about half, speeds within 1-10 % of rated (a hold at zero)."""
    cases = [draw_case(4, i, 0, draw_motor(4, i)) for i in range(200)]
    assert draw_case(4, 17, 0, draw_motor(4, 17)) == cases[17]
    assert {c.estimator for c in cases} == {"injection_frame", "conventional", "improved", "synchronous", "square_wave"}
    assert {c.T_s for c in cases} == {5e-5, 1e-4, 2e-4} and len({c.profile for c in cases}) == 5
    loaded = np.mean([c.load_per_rated > 0 for c in cases])
    flawed = np.mean([c.flaws.lost_share > 0 for c in cases])
    assert 0.38 < loaded < 0.62 and 0.38 < flawed < 0.62
    for c in cases:
        rated = draw_motor(4, cases.index(c)).document["nameplate"]["rated_speed_rpm"]
        assert (c.speed_rpm == 0.0) == (c.profile == "hold")
        assert c.profile == "hold" or 0.01 * rated <= c.speed_rpm <= 0.1 * rated
        assert c.flaws.jitter_s <= 0.05 * c.T_s


def test_bag_synth_writes_bags_with_ground_truth_that_replay_reads(tmp_path):
    """Two bags of 0.3 s: each written with its motor's class figures and case in corpus.json, its ground truth
    in the bag, its recorder's lost messages counted by replay, and the same case as draw_case says."""
    out = drive_in_process(["bag", "synth", tmp_path / "c", "--count", "2", "--seed", "11", "--duration", "0.3",
                            "--workers", "1", "--json"])
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["written"] == 2 and json.loads((tmp_path / "c" / "corpus.json").read_text()) == report
    for row in report["bags"]:
        case = draw_case(11, row["index"], len(row["attempts"]), draw_motor(11, row["index"]))
        assert row["case"]["estimator"] == case.estimator and row["case"]["T_s"] == case.T_s
        replayed = drive_in_process(["bench", "replay", tmp_path / "c" / row["bag"], "--estimators", "sensored",
                                     "--no-plot", "--json", "--windows", "0.1:0.3"])
        assert replayed.returncode == 0, replayed.stderr
        replay = json.loads(replayed.stdout)
        assert replay["ground_truth"] and replay["results"][0]["angle_error_rms"] == pytest.approx(0.0, abs=1e-9)
        lost = sum(replay["missing_samples"].values())
        assert (lost > 0) == (case.flaws.lost_share * row["samples"] > 5)
    again = drive_in_process(["bag", "synth", tmp_path / "c", "--count", "1"])
    assert again.returncode == 2 and "not an empty folder" in again.stderr


def test_a_corpus_on_local_workers_gives_the_serial_results(corpus):
    """--workers 2 (a local Dask cluster): every bag's entries equal the serial run's, a path that is not a bag
    skipped the same way."""
    folder, bags, (serial, facts) = corpus
    spread, spread_facts = replay_corpus(bags, OPTIONS, Engine(workers=2))
    assert facts["engine"] == "this process" and spread_facts["workers"] == 2
    assert without_timing(spread) == without_timing(serial)
    assert sum("skipped" in o for o in serial) == 1 and sum("report" in o for o in serial) == BAGS


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_worker_killed_mid_corpus_costs_only_its_bags_retried(corpus, tmp_path):
    """A scheduler on the loopback address and two worker processes (`dask scheduler`, `dask worker`, no
    nanny to restart them); one worker is killed (SIGKILL) as the first bag comes back, while it holds another
    (each worker has two). Its bags go to the other worker (retried ≥ 1), every bag is replayed, each as in
    the serial run; the replay through the command line names the
    cluster."""
    folder, bags, (serial, _) = corpus
    dask = str(Path(sys.executable).parent / "dask")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    logs = [open(tmp_path / name, "w") for name in ("scheduler.log", "worker_a.log", "worker_b.log")]
    scheduler = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                  "--no-dashboard"], stdout=logs[0], stderr=subprocess.STDOUT, env=env)
    workers = [subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                                 "--host", "127.0.0.1"], stdout=log, stderr=subprocess.STDOUT, env=env)
               for log in logs[1:]]
    try:
        from distributed import Client
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        killed = []

        def kill_one(line):
            if not killed:
                workers[0].send_signal(signal.SIGKILL)
                killed.append(time.monotonic())
        outcomes, facts = replay_corpus(bags, OPTIONS, Engine(cluster=address), kill_one)
        assert killed and workers[0].wait(timeout=10) == -signal.SIGKILL
        assert without_timing(outcomes) == without_timing(serial)
        assert facts["address"] == address and facts["workers"] == 2 and facts["retried"] >= 1
        out = drive_in_process(["bench", "replay", folder, "--estimators", "injection_frame", "--windows", "0.25:0.4",
                                "--cluster", address, "--no-plot", "--json"])
        assert out.returncode == 0, out.stderr
        report = json.loads(out.stdout)
        assert report["engine"]["address"] == address and report["bags"] == BAGS
    finally:
        for process in (*workers, scheduler):
            process.kill()
            process.wait(timeout=10)
        for log in logs:
            log.close()


def test_the_engine_options_are_refused_where_they_do_not_apply(corpus):
    folder, bags, _ = corpus
    one = drive_in_process(["bench", "replay", bags[0], "--workers", "2", "--no-plot"])
    assert one.returncode == 2 and "is one bag" in one.stderr and one.stderr.count("\n") == 1
    both = drive_in_process(["bench", "replay", folder, "--workers", "2", "--cluster", "tcp://127.0.0.1:1"])
    assert both.returncode == 2 and "give one" in both.stderr
    none = drive_in_process(["bench", "replay", folder, "--workers", "0"])
    assert none.returncode == 2 and "--workers" in none.stderr


def test_a_corpus_report_is_one_self_contained_page_with_its_data_beside_it(corpus, tmp_path):
    """--report DIR: report.html with its plot inline and nothing fetched, report.json and bags.csv with one
    row per bag and estimator; per estimator the median over bags with its bootstrap interval around it; the
    ranking tests neighbours on their common bags; every not-applicable entry counted by its reason."""
    import csv
    folder, bags, _ = corpus
    out = drive_in_process(["bench", "replay", folder, "--estimators", ",".join(ESTIMATORS), "--windows", "0.25:0.4",
                            "--no-plot", "--report", tmp_path / "report", "--json"])
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    html = Path(report["report"]["html"]).read_text()
    assert "data:image/png;base64," in html and "http" not in html and "<script" not in html
    data = json.loads(Path(report["report"]["json"]).read_text())
    with open(report["report"]["csv"]) as stream:
        rows = list(csv.DictReader(stream))
    assert len(rows) == BAGS * len(ESTIMATORS) == len(data["rows"])
    for entry in data["estimators"]:
        assert entry["scored"] == BAGS
        low, high = entry["rms_median_ci"]
        assert low <= entry["rms_median"] <= high
        assert 0.0 <= entry["within_share_ci"][0] <= entry["within_share"] <= entry["within_share_ci"][1] <= 1.0
    ranked = data["ranking"]
    assert [r["estimator"] for r in ranked] == ["sensored", "injection_frame"]
    test = ranked[0]["against_next"]
    assert test["common_bags"] == BAGS and test["p"] is None
    assert data["by_pole_pairs"] == {"1-5": {name: {"bags": BAGS, "rms_median": next(
        e["rms_median"] for e in data["estimators"] if e["estimator"] == name)} for name in ESTIMATORS}}


def test_a_robots_recording_replays_to_the_bit_on_any_drawn_motor(tmp_path, monkeypatch):
    """Recordings that name no scenario (a robot's) on four drawn motors (seed 5), of ours on two and of the
    estimator the corpus draws on the others, each commissioned and run as `drive bag synth` runs it, its
    recorder losing nothing: the bag states the drive's bus, its estimator's settings (loops scaled to the
    motor; a paper's estimator on its paper's carrier) and its controller's, and replaying the recording's
    own estimator on it gives the recorded angle estimate to rounding (≤ 1e-9 rad), start-up included."""
    from drive_tools.evaluation import synthetic_corpus
    from drive_tools.evaluation.recording import read_recording
    from drive_tools.evaluation.replay import replay

    drawn = synthetic_corpus.draw_case

    def without_losses(seed, index, *args):
        case = drawn(seed, index, *args)
        estimator = case.estimator if index % 2 else "injection_frame"
        return case._replace(estimator=estimator, flaws=RecorderFlaws(scenario_named=False))
    monkeypatch.setattr(synthetic_corpus, "draw_case", without_losses)
    for index in range(4):
        row = synthetic_corpus.synthetic_bag((5, index, str(tmp_path), 0.4))
        assert row["written"], row
        recording = read_recording(str(tmp_path / row["bag"]), windows=[(0.3, 0.4)])
        assert recording.scenario is None and math.isfinite(recording.U_dc_V)
        assert recording.sources["estimator_settings"] == "drive_config estimator_settings"
        assert recording.sources["controller"] == "drive_config controller"
        _, (result,) = replay(recording, [recording.estimator])
        recorded, replayed = (log[:, COLUMN["theta_e_hat"]] for log in (recording.log, result.log))
        known = np.isfinite(recorded)
        assert known.sum() > 0.9 * len(recorded)
        assert np.max(np.abs(np.angle(np.exp(1j * (replayed[known] - recorded[known]))))) <= 1e-9, \
            recording.estimator


def test_a_robots_recorder_losing_messages_leaves_ours_replayed_as_the_drive_ran(tmp_path, monkeypatch):
    """Ours recorded on drawn motors (seed 6) by a recorder that loses 1 % of each per-sample topic's
    messages, drive_config without a scenario: where the drive answered a sample whose currents the recorder
    lost, replay rebuilds them (recorded_inputs.rebuilt_currents) and steps there as the drive did. On each
    recording that held its lock (RMS ≤ 0.05 rad in its scored window), the replay holds it too, within
    0.01 rad + 30 % of the recording's RMS; where its start-up follows the recorded one, its estimate stays
    within 0.05 rad of the recorded one at 99 % of the samples after the recording first tracked, else the
    entry says where it left and takes the polarity from the recording: as one sample of the alignment that
    neither the recording nor the drive holds (its currents and answers lost) makes it. (Before the rebuild,
    replay stepped over these samples: at π on 2 of 30 bags of a seed-31 corpus.)"""
    from drive_tools.evaluation import synthetic_corpus
    from drive_tools.evaluation.recorded_inputs import ANSWER_COLUMNS, replay_inputs
    from drive_tools.evaluation.recording import read_recording
    from drive_tools.evaluation.replay import replay

    drawn = synthetic_corpus.draw_case

    def lossy(seed, index, *args):
        case = drawn(seed, index, *args)
        return case._replace(estimator="injection_frame",
                             flaws=RecorderFlaws(epoch_s=1.76e9, lost_share=0.01, seed=index, scenario_named=False))
    monkeypatch.setattr(synthetic_corpus, "draw_case", lossy)
    held, rebuilt = [], 0
    for index in range(8):
        row = synthetic_corpus.synthetic_bag((6, index, str(tmp_path), 0.4))
        assert row["written"], row
        recording = read_recording(str(tmp_path / row["bag"]), windows=[(0.3, 0.39)])
        (entry,), (result,) = replay(recording, ["injection_frame"])
        recorded_scores = angle_scores(recording.log, recording.n_p, recording.windows, recording.start_s)
        if recorded_scores["angle_error_rms"] > 0.05 or recorded_scores["lock_lost_s"]:
            continue
        held.append(recording)
        currents = replay_inputs(recording)[0]
        rebuilt += int((np.isfinite(currents[:, 0]) & np.isnan(recording.log[:, COLUMN["i_a_meas"]])).sum())
        assert not entry["lost"] and entry["angle_error_rms"] <= 0.01 + 1.3 * recorded_scores["angle_error_rms"]
        if "left the recorded one" in entry["reason"]:
            continue
        recorded, replayed = (log[:, COLUMN["theta_e_hat"]] for log in (recording.log, result.log))
        after = np.arange(len(recorded)) >= np.argmax(recording.log[:, COLUMN["state"]] == TRACKING)
        known = after & np.isfinite(recorded) & np.isfinite(replayed)
        assert np.quantile(np.abs(np.angle(np.exp(1j * (replayed[known] - recorded[known])))), 0.99) <= 0.05
    assert len(held) >= 4 and rebuilt > 0, (len(held), rebuilt)
    recording = held[0]
    rms = angle_scores(recording.log, recording.n_p, recording.windows, recording.start_s)["angle_error_rms"]
    aligning = np.flatnonzero(recording.log[:, COLUMN["state"]] == ALIGNING)
    lost = [COLUMN[name] for name in ("i_a_meas", "i_b_meas", "i_c_meas", *ANSWER_COLUMNS)]
    recording.log[aligning[len(aligning) // 2], lost] = np.nan
    (entry,), _ = replay(recording, ["injection_frame"])
    assert "left the recorded one" in entry["reason"] and "polarity taken from the recording" in entry["reason"]
    assert not entry["lost"] and entry["angle_error_rms"] <= 0.01 + 1.3 * rms


def test_a_reports_classes_hold_their_bounds_and_come_in_their_order():
    """Pole pairs 5 are in the band "1-5" and 15 in "6-15"; bands are listed in their order (speed 2-10 %
    before 10-30 %, not as text), a bag whose figure is unknown last."""
    from drive_tools.evaluation.corpus_report import POLE_PAIR_BANDS, _band, class_table, speed_band

    rows = [{"bag": f"b{i}", "estimator": "x", "applicable": True, "angle_error_rms": 0.01 * (i + 1), "n_p": n_p,
             "speed_per_rated": speed} for i, (n_p, speed) in enumerate(((16, 0.5), (5, 0.2), (15, 0.05),
                                                                          (1, None), (6, 0.01)))]
    by_pole_pairs = class_table(rows, ["x"], "n_p", lambda v: _band(v, POLE_PAIR_BANDS))
    assert list(by_pole_pairs) == ["1-5", "6-15", "16+"]
    assert by_pole_pairs["1-5"]["x"]["bags"] == 2 and by_pole_pairs["6-15"]["x"]["bags"] == 2
    assert list(class_table(rows, ["x"], "speed_per_rated", speed_band)) == ["0-2 %", "2-10 %", "10-30 %",
                                                                             "30-110 %", "unknown"]
