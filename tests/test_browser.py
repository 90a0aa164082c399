"""A real browser opens the reports: tables and figures present, no console errors.

Needs Debian's chromium and chromium-driver (.ci/run installs them).  Skipped
locally when they are missing; under CI (CI=true) their absence is a failure.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from ftcreport.studies.batch import run_batch

CASES = Path(__file__).resolve().parents[1] / "cases"
# the motor overlay of two_link_switching (its page compares with it, so both run)
SUBSET = [CASES / "two_link_switching.toml", CASES / "two_link_intermittent.toml"]
MOTORS = CASES / "motors" / "two_link_switching_motors.toml"
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
    res = run_batch([*SUBSET, MOTORS], out, jobs=2, duration=22.0, show_progress=False)
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
    assert len(rows) == len(SUBSET) + 1
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
    assert sorted(a.get_attribute("href").split("/")[-2] for a in links) == sorted(p.stem for p in [*SUBSET, MOTORS])
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
    head = ["after_fault_error_max", "position_error_final", "recovery_time_max", "torque_peak_after_fault", "energy"]
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
    # fault phases shaded: every phase with a fault (10-20 s: 1l lost; after 20 s: healthy again, unshaded),
    # colored by pattern, with the pattern's gains in the legend
    shapes = driver.execute_script("return document.getElementById('plot-errors').layout.shapes")
    rects = [s for s in shapes if s["type"] == "rect"]
    assert [(r["x0"], r["x1"]) for r in rects] == [(10.0, 20.0)]
    assert rects[0]["showlegend"] and "gains 1 0 1 1" in rects[0]["name"]
    legend = " ".join(e.text for e in driver.find_elements(By.CSS_SELECTOR, "#plot-errors .legendtext"))
    assert "gains 1 0 1 1" in legend
    assert _console_errors(driver) == []


def _wait_drawn(driver, timeout: float = 30.0) -> None:
    """Until the page's inline plotly.js is unpacked and every interactive figure drawn."""
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(driver, timeout).until(lambda d: d.execute_script("return document.body.dataset.figures"))
    assert driver.execute_script("return document.body.dataset.figures") == "drawn"


def _trace_values(driver, div: str, axis: str) -> list[float]:
    """Every y value the traces of figure ``div`` draw on ``axis`` (e.g. 'y2')."""
    return driver.execute_script(
        "var d = document.getElementById(arguments[0]).data, axis = arguments[1], out = [];"
        "d.forEach(function (t) { if ((t.yaxis || 'y') === axis) t.y.forEach(function (v) {"
        " if (v !== null) out.push(v); }); }); return out;",
        div,
        axis,
    )


def test_motor_page_plots_voltage_and_current_with_the_limits(reports, driver, tmp_path):
    """Issue 35 item 1: the motor case is about chatter at the voltage limit; its page plots the armature
    voltage and current per wheel, with +-V_max drawn, and the voltage reaches the 48 V limit."""
    from selenium.webdriver.common.by import By

    driver.get((reports / "two_link_switching_motors" / "index.html").as_uri())
    _wait_drawn(driver)
    fig = driver.find_element(By.ID, "plot-motors")
    driver.execute_script("arguments[0].scrollIntoView()", fig)
    assert fig.size["height"] > 500 and fig.size["width"] > 600
    lay = driver.execute_script("return document.getElementById('plot-motors').layout")
    assert "armature voltage" in lay["yaxis2"]["title"]["text"] and "current" in lay["yaxis5"]["title"]["text"]
    limits = {round(s["y0"], 6) for s in lay["shapes"] if s["type"] == "line" and s.get("yref") == "y2"}
    assert limits == {48.0, -48.0}  # the driver's supply, the [actuators] default
    volts = _trace_values(driver, "plot-motors", "y2")  # the whole run, the switching scheme's wheels
    amps = _trace_values(driver, "plot-motors", "y5")
    assert volts and amps
    assert max(abs(v) for v in volts) <= 48.0 + 1e-6  # the driver saturates at +-V_max
    assert max(abs(v) for v in volts) >= 0.99 * 48.0  # and the chattering command drives it there
    assert max(abs(a) for a in amps) > 1.0
    caption = driver.find_element(By.CSS_SELECTOR, "#fig-motors figcaption").text
    assert "+-48 V" in caption and "first second" in caption
    # the oracle is beaten here, and the page says why from the base case's numbers
    notes = " ".join(e.text for e in driver.find_elements(By.CSS_SELECTOR, "p.oracle-note"))
    assert "base case two_link_switching" in notes and "it is no bound" in notes
    assert driver.save_screenshot(str(tmp_path / "motors.png"))
    assert _console_errors(driver) == []


def test_start_up_transient_does_not_set_the_torque_axis(reports, driver):
    """Issue 35 item 2: k_v = 3000 gives a ~4,300 N m torque at t = 0 on two_link_switching; it is drawn
    in the first-second panel, and the whole-run panel's axis comes from t >= 1 s."""
    driver.get((reports / "two_link_switching" / "index.html").as_uri())
    _wait_drawn(driver)
    first = _trace_values(driver, "plot-torques", "y")
    lay = driver.execute_script("return document.getElementById('plot-torques').layout")
    lo, hi = lay["yaxis2"]["range"]
    assert max(abs(v) for v in first) > 1000.0  # the start-up spike, in its own panel
    assert max(abs(lo), abs(hi)) < 0.2 * max(abs(v) for v in first)


def test_a_page_copied_alone_draws_its_figures(reports, driver, tmp_path):
    """Issue 35 item 9: plotly.js is inlined (gzip, base64) in every case page, so the page alone works."""
    from selenium.webdriver.common.by import By

    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(reports / "two_link_intermittent" / "index.html", alone / "page.html")
    driver.get((alone / "page.html").as_uri())
    _wait_drawn(driver)
    figs = driver.find_elements(By.CSS_SELECTOR, "div.plotly-fig")
    assert len(figs) >= 4
    for f in figs:
        assert f.find_elements(By.CSS_SELECTOR, "svg.main-svg"), f.get_attribute("id")
    assert "not drawn" not in driver.find_element(By.TAG_NAME, "body").text
    assert _console_errors(driver) == []


def test_print_to_pdf_is_a_clean_document(reports, driver, tmp_path):
    """Issue 35 item 9: the browser's print (headless Chromium's print to PDF) gives a document without
    the controls, with the figures fitted to the paper."""
    import base64
    import re
    import subprocess

    from selenium.webdriver.common.print_page_options import PrintOptions

    driver.get((reports / "two_link_switching_motors" / "index.html").as_uri())
    _wait_drawn(driver)
    opts = PrintOptions()
    opts.page_width, opts.page_height = 21.0, 29.7  # A4 [cm]
    driver.execute_script("ftcPrint(true)")  # what the browser's beforeprint does
    pdf = base64.b64decode(driver.print_page(opts))
    driver.execute_script("ftcPrint(false)")
    path = tmp_path / "page.pdf"
    path.write_bytes(pdf)
    assert pdf.startswith(b"%PDF")
    pages = len(re.findall(rb"/Type\s*/Page[^s]", pdf))
    assert 5 <= pages <= 60, pages
    widths = driver.execute_script(
        "ftcPrint(true); var w = Array.prototype.map.call(document.querySelectorAll('div.plotly-fig'),"
        " function (d) { return d.layout.width; }); ftcPrint(false); return w;"
    )
    assert widths and all(w == 680 for w in widths)  # fitted to the paper's width (A4, 12 mm margins)
    if shutil.which("pdftotext"):
        text = subprocess.run(["pdftotext", str(path), "-"], capture_output=True, text=True, check=True).stdout
        assert "Verdict" in text and "Fault timeline" in text and "Provenance" in text
        assert "Robots and links to scale" not in text and "all cases" not in text  # no replay, no navigation
        assert "The replay (an animation) is in the HTML page." in text


def test_campaign_sample_page(driver, tmp_path):
    """Issue 35 item 7: a failing campaign sample opens from the campaign's table as its own page (its
    replay and signals)."""
    import tomllib

    from selenium.webdriver.common.by import By

    from ftcreport.cases import parse_case
    from ftcreport.report.campaign import render_campaign
    from ftcreport.studies.campaign import read_table, run_campaign

    data = tomllib.loads((CASES / "two_link_campaign.toml").read_text())
    data["simulation"]["duration"] = 8.0
    data["campaign"]["fault_time"] = [2.0, 5.0]
    data["campaign"]["success"] = {"position_error_final": {"max": 1e-9}}  # every sample fails
    base = parse_case(data, "campaign_pages")
    out = tmp_path / "campaign"
    res = run_campaign(base, 2, out, seed=3, schemes=["nominal", "oracle"], in_process=True, show_progress=False)
    render_campaign(out, read_table(res.table), worst=1)
    driver.get((out / "index.html").as_uri())
    link = driver.find_element(By.CSS_SELECTOR, "#failing-samples a")
    assert driver.find_element(By.ID, "matrix-success").is_displayed()
    link.click()
    assert "/sample_pages/sample-" in driver.current_url
    _wait_drawn(driver)
    assert driver.find_element(By.ID, "replay").is_displayed()
    assert len(driver.find_elements(By.CSS_SELECTOR, "#replay canvas")) == 2
    assert driver.find_elements(By.CSS_SELECTOR, "#plot-errors svg.main-svg")
    assert "campaign" in driver.find_element(By.CSS_SELECTOR, "nav a").text
    assert _console_errors(driver) == []
