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
    assert driver.save_screenshot(str(tmp_path / "index.png"))
    assert (tmp_path / "index.png").stat().st_size > 10_000
    assert _console_errors(driver) == []


def test_case_page(reports, driver, tmp_path):
    from selenium.webdriver.common.by import By

    driver.get((reports / "two_link_switching" / "index.html").as_uri())
    for tid in ("faults", "schemes", "phases", "thresholds"):
        assert driver.find_element(By.ID, tid).is_displayed(), tid
    figures = driver.find_elements(By.CSS_SELECTOR, "figure svg")
    assert len(figures) >= 5
    for f in figures:
        size = f.size
        assert size["width"] > 200 and size["height"] > 100
    assert len(driver.find_elements(By.CSS_SELECTOR, "#schemes tbody tr")) == 3
    assert driver.save_screenshot(str(tmp_path / "case.png"))
    assert _console_errors(driver) == []
