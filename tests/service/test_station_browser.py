"""The operator station in a real browser: Debian's headless chromium, driven by selenium, against the
service running on simulated cameras (one service for the module; cycles ~3 s each on 640x512 images).

Set CELLCTL_SCREENSHOTS=DIR to also save a screenshot of each page there (docs/station.md uses them).
"""

from __future__ import annotations

import base64
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.service import Service as DriverService
from selenium.webdriver.common.by import By
from selenium.webdriver.remote.webdriver import WebDriver
from selenium.webdriver.support.ui import WebDriverWait

from tests.service.station_rig import TOKEN, StationService, write_station_config

pytestmark = pytest.mark.slow

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
WAIT_S = 120.0  # a cycle on the shared 2-core machine; the waits end as soon as the page shows it


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StationService]:
    service = StationService(write_station_config(tmp_path_factory.mktemp("station")))
    yield service
    service.stop()


@pytest.fixture(scope="module")
def browser() -> Iterator[WebDriver]:
    profile = tempfile.mkdtemp(prefix="cellctl-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={profile}",
        "--window-size=1440,1100",
    ):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=DriverService(CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def shot(driver: WebDriver, name: str) -> None:
    folder = os.environ.get("CELLCTL_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        height = int(driver.execute_script("return document.documentElement.scrollHeight"))
        clip = {"x": 0, "y": 0, "width": 1440, "height": min(height, 2400), "scale": 1}
        picture = driver.execute_cdp_cmd("Page.captureScreenshot", {"captureBeyondViewport": True, "clip": clip})
        (Path(folder) / f"station-{name}.png").write_bytes(base64.b64decode(picture["data"]))


def image_loaded(driver: WebDriver, element_id: str) -> bool:
    return bool(
        driver.execute_script(
            "const i = document.getElementById(arguments[0]); return !!i && i.complete && i.naturalWidth > 0;",
            element_id,
        )
    )


def test_a_cycle_appears_live_on_the_cell_page(cell: StationService, browser: WebDriver) -> None:
    browser.get(cell.url + "/")
    assert "READY" in browser.find_element(By.ID, "t-phase").text
    shown_before = browser.find_elements(By.ID, "last-result")
    reading = cell.cycle()  # the page is not reloaded: the result must arrive by itself
    WebDriverWait(browser, WAIT_S).until(
        lambda d: d.find_elements(By.CSS_SELECTOR, f"#last-result[data-cycle='{reading.cycle}']")
    )
    assert not shown_before or shown_before[0].get_attribute("data-cycle") != str(reading.cycle)
    result = browser.find_element(By.ID, "last-result")
    assert "PASS" in result.text and f"{reading.length_mm:.2f} mm" in result.text
    WebDriverWait(browser, WAIT_S).until(lambda d: image_loaded(d, "last-overlay"))
    WebDriverWait(browser, WAIT_S).until(lambda d: "READY" in d.find_element(By.ID, "t-phase").text)
    assert browser.find_element(By.ID, "t-cameras").text == "OK"
    shot(browser, "cell")


def test_a_failed_cycle_opens_its_pictures_from_the_history(cell: StationService, browser: WebDriver) -> None:
    reading = cell.failing_cycle()
    assert not reading.ok
    browser.get(cell.url + "/")
    WebDriverWait(browser, WAIT_S).until(
        lambda d: d.find_elements(By.CSS_SELECTOR, f"#last-result[data-cycle='{reading.cycle}']")
    )
    failed = browser.find_element(By.ID, "last-result")
    assert "FAIL" in failed.text and str(reading.error_code) in failed.text
    assert "Operator" in failed.text  # the operator's action from docs/modbus.md is shown
    shot(browser, "cell-failed")
    browser.get(cell.url + "/history?status=error")
    rows = browser.find_elements(By.CSS_SELECTOR, "table.history tbody tr")
    assert rows and all("FAIL" in row.text for row in rows)
    rows[0].find_element(By.CSS_SELECTOR, "a.pics").click()
    for picture in ("cycle-overlay", "cycle-left", "cycle-right"):
        WebDriverWait(browser, WAIT_S).until(lambda d, p=picture: image_loaded(d, p))
    assert f"cycle {reading.cycle}" in browser.find_element(By.CSS_SELECTOR, ".verdict").text
    shot(browser, "cycle-failed")


def test_actions_are_refused_without_the_token(cell: StationService, browser: WebDriver) -> None:
    browser.get(cell.url + "/cameras")
    WebDriverWait(browser, WAIT_S).until(lambda d: image_loaded(d, "live-left") and image_loaded(d, "live-right"))
    browser.find_element(By.ID, "token").clear()
    browser.find_element(By.ID, "capture").click()
    result = browser.find_element(By.ID, "action-result")
    WebDriverWait(browser, WAIT_S).until(lambda d: "refused" in result.text)
    assert not (cell.daemon.config.journal.state_dir / "captures").exists()
    box = browser.find_element(By.ID, "token")
    box.send_keys(TOKEN)
    browser.find_element(By.ID, "capture").click()
    WebDriverWait(browser, WAIT_S).until(lambda d: "saved pair" in result.text)
    assert (cell.daemon.config.journal.state_dir / "captures" / "left_00.png").is_file()
    WebDriverWait(browser, WAIT_S).until(lambda d: image_loaded(d, "capture-preview"))
    shot(browser, "cameras")


def test_the_calibration_page_shows_the_loaded_calibration(cell: StationService, browser: WebDriver) -> None:
    browser.get(cell.url + "/calibration")
    text = browser.find_element(By.TAG_NAME, "main").text
    assert "LOADED" in text and "640 × 512 px" in text
    shot(browser, "calibration")


def test_the_history_shows_every_cycle_with_trends(cell: StationService, browser: WebDriver) -> None:
    readings = [cell.cycle(), cell.cycle()]
    browser.get(cell.url + "/history")
    rows = browser.find_elements(By.CSS_SELECTOR, "table.history tbody tr")
    assert len(rows) >= 4 and any("FAIL" in r.text for r in rows) and any("PASS" in r.text for r in rows)
    assert f"{readings[-1].length_mm:.2f}" in rows[0].text  # newest first
    plots = browser.find_elements(By.CSS_SELECTOR, "svg.trend")
    assert [p.get_attribute("aria-label") for p in plots] == ["Length", "Heel height", "Toe height", "Cycle time"]
    assert all(p.find_elements(By.CSS_SELECTOR, "polyline") for p in plots)
    assert plots[0].find_elements(By.CSS_SELECTOR, "line.fail")  # the failed cycle is marked on the length axis
    shot(browser, "history")
