"""The outside DDS client (dds_client.py) in a process of its own, as the tests run it: started, waited on until its
topics matched, its lines read."""
import json
import subprocess
import sys
import time
from pathlib import Path

CLIENT = Path(__file__).resolve().parent / "dds_client.py"


def client(out, *args):
    """The client in a process of its own, its lines into the file ``out`` (a pipe nobody reads while the drive
    runs would stop it once full)."""
    with open(out, "w") as stream:
        return subprocess.Popen([sys.executable, str(CLIENT), *args], stdout=stream, stderr=subprocess.PIPE,
                                text=True)


def lines(process, out, timeout_s=120.0):
    """(the messages the client read, its summary) once it ended."""
    _, err = process.communicate(timeout=timeout_s)
    assert process.returncode == 0, err
    records = [json.loads(line) for line in Path(out).read_text().splitlines()]
    return [r for r in records[:-1] if "topic" in r], records[-1]["summary"]


def matched(process, out, topics, timeout_s=120.0):
    """Wait until the client has started and says each of ``topics`` matched (its reader a writer, its writer a
    reader)."""
    end = time.monotonic() + timeout_s
    while True:
        records = [json.loads(line) for line in Path(out).read_text().splitlines()]
        said = {r.get("matched") for r in records}
        if {"started": True} in records and set(topics) <= said:
            return
        assert process.poll() is None and time.monotonic() < end, f"the client matched only {said & set(topics)}"
        time.sleep(0.05)


def read_so_far(out):
    """The messages the running client has read so far (its lines in ``out``)."""
    return [r for r in (json.loads(line) for line in Path(out).read_text().splitlines()) if "topic" in r]
