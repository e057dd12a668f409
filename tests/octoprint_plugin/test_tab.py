"""The Heater tuning tab in a real browser: OctoPrint with the plugin, twin-serial's stock printer, headless
Chromium (Debian's chromium and chromium-driver) driven by selenium, and the real twin-tune.

As a user would: the tab refuses to start before the printer is connected and says why in one line; a
capture without autotune output is twin-tune's one-line error; connected, it runs M303, tunes the capture,
shows the answer; Apply stores it, and the printer (M501 then M503 through OctoPrint's terminal) holds what
the tab showed; a second autotune right after says "keep your gains". Screenshots go to
twin-out/octoprint/ (the CI's artefacts); with HEATER_TWIN_WRITE_DOCS=1 also to docs/octoprint/.

CI cost: one OctoPrint start, two autotunes of under a second each at --speed max, two tunes by twin-tune.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
from pathlib import Path

import pytest

from tests.conftest import unavailable
from tests.helpers.octoprint_server import start_octoprint, twin_printer

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
ARTEFACTS = ROOT / "twin-out" / "octoprint"
DOCS = ROOT / "docs" / "octoprint"
WRITE_DOCS = os.environ.get("HEATER_TWIN_WRITE_DOCS") == "1"
USER = ("heater", "twin-tune-in-octoprint")
IDLE_SPEED = 50  # the printer's clock while OctoPrint waits: the hotend cools between the two autotunes
PAGE_TIMEOUT_S = 600  # OctoPrint's page loads its assets, the tab's requests come back
TUNE_TIMEOUT_S = 1800  # twin-tune on a loaded 2-core machine
WINDOW = "1280,2200"  # tall enough for the answer with its proof table and plot in one screenshot
# Chromium without a network, a profile or anything that phones home.
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-dev-shm-usage", f"--window-size={WINDOW}"]
NOT_CONNECTED = "The printer is not connected (Offline): connect it first"
M301_RE = re.compile(r"M301(?: E0)? P([-\d.]+) I([-\d.]+) D([-\d.]+)")
M503_DIGIT_C = 0.005  # M503 prints gains to two decimals: what it reads is within half a digit of what was sent
GAIN_DIGITS_REL = 5e-4  # the tab shows gains to 4 significant digits: within half a unit of the 4th


@pytest.fixture
def browser(tmp_path, monkeypatch):
    """Headless Chromium under chromedriver, a fresh profile in tmp_path; always quit."""
    chromium, chromedriver = shutil.which("chromium"), shutil.which("chromedriver")
    if not (chromium and chromedriver):
        unavailable("headless Chromium is not installed: apt-get install chromium chromium-driver (.ci/run does)")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        unavailable("selenium is not installed: pip install -e '.[browser]' (.ci/run does)")
    monkeypatch.setenv("SE_OFFLINE", "true")  # selenium's driver manager: use the drivers given, fetch nothing
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for flag in CHROMIUM_FLAGS + [f"--user-data-dir={tmp_path / 'chromium'}"]:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(chromedriver, log_output=str(tmp_path / "chromedriver.log")),
                              options=options)
    yield driver
    driver.quit()


@pytest.fixture
def octoprint(tmp_path, spawn):
    """OctoPrint with the plugin (installed with the package), a user to log in as, and the printer's link."""
    with twin_printer(tmp_path, spawn, IDLE_SPEED) as link:
        server = start_octoprint(tmp_path, link, spawn)
        server.add_user(*USER)
        yield server, link


class Tab:
    """The Heater tuning tab in the browser, as a user sees and clicks it."""

    def __init__(self, driver, base: str):
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support import expected_conditions
        from selenium.webdriver.support.ui import WebDriverWait

        self.driver, self.base, self.by, self.ec = driver, base, By, expected_conditions
        self.wait = lambda timeout_s: WebDriverWait(driver, timeout_s)

    def open(self) -> None:
        """Log in, then choose the tab (in OctoPrint's overflow menu: the core tabs fill the bar)."""
        by, ec = self.by, self.ec
        self.driver.get(self.base)
        self.wait(PAGE_TIMEOUT_S).until(ec.visibility_of_element_located((by.ID, "login-user"))).send_keys(USER[0])
        self.driver.find_element(by.ID, "login-password").send_keys(USER[1] + "\n")
        self.wait(PAGE_TIMEOUT_S).until(ec.element_to_be_clickable((by.CSS_SELECTOR, "#tabs .dropdown-toggle"))).click()
        self.wait(PAGE_TIMEOUT_S).until(ec.element_to_be_clickable(
            (by.CSS_SELECTOR, 'a[href="#tab_plugin_heater_twin"]'))).click()
        self.wait(PAGE_TIMEOUT_S).until(ec.element_to_be_clickable((by.ID, "heater_twin_start")))

    def element(self, element_id: str):
        return self.driver.find_element(self.by.ID, element_id)

    def text(self, element_id: str) -> str:
        return self.element(element_id).text.strip()

    def click(self, element_id: str) -> None:
        self.wait(PAGE_TIMEOUT_S).until(self.ec.element_to_be_clickable((self.by.ID, element_id))).click()

    def error(self) -> str:
        """The tab's one-line error, once it shows."""
        self.wait(TUNE_TIMEOUT_S).until(self.ec.visibility_of_element_located((self.by.ID, "heater_twin_error")))
        return self.text("heater_twin_error")

    def run(self) -> str:
        return self.element("heater_twin_answer").get_attribute("data-run") or ""

    def answer(self, after_run: str) -> str:
        """Wait for the answer of a run other than ``after_run``; the verdict. Fails on the tab's error."""
        def shown(driver) -> bool:
            error = self.element("heater_twin_error")
            assert not error.is_displayed(), f"the tab says: {error.text}"
            answer = self.element("heater_twin_answer")
            return answer.is_displayed() and self.run() != after_run and self.element("heater_twin_verdict").text

        self.wait(TUNE_TIMEOUT_S).until(shown)
        return self.text("heater_twin_verdict")

    def paste(self, text: str) -> str:
        """Tune a pasted capture; the tab's error (then the paste box is folded again)."""
        fold = self.driver.find_element(self.by.CSS_SELECTOR, ".heater-twin-paste summary")
        fold.click()
        self.element("heater_twin_paste_text").send_keys(text)
        self.click("heater_twin_paste")
        error = self.error()
        fold.click()
        return error

    def shot(self, name: str, element_id: str | None = None) -> None:
        """A screenshot of the window (or of one element) into the artefacts, and docs/ when asked."""
        ARTEFACTS.mkdir(parents=True, exist_ok=True)
        path = ARTEFACTS / f"{name}.png"
        if element_id is None:
            self.driver.save_screenshot(str(path))
        else:
            self.element(element_id).screenshot(str(path))
        if WRITE_DOCS:
            DOCS.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, DOCS / path.name)

    def settings(self, cycles: int) -> None:
        """On the plugin's settings page (photographed), set the cycles and save."""
        by, ec = self.by, self.ec
        self.click("navbar_show_settings")
        self.wait(PAGE_TIMEOUT_S).until(ec.element_to_be_clickable(
            (by.CSS_SELECTOR, 'a[href="#settings_plugin_heater_twin"]'))).click()
        field = self.wait(PAGE_TIMEOUT_S).until(ec.visibility_of_element_located((by.ID, "heater_twin_settings_cycles")))
        self.shot("settings", "settings_dialog")
        field.clear()
        field.send_keys(str(cycles))
        self.wait(PAGE_TIMEOUT_S).until(ec.element_to_be_clickable(
            (by.CSS_SELECTOR, '#settings_dialog [data-test-id="settings-save"]'))).click()
        self.wait(PAGE_TIMEOUT_S).until(ec.invisibility_of_element_located((by.ID, "settings_dialog")))


def gains(text: str) -> tuple[float, float, float]:
    m = M301_RE.search(text)
    assert m, f"no M301 gains in {text!r}"
    return float(m[1]), float(m[2]), float(m[3])


def stored_gains(server) -> tuple[float, float, float]:
    """The hotend's gains as the printer reports them after reloading its EEPROM: M501, then M503, sent from
    OctoPrint's terminal and read back through its push API."""
    def replied(lines: list[str]) -> bool:
        after = lines[lines.index("Send: M503"):] if "Send: M503" in lines else []
        return any(M301_RE.search(line) for line in after) and any(line.startswith("Recv: ok") for line in after)

    lines = server.terminal(["M501", "M503"], replied, USER)
    assert "Recv: echo:Hardcoded Default Settings Loaded" not in lines, "M501 found no stored settings"
    return gains("\n".join(lines[lines.index("Send: M503"):]))


def check_plot(tab: Tab) -> None:
    """The answer's plot where OctoPrint's environment has matplotlib (the octoprint extra brings it); without
    it (.ci/run's octoprint job runs this test again after uninstalling it), no plot and the line saying why."""
    from octoprint_heater_twin.tuner import NO_MATPLOTLIB

    plot, no_plot = tab.element("heater_twin_plot"), tab.element("heater_twin_no_plot")
    if importlib.util.find_spec("matplotlib") is not None:
        assert plot.get_attribute("naturalWidth") not in (None, "0"), "the plot did not load"
        assert not no_plot.is_displayed(), no_plot.text
    else:
        assert not plot.is_displayed() and tab.text("heater_twin_no_plot") == NO_MATPLOTLIB


def test_the_tab_tunes_the_printer_and_the_printer_holds_the_answer(octoprint, browser):
    server, link = octoprint
    tab = Tab(browser, server.base + "/")
    tab.open()
    tab.click("heater_twin_start")
    assert tab.error() == NOT_CONNECTED
    tab.shot("refused", "tab_plugin_heater_twin")

    error = tab.paste("Send: M303 E0 S210 C8\nRecv: PID Autotune start\nRecv: ok\n")
    assert "no autotune output" in error and "\n" not in error

    server.connect(link)
    tab.click("heater_twin_start")
    assert tab.answer(after_run="") == "New gains", tab.text("heater_twin_why")
    tab.shot("answer")
    check_plot(tab)
    shown = gains(tab.text("heater_twin_commands"))

    tab.click("heater_twin_apply")
    tab.wait(PAGE_TIMEOUT_S).until(tab.ec.visibility_of_element_located((tab.by.ID, "heater_twin_applied")))
    assert tab.text("heater_twin_applied").startswith("The printer holds the new gains: M301 ")
    tab.shot("applied", "heater_twin_answer")
    stored = stored_gains(server)
    assert all(abs(s - g) <= M503_DIGIT_C + 1e-9 for s, g in zip(stored, shown)), (stored, shown)

    first = tab.run()
    tab.click("heater_twin_start")
    verdict = tab.answer(after_run=first)
    tab.shot("second-run", "tab_plugin_heater_twin")
    # The second run: "keep your gains", or new gains with the one line why (the second capture may allow
    # other plants than the first); either way against the gains the printer now holds.
    assert verdict in ("Keep your gains", "New gains") and tab.text("heater_twin_why"), verdict
    yours = [float(tab.text(f"heater_twin_current_{k}")) for k in ("kp", "ki", "kd")]
    assert yours == pytest.approx(stored, rel=GAIN_DIGITS_REL), "the second run did not start from the stored gains"
    tab.settings(cycles=5)
    tab.wait(PAGE_TIMEOUT_S).until(lambda driver: tab.text("heater_twin_m303") == "M303 E0 S210 C5")
