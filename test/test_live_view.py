"""`drive view` in a real headless browser: Chromium from the system's packages (installed here when absent and
the test may, as ./setup.sh does), driven by Selenium. A drive runs 3 s behind a virtual inverter with blocks of
10 at 10 kHz, so its bridge publishes `angle_error` at 1 kHz (one per block: the block's first sample), with
command blocks lost on the way; a `drive view` process serves it; the page must plot at least 90 % of the angle
error messages the drive published (the bag the launcher recorded counts them) and show the faults on its
counters."""
import json
import os
import shutil
import subprocess
import sys
import time

import pytest

from drive_tools.bags.reader import bag_info
from drive_tools.doubles.faults import FaultPlan, faulty
from drive_tools.launch.launcher import DriveSpec, launch

AXIS = "/live_view"
CHROMIUM, DRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
RUN_S = 3.0
LATE_EVERY = 37
"""Every 37th command block lost: 10 periods at zero volts each, counted by the inverter."""
WATCHDOG_RUN = tuple(range(1500, 1503))
"""Three command blocks lost in a row (the inverter's watchdog: three blocks) trip it once."""


def chromium():
    """The system's Chromium and its driver: installed with apt-get when absent (as ./setup.sh does), else the
    test is skipped saying why."""
    if not (os.path.exists(CHROMIUM) and os.path.exists(DRIVER)):
        if os.geteuid() != 0 or not shutil.which("apt-get"):
            pytest.skip("Chromium is not installed and this user cannot install it (apt-get install chromium "
                        "chromium-driver, as root)")
        for step in (["apt-get", "install", "-y", "-q", "chromium", "chromium-driver"], ["apt-get", "update", "-q"],
                     ["apt-get", "install", "-y", "-q", "chromium", "chromium-driver"]):
            if subprocess.run(step, capture_output=True).returncode == 0 and os.path.exists(DRIVER):
                break
    if not (os.path.exists(CHROMIUM) and os.path.exists(DRIVER)):
        pytest.skip("apt-get could not install chromium and chromium-driver here (no package source)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        options.add_argument(flag)
    return webdriver.Chrome(options=options, service=Service(DRIVER))


def page_state(browser):
    return json.loads(browser.execute_script(
        "const v = window.driveView; return JSON.stringify({connected: v.connected, errors: v.errors, "
        "axes: Object.fromEntries(Object.entries(v.axes).map(([k, a]) => [k, {plotted: a.plotted, "
        "counters: a.counters, shown: a.el.querySelector('.counters').textContent}]))});"))


def wait_for(what, condition, timeout_s=30.0):
    end = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.1)


@pytest.mark.heavy
def test_the_page_plots_a_drives_angle_error_as_it_comes_and_counts_its_faults(tmp_path):
    """Lock-step, so the count does not hang on the machine's pace: the drive's 1 kHz of angle error (of its
    time) came at about 300 a second of wall time on the 2-core machine (3 s of drive time in about 10 s)."""
    browser = chromium()
    view = subprocess.Popen([sys.executable, "-m", "drive_tools.cli", "view", "--namespace", AXIS, "--port", "0",
                             "--page-port", "0"], stdout=subprocess.PIPE, text=True)
    try:
        ready = view.stdout.readline()
        assert ready.startswith("drive view: page http://127.0.0.1:"), ready
        browser.get(ready.split()[3])
        wait_for("the page to connect", lambda: page_state(browser)["connected"])
        faults = FaultPlan(lose_command_every=LATE_EVERY, lose_commands=WATCHDOG_RUN)
        bag = tmp_path / "run"
        launch(DriveSpec("wang_100rpm", AXIS, duration_s=RUN_S, extra_parameters={"block_samples": 10},
                         bag=str(bag), link="pty", inverter=faulty(faults)))
        published = {t["topic"]: t["count"] for t in bag_info(bag)["topics"]}[f"{AXIS}/angle_error"]
        assert published == RUN_S * 1000

        def settled():
            axis = page_state(browser)["axes"].get(AXIS)
            return axis and axis["plotted"]["angle_error"] >= 0.9 * published and axis["counters"]["late_periods"]
        wait_for("the page's plots and counters", settled, timeout_s=90.0)
        time.sleep(2.0)
        state = page_state(browser)
        axis = state["axes"][AXIS]
        lost = faults.counts["commands_lost"]
        assert state["errors"] == []
        assert 0.9 * published <= axis["plotted"]["angle_error"] <= published
        assert axis["plotted"]["speed"] > 0 and axis["plotted"]["currents"] > 0
        assert axis["counters"]["late_periods"] >= 10 * lost > 0
        assert axis["counters"]["watchdog"] >= 1 and axis["counters"]["faults"] >= 1
        assert f"late periods {axis['counters']['late_periods']}" in axis["shown"]
    finally:
        browser.quit()
        view.send_signal(2)
        view.wait(10)
