"""A real browser opens the reports: tables and figures present, no console errors.

Needs Debian's chromium and chromium-driver (.ci/run installs them).  Skipped
locally when they are missing; under CI (CI=true) their absence is a failure.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from ftcreport.batch import run_batch

CASES = Path(__file__).resolve().parents[1] / "cases"
SUBSET = [CASES / "two_link_switching.toml", CASES / "two_link_intermittent.toml"]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")

if not (CHROMIUM and DRIVER):
    if os.environ.get("CI"):
        pytest.fail("CI must install chromium and chromium-driver (see .ci/run)", pytrace=False)
    pytest.skip("chromium/chromedriver not installed", allow_module_level=True)

webdriver = pytest.importorskip("selenium.webdriver")


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    out = tmp_path_factory.mktemp("browser_reports")
    # two cases keep the test quick; 22 s keeps their faults at 20 s
    res = run_batch(SUBSET, out, jobs=2, duration=22.0, show_progress=False)
    assert not res.failed_runs and not res.case_errors
    return out


@pytest.fixture(scope="module")
def driver():
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = CHROMIUM
    for arg in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--window-size=1200,1600",
    ):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    drv = webdriver.Chrome(service=Service(DRIVER), options=opts)
    yield drv
    drv.quit()


def _console_errors(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def test_index_page(reports, driver, tmp_path):
    from selenium.webdriver.common.by import By

    driver.get((reports / "index.html").as_uri())
    table = driver.find_element(By.ID, "matrix")
    rows = table.find_elements(By.CSS_SELECTOR, "tbody tr")
    assert len(rows) == len(SUBSET)
    # sorting by clicking a header reorders rows without errors
    headers = table.find_elements(By.CSS_SELECTOR, "th.sortable")
    headers[0].click()
    first = table.find_elements(By.CSS_SELECTOR, "tbody tr td")[0].text
    headers[0].click()
    assert table.find_elements(By.CSS_SELECTOR, "tbody tr td")[0].text != first
    # the scoreboard comes first: wins per metric per scheme, one row per case linking to its page
    board = driver.find_element(By.ID, "scoreboard")
    assert board.location["y"] < table.location["y"]
    names = [r.find_element(By.CSS_SELECTOR, "td").text for r in board.find_elements(By.CSS_SELECTOR, "tbody tr")]
    assert {"nominal", "switching", "adaptive", "oracle"} <= set(names)
    wins = board.find_element(By.CSS_SELECTOR, "tbody tr td:nth-child(2)").text
    assert " / " in wins  # "k / N": cases won out of cases with a winner
    links = driver.find_elements(By.CSS_SELECTOR, "#cases tbody tr td:first-child a")
    assert sorted(a.get_attribute("href").split("/")[-2] for a in links) == sorted(p.stem for p in SUBSET)
    assert driver.find_element(By.ID, "regret").is_displayed()
    assert driver.save_screenshot(str(tmp_path / "index.png"))
    assert (tmp_path / "index.png").stat().st_size > 10_000
    assert _console_errors(driver) == []


def test_case_page(reports, driver, tmp_path):
    from selenium.webdriver.common.by import By

    driver.get((reports / "two_link_switching" / "index.html").as_uri())
    for tid in ("faults", "schemes", "phases", "thresholds"):
        assert driver.find_element(By.ID, tid).is_displayed(), tid
    # static figures (paths, articulation, poles) are inline SVG; the time series are plotly figures
    figures = driver.find_elements(By.CSS_SELECTOR, "figure > svg")
    figures += driver.find_elements(By.CSS_SELECTOR, "figure div.plotly-fig svg.main-svg:first-child")
    assert len(figures) >= 5
    assert len(driver.find_elements(By.CSS_SELECTOR, "figure div.plotly-fig")) >= 3  # errors, torques, switching
    for f in figures:
        size = f.size
        assert size["width"] > 200 and size["height"] > 100
    # nominal, switching, adaptive, oracle; active and active_ukf cannot apply at k_v = 3000 and say why
    assert len(driver.find_elements(By.CSS_SELECTOR, "#schemes tbody tr")) == 4
    assert len(driver.find_elements(By.CSS_SELECTOR, "p.not-run")) == 2
    assert driver.save_screenshot(str(tmp_path / "case.png"))
    assert _console_errors(driver) == []


def test_verdict_replay_and_interactive_figures(reports, driver):
    import time

    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver.get((reports / "two_link_intermittent" / "index.html").as_uri())
    # the verdict is the first thing under the title: sentences, then a row per headline metric
    first = driver.find_element(By.XPATH, "//h1/following-sibling::*[1]")
    assert first.get_attribute("id") == "verdict"
    sentences = first.find_elements(By.CSS_SELECTOR, "p.verdict-sentence")
    assert 2 <= len(sentences) <= 4 and "After the faults at 10 and 20 s" in sentences[0].text
    rows = first.find_elements(By.CSS_SELECTOR, "#verdict-table tbody tr")
    metrics = [r.get_attribute("data-metric") for r in rows]
    head = ["after_fault_error_max", "position_error_final", "recovery_time_max", "torque_peak", "energy"]
    assert metrics[:5] == head
    assert {"detection_delay_max", "false_alarms"} <= set(metrics)
    # the replay advances when played, stops when paused, and the scrubber moves it
    replay = driver.find_element(By.ID, "replay")
    assert len(replay.find_elements(By.CSS_SELECTOR, "canvas")) == 6  # every scheme side by side
    t0 = float(replay.get_attribute("data-t"))
    driver.find_element(By.ID, "replay-play").click()
    time.sleep(0.8)
    driver.find_element(By.ID, "replay-play").click()
    t1 = float(replay.get_attribute("data-t"))
    assert t1 > t0 + 0.5  # 5x speed: about 4 s of simulated time in 0.8 s
    time.sleep(0.3)
    assert float(replay.get_attribute("data-t")) == t1  # paused
    driver.execute_script(
        "var s = document.getElementById('replay-scrub'); s.value = '900'; s.dispatchEvent(new Event('input'));"
    )
    assert float(replay.get_attribute("data-t")) == pytest.approx(0.9 * 22.0, abs=0.05)
    assert driver.find_element(By.ID, "replay-time").text == "t = 19.8 s"
    # a single scheme at full size
    Select(driver.find_element(By.ID, "replay-scheme")).select_by_value("switching")
    canvases = replay.find_elements(By.CSS_SELECTOR, "canvas")
    assert len(canvases) == 1 and canvases[0].get_attribute("data-scheme") == "switching"
    # hovering the tracking-error figure shows the values under the cursor
    fig = driver.find_element(By.ID, "plot-errors")
    driver.execute_script("arguments[0].scrollIntoView()", fig)
    ActionChains(driver).move_to_element_with_offset(fig, 120, -120).perform()
    time.sleep(0.5)
    labels = [e.text for e in driver.find_elements(By.CSS_SELECTOR, "#plot-errors .hoverlayer text")]
    assert any(" m" in x and any(c.isdigit() for c in x) for x in labels), labels
    # fault phases shaded: one rectangle from the first event
    assert len(driver.find_elements(By.CSS_SELECTOR, "#plot-errors .shapelayer path")) >= 2
    assert _console_errors(driver) == []
