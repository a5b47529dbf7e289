"""Misuse of the command line and scenario files: unsafe or non-finite settings are refused with one
line naming the key and the file, and no generated scenario file (≥ 200, mutated with hostile values)
gives a traceback or NaN/Infinity in the JSON output: a refusal names the file and the key mutated (or
one enclosing it)."""
import json
import random
import re

import pytest

from drive_tools.cli.cli import main

BASE = {"motor": "wang_spmsm", "estimator": {"type": "injection_frame", "settings": {"pll_bandwidth_Hz": 18.0}},
        "injection": {"frequency_Hz": 900.0, "amplitude_V": 5.0}, "duration_s": 0.02,
        "sampling_period_s": 1.0e-4, "speed": {"unit": "rpm", "points": [[0.0, 0.0], [0.01, 60.0]]},
        "load": {"unit": "rated", "points": [[0.0, 0.0]]}, "initial": {"theta_m_rad": 0.3},
        "controller": {"current_limit_A": 5.0, "hf_notch_quality": 1.0, "speed_limit_rad_s": 100.0},
        "metrics": {"settle_s": 0.005}, "seed": 1, "substeps": 1, "block_samples": 1,
        "answer_periods": 0}
HOSTILE = [float("nan"), float("inf"), -float("inf"), -1, 0, 0.0, 1e308, 5e-324, 1e12, 1e-12, "abc", "5", True,
           None, [], {}, [[1, 2]], 2 ** 70, -2 ** 70, "", [1.0, 2.0, 3.0], {"a": 1}]


def write(tmp_path, name, document):
    path = tmp_path / f"{name}.yaml"
    path.write_text(json.dumps(document, allow_nan=True).replace("NaN", ".nan").replace("-Infinity", "-.inf")
                    .replace("Infinity", ".inf"))
    return str(path)


def run_cli(capsys, argv):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def strict(text):
    def refuse(constant):
        raise AssertionError(f"non-strict JSON constant {constant}")
    return json.loads(text, parse_constant=refuse)


@pytest.mark.parametrize("section, key, value", [
    ("controller", "current_limit_A", float("nan")),
    ("controller", "current_limit_A", float("inf")),
    ("controller", "current_limit_A", "5"),
    ("controller", "current_limit_A", 17.7),
    ("controller", "hf_notch_quality", 0),
    ("controller", "speed_limit_rad_s", float("nan")),
    ("controller", "speed_filter_Hz", 6000.0),
    ("injection", "frequency_Hz", 5e-324),
    ("injection", "amplitude_V", float("inf")),
])
def test_unsafe_settings_are_refused_naming_key_and_file(tmp_path, capsys, section, key, value):
    document = json.loads(json.dumps(BASE))
    document[section][key] = value
    path = write(tmp_path, "unsafe", document)
    code, out, err = run_cli(capsys, ["run", path, "--no-plot", "--json"])
    assert code == 2 and out == "", out
    assert err.count("\n") == 1 and path in err and key in err, err


@pytest.mark.parametrize("name, value", [("controller.current_limit_A", float("nan")), ("duration_s", -1.0),
                                         ("lockstep_timeout_s", float("inf")), ("seed", -5),
                                         ("injection.frequency_Hz", float("-inf"))])
def test_an_unsafe_node_parameter_is_refused_naming_it(name, value):
    from drive_common.config.parameters import all_parameters, scenario_from_parameters
    from drive_common.config.scenario import ScenarioError
    with pytest.raises(ScenarioError, match=f"^parameter {name}: must be a finite number"):
        scenario_from_parameters(all_parameters({name: value}))


@pytest.mark.parametrize("key, value", [("block_samples", 0), ("block_samples", 101), ("block_samples", 2.5),
                                        ("block_samples", "10"), ("block_samples", True), ("answer_periods", -1),
                                        ("answer_periods", 102), ("answer_periods", 1.5)])
def test_a_block_size_out_of_range_is_refused_naming_it(tmp_path, capsys, key, value):
    document = {**json.loads(json.dumps(BASE)), key: value}
    path = write(tmp_path, "blocks", document)
    code, out, err = run_cli(capsys, ["run", path, "--no-plot", "--json"])
    assert code == 2 and out == "" and err.count("\n") == 1 and path in err and key in err, err


@pytest.mark.parametrize("argv, named", [(["run", "wang_100rpm", "--block-samples", "0"], "--block-samples"),
                                         (["bench", "graph", "--block-samples", "5,x"], "--block-samples"),
                                         (["bridge", "{answer}", "--no-plot"], "answer_periods"),
                                         (["launch", "{answer}", "--link", "can"], "answer_periods"),
                                         (["bench", "bridge", "--block-samples", "31"], "--block-samples")])
def test_blocks_where_they_cannot_go_are_refused_in_one_line(tmp_path, capsys, argv, named):
    """A block size out of range on the command line, and blocks behind an inverter answered at another
    delay than the protocol's (N + 1 periods), are refused before anything runs."""
    answer = write(tmp_path, "answer", {**json.loads(json.dumps(BASE)), "block_samples": 5, "answer_periods": 3})
    code, out, err = run_cli(capsys, [a.format(answer=answer) for a in argv])
    assert code == 2 and out == "" and err.count("\n") == 1 and named in err, err


def mutations(rng, count):
    """(name, file content) pairs: one value replaced by a hostile one, a key dropped, or the file
    itself broken."""
    paths = []

    def walk(node, trail):
        for key, value in node.items():
            paths.append(trail + (key,))
            if isinstance(value, dict):
                walk(value, trail + (key,))
    walk(BASE, ())
    yield "non_utf8", b"motor: \xff\xfe wang\n", ()
    yield "deep", ("a: " + "[" * 5000 + "]" * 5000 + "\n").encode(), ()
    yield "list_top", b"- 1\n- 2\n", ()
    yield "aliases", b"a: &a [1, 2]\nb: *a\n", ("a",)
    for i in range(count):
        document = json.loads(json.dumps(BASE))
        trail = rng.choice(paths)
        parent = document
        for key in trail[:-1]:
            parent = parent[key]
        if rng.random() < 0.1:
            del parent[trail[-1]]
        else:
            parent[trail[-1]] = rng.choice(HOSTILE)
        text = json.dumps(document, allow_nan=True).replace("NaN", ".nan").replace("-Infinity", "-.inf")
        yield f"m{i}_{'_'.join(map(str, trail))}", text.replace("Infinity", ".inf").encode(), trail


def test_generated_scenario_files_give_one_line_or_a_strict_result(tmp_path, capsys):
    rng = random.Random(20261122)
    outcomes = {0: 0, 2: 0}
    for name, content, trail in mutations(rng, 220):
        path = tmp_path / f"{name}.yaml"
        path.write_bytes(content)
        code, out, err = run_cli(capsys, ["run", str(path), "--no-plot", "--json"])
        assert code in outcomes, (name, code, err)
        outcomes[code] += 1
        if code == 2:
            assert err.count("\n") == 1 and str(path) in err and "Traceback" not in err, (name, err)
            named = [re.escape(".".join(map(str, trail[:n]))) for n in range(1, len(trail) + 1)]
            assert not trail or re.search(rf"(?<![\w.])({'|'.join(named)})(?![\w.])", err), (name, err)
        else:
            metrics = strict(out)
            assert metrics["samples"] > 0, name
    assert outcomes[0] > 10 and outcomes[2] > 100, outcomes


def test_a_full_disk_while_recording_keeps_the_metrics_and_what_was_written(small_disk, capsys, tmp_path):
    bag = small_disk / "full"
    code, out, err = run_cli(capsys, ["run", "wang_100rpm", "--duration", "0.6", "--no-plot", "--json",
                                      "--record", str(bag)])
    assert code == 4, err
    metrics = strict(out)
    assert metrics["angle_error_rms"] is not None and "No space left" in metrics["recording_error"]
    assert err.count("\n") == 1 and "No space left on device" in err and str(bag) in err
    assert not (bag / "metadata.yaml").exists() and (bag / "full_0.mcap").stat().st_size > 0
    copy = tmp_path / "copy"
    import shutil
    shutil.copytree(bag, copy)
    code, out, err = run_cli(capsys, ["bag", "reindex", str(copy), "--json"])
    assert code == 0, err
    assert strict(out)["messages"] > 0


@pytest.mark.parametrize("target, message", [("/nonexistent/x/bag", "does not exist"),
                                             ("/proc/drive_bag", "cannot write")])
def test_a_record_target_that_cannot_be_written_is_refused_before_running(capsys, target, message):
    code, out, err = run_cli(capsys, ["run", "wang_100rpm", "--duration", "0.01", "--no-plot",
                                      "--record", target])
    assert code == 2 and out == "" and message in err and err.count("\n") == 1, err
    import os
    assert not os.path.exists("/nonexistent")


def test_a_plot_that_cannot_be_written_keeps_the_metrics(capsys):
    code, out, err = run_cli(capsys, ["run", "wang_100rpm", "--duration", "0.6", "--json", "--out",
                                      "/proc/drive_plots"])
    assert code == 4 and err.count("\n") == 1 and "/proc/drive_plots" in err, err
    metrics = strict(out)
    assert metrics["angle_error_rms"] is not None and "plots" not in metrics and metrics["plot_error"]


@pytest.mark.parametrize("argv", [["bag", "info", "{d}"], ["bench", "replay", "{d}"], ["bag", "reindex", "{d}"],
                                  ["bench", "compare", "{d}", "{d}"]])
def test_a_directory_that_is_not_a_bag_gives_one_line(tmp_path, capsys, argv):
    directory = tmp_path / "not_a_bag"
    (directory / "sub").mkdir(parents=True)
    code, out, err = run_cli(capsys, [a.format(d=directory) for a in argv])
    assert code == 2 and out == "" and err.count("\n") == 1 and str(directory) in err, err
    assert "reindex" not in err or argv[1] == "reindex"


def test_an_invalid_namespace_is_refused_in_one_line(capsys):
    code, out, err = run_cli(capsys, ["launch", "wang_100rpm", "--namespace", "/bad-ns", "--no-plot"])
    assert code == 2 and err.startswith("drive: namespace '/bad-ns' is not a ROS namespace") and \
        err.count("\n") == 1
