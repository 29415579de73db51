"""The dashboard page in a real browser against a real demo stack.

``ersac-hil demo --secure --dashboard --linger`` (router with TLS, client certificates and the
roles' access control, CAN hub, MuJoCo simulator, agent, daemon, and the dashboard acting as the
operator) runs once for the module; headless Chromium (Debian's ``chromium`` with its
``chromedriver``, driven by Selenium; never a downloaded browser) opens the page while the
run learns. The daemon's state is checked with ``ersac-hil state`` as the observer. Screenshots go to ``$ERSAC_ARTIFACTS/dashboard/`` (default ``./artifacts``).
Skipped with the reason where Chromium, its driver or Selenium is missing.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from ersac_hil.dashboard.browser import console_errors, headless_chromium, missing
from ersac_hil.stack import Child
from helpers.waiting import wait_until
from helpers.webclient import http

ROOT = Path(__file__).resolve().parents[3]
ARTIFACTS = Path(os.environ.get("ERSAC_ARTIFACTS", ROOT / "artifacts")) / "dashboard"
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl",
       "PYTHONUNBUFFERED": "1"}
EPISODES = 8
ROBOT = "ubot1"
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """Headless Chromium, started before the demo so that the page can open with the run."""
    reason = missing()
    if reason:
        pytest.skip(f"{reason}; .ci/run installs it")
    driver = headless_chromium(tmp_path_factory.mktemp("chromium"))
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="module")
def demo(browser, tmp_path_factory):
    """The demo stack with the dashboard, lingering after its run; stopped with Ctrl-C (SIGINT).
    The page opens as soon as the dashboard is up, before the daemon starts: it sees the whole
    run live, however fast the run goes."""
    out = tmp_path_factory.mktemp("demo")
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    demo = Child("demo", [sys.executable, "-m", "ersac_hil.cli", "demo", "--out", str(out), "--episodes",
                          str(EPISODES), "--seed", "3", "--kappa", "2", "--secure", "--dashboard", "--dashboard-port",
                          "0", "--linger"], ARTIFACTS, ENV)
    try:
        url = demo.wait_for(r"^demo: dashboard (http://\S+)", 120).group(1)
        browser.get(url)
        demo.wait_for(r"^demo: children ", 60)
        stack = json.loads((out / "stack.json").read_text())
        yield {"url": url, "configs": stack["configs"]}
        os.killpg(demo.pid, signal.SIGINT)  # Ctrl-C
        assert demo.proc.wait(60) == 130
    finally:
        demo.stop()
    children = demo.wait_for(r"^demo: children (.*)$", 1).group(1)
    for pid in (int(item.split("=")[1]) for item in children.split()):
        assert not Path(f"/proc/{pid}").exists() or Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"


def _js(driver, script: str):  # noqa: ANN001, ANN202
    return driver.execute_script(f"return {script};")


def _wait_js(driver, script: str, what: str, timeout_s: float = 120):  # noqa: ANN001, ANN202
    return wait_until(lambda: _js(driver, script), timeout_s=timeout_s, poll_s=0.1, what=what)


def _cli_state(demo) -> dict:  # noqa: ANN001
    done = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "state", "--json", "--robot", ROBOT,
                           "--zenoh-config", demo["configs"]["observer"]], capture_output=True, text=True,
                          timeout=60, cwd=ROOT, env=ENV)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def _message(driver) -> str:  # noqa: ANN001
    return _js(driver, "document.getElementById('message').textContent")


def test_page_loads_and_the_curve_gains_points_as_episodes_arrive(demo, browser):
    assert browser.title == "ersac-hil dashboard"
    _wait_js(browser, "window.dashboard.points.length >= 1", "a first point")
    first = _js(browser, "window.dashboard.points.length")
    assert first < EPISODES, "the run was over before the page saw it learn"
    _wait_js(browser, f"window.dashboard.points.length > {first}", "a later point")
    plotted = _js(browser, "document.getElementById('curve').data.slice(0, 3)"
                           ".reduce((n, t) => n + t.x.length, 0)")
    assert plotted >= first + 1
    browser.save_screenshot(str(ARTIFACTS / "learning.png"))
    assert console_errors(browser) == []


def test_moving_kappa_changes_the_daemons_kappa(demo, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    _wait_js(browser, "window.dashboard.state && window.dashboard.state.kappa === 2", "the demo's kappa")
    browser.find_element(By.ID, "kappa-slider").send_keys(Keys.ARROW_RIGHT)  # one step: 2.0 -> 2.1
    wait_until(lambda: _message(browser) == "kappa set to 2.1", what="the confirmation")
    assert _cli_state(demo)["kappa"] == 2.1
    assert console_errors(browser) == []
    number = browser.find_element(By.ID, "kappa-number")
    number.clear()
    number.send_keys("50", Keys.ENTER)
    wait_until(lambda: _message(browser).startswith("refused"), what="a visible refusal")
    assert "kappa" in _message(browser) and "10" in _message(browser)
    assert "error" in browser.find_element(By.ID, "message").get_attribute("class")
    assert _cli_state(demo)["kappa"] == 2.1
    # the browser logs the refused request itself (HTTP 400) and nothing else
    assert [re.sub(r"^\S+/api/", "/api/", e) for e in console_errors(browser)] == [
        "/api/kappa - Failed to load resource: the server responded with a status of 400 (Bad Request)"]


def test_select_then_adopt_changes_theta(demo, browser):
    from selenium.webdriver.common.by import By

    _wait_js(browser, f"window.dashboard.state && window.dashboard.state.episode_count === {EPISODES} "
                      "&& window.dashboard.state.status === 'idle'", "the end of the run", timeout_s=300)
    _wait_js(browser, "window.dashboard.critic && window.dashboard.critic.episode_count === "
                      f"{EPISODES}", "the critic after the last update")
    browser.find_element(By.ID, "select-kappa").clear()
    browser.find_element(By.ID, "select-kappa").send_keys("-1")
    browser.find_element(By.ID, "select").click()
    wait_until(lambda: browser.find_element(By.ID, "selection").is_displayed(), what="the selection")
    selected = _js(browser, "window.dashboard.selection")
    assert selected["adopted"] is False and selected["kappa"] == -1
    before = _cli_state(demo)["theta"]
    assert _js(browser, "window.dashboard.state.theta") == before  # a selection changes nothing
    browser.find_element(By.ID, "adopt").click()
    wait_until(lambda: _message(browser).startswith("adopted"), what="the adoption")
    adopted = _js(browser, "window.dashboard.selection")
    assert adopted["adopted"] is True
    assert _cli_state(demo)["theta"] == adopted["theta"]
    assert before != adopted["theta"]
    _wait_js(browser, f"JSON.stringify(window.dashboard.state.theta) === '{json.dumps(adopted['theta'])}'"
             .replace(" ", ""), "the page's state to show the adopted theta")
    browser.save_screenshot(str(ARTIFACTS / "dashboard.png"))
    assert console_errors(browser) == []


def test_every_episode_is_drawn_once_after_it_was_published(demo, browser):
    """Every episode that came live is drawn once, in order, and after the learner published it
    (how long after is bench/dashboard.py's figure, not a test's)."""
    _wait_js(browser, f"window.dashboard.points.length >= {EPISODES}", "every episode drawn", timeout_s=300)
    points = _js(browser, "window.dashboard.points")
    latency = _js(browser, "window.dashboard.latency")
    ids = [p["episode_id"] for p in points]  # the first ones may have come with the page's snapshot
    assert len(set(ids)) == len(ids) == EPISODES
    assert latency and [r["episode_id"] for r in latency] == ids[len(ids) - len(latency):]
    # one machine, one wall clock: drawn no earlier than published (1 ms: the page's clock
    # is read at millisecond resolution)
    early = [r for r in latency if r["shown_ms"] < 1000 * r["stamp_s"] - 1.0]
    assert not early, early
    (ARTIFACTS / "latency.json").write_text(json.dumps(latency, indent=1))


def test_observer_page_shows_no_controls(demo, browser):
    """A dashboard with the observer's certificate (no --read-only flag): no controls, 403."""
    from selenium.webdriver.common.by import By

    proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.cli", "dashboard", "--robot", ROBOT,
                             "--zenoh-config", demo["configs"]["observer"], "--port", "0"], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = proc.stdout.readline()
        url = re.match(r"dashboard: (http://\S+) .*role observer, read-only", line)
        assert url, line + proc.stdout.read() if proc.poll() is not None else line
        browser.get(url.group(1))
        run_id = _cli_state(demo)["run_id"]
        wait_until(lambda: browser.find_element(By.ID, "s-run").text == run_id, what="the state")
        _wait_js(browser, f"window.dashboard.critic && window.dashboard.critic.episode_count === {EPISODES}",
                 "the critic")
        # nothing to act with; the plots' own zoom/pan buttons (Plotly's mode bar) only change the view
        assert browser.find_elements(By.CSS_SELECTOR, "#controls, input, select, textarea, "
                                                      "button:not(.modebar-btn)") == []
        assert browser.find_element(By.ID, "mode").text == "read-only"
        status, reply = http(url.group(1) + "api/kappa", {"kappa": 0.0})
        assert status == 403 and reply["error"]["code"] == "forbidden"
        assert _cli_state(demo)["kappa"] == 2.1
        browser.save_screenshot(str(ARTIFACTS / "observer.png"))
        assert console_errors(browser) == []
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 128 + signal.SIGTERM
