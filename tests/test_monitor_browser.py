"""The status page in a real browser: Debian's chromium, headless, driven by selenium through chromedriver.

``scripts/test.sh`` installs ``chromium`` and ``chromium-driver`` where they are missing and apt-get
exists; the tests skip, saying so, only where no browser can be had.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from monitorkit import DEMO_GUARDS, Watched, real_signals, running, sighup_with_threshold, wait_for, watched_daemon

pytestmark = pytest.mark.slow

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
if CHROMIUM is None or CHROMEDRIVER is None:
    pytest.skip("no chromium / chromedriver on this machine (scripts/test.sh installs them with apt-get where it can: "
                "apt-get install chromium chromium-driver)", allow_module_level=True)
# selenium is imported by the fixture and by until(), not here: importing it (~0.3 CPU-s) at collection
# would cost every pytest-xdist worker, and only the one running these tests needs it.


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """A headless chromium with a profile of its own, no network but loopback: one for the module's tests
    (starting chromium costs more CPU than a test), each test opening its own daemon's page."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    tmp_path = tmp_path_factory.mktemp("chromium")
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--no-first-run", f"--user-data-dir={tmp_path / 'chromium-profile'}"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)), options=options)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture
def page(tmp_path: Path, browser: Any) -> Iterator[tuple[Watched, Any]]:
    """The demo's daemon, its task running, and its status page open in the browser."""
    with watched_daemon(tmp_path) as w:
        wait_for("the task to run", lambda: running(w))
        browser.get(w.http + "/")
        try:
            yield w, browser
        finally:
            browser.get("about:blank")  # the next test's page starts from nothing of this one's


def until(driver: Any, condition: Callable[[Any], object], timeout_s: float = 10.0, poll_s: float = 0.5) -> None:
    """Wait until ``condition(driver)`` holds (selenium's WebDriverWait, polling every ``poll_s``)."""
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(driver, timeout_s, poll_frequency=poll_s).until(condition)


# The page redraws at each update: read it in one script call, never through element handles that go stale.
def text_of(driver: Any, element_id: str) -> str:
    """The text of the element with that id ('' while it is not on the page)."""
    return str(driver.execute_script("const e = document.getElementById(arguments[0]); return e ? e.textContent : '';",
                                     element_id))


def guards_shown(driver: Any) -> set[str]:
    """The guard names of the page's guard table."""
    return set(driver.execute_script("return [...document.querySelectorAll('tr.guard')].map(r => r.dataset.guard);"))


def threshold_shown(driver: Any, guard: str) -> str:
    """The threshold cell of a guard's row."""
    return str(driver.execute_script(
        "const r = document.querySelector(`tr.guard[data-guard='${arguments[0]}']`);"
        "return r ? r.cells[3].textContent : '';", guard))


def stop_reason_shown(driver: Any, watched: Watched) -> tuple[str, float]:
    """Trip PackCurrent; (the page's stop reason, ms from the stop to the page drawing it, by the page's clock)."""
    watched.trip()
    until(driver, lambda d: "PackCurrent" in text_of(d, "task-reason"), poll_s=0.05)
    after = driver.execute_script("return document.body.dataset.stopShownAfterMs")
    return text_of(driver, "task-reason"), float(after)


def test_page_renders_every_guard_of_the_demo_tree(page: tuple[Watched, Any]) -> None:
    """Every guard of the demo's tree has its row (value, threshold, heat), and the page fetched nothing external."""
    w, driver = page
    until(driver, lambda d: guards_shown(d) == set(DEMO_GUARDS))
    assert text_of(driver, "task-state") == "running"
    assert threshold_shown(driver, "PackCurrent") == "35.00 A"
    resources = driver.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert all(str(url).startswith(w.http) for url in resources)


def test_trip_shows_the_stop_reason_within_a_second(page: tuple[Watched, Any]) -> None:
    """An overcurrent frame puts the stop, its guard and its reason on the page within a second."""
    w, driver = page
    until(driver, lambda d: text_of(d, "task-state") == "running")
    reason, after_ms = stop_reason_shown(driver, w)
    assert after_ms < 1000.0  # the stop's time (the daemon's clock) to the page drawing it (the browser's)
    assert "overcurrent" in reason
    assert text_of(driver, "task-state") == "stopped"
    assert text_of(driver, "task-guards") == "PackCurrent"


def test_page_keeps_working_after_sighup_reload(tmp_path: Path, browser: Any) -> None:
    """After SIGHUP reloads a changed config, the open page shows the new threshold and still shows a stop."""
    with watched_daemon(tmp_path) as w, real_signals(w.daemon):  # the real SIGHUP path: the loop reloads
        wait_for("the task to run", lambda: running(w))
        browser.get(w.http + "/")
        until(browser, lambda d: guards_shown(d) == set(DEMO_GUARDS))
        sighup_with_threshold(w, tmp_path, "30.0")
        until(browser, lambda d: threshold_shown(d, "PackCurrent") == "30.00 A")
        assert "reload" in text_of(browser, "event-list")
        wait_for("the task to run again", lambda: running(w))
        until(browser, lambda d: text_of(d, "task-state") == "running")
        reason, after_ms = stop_reason_shown(browser, w)
        browser.get("about:blank")
        assert "threshold 30" in reason and after_ms < 1000.0
