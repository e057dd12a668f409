"""The Heater tuning tab in a real browser: OctoPrint with the plugin, twin-serial's stock printer, headless
Chromium (Debian's chromium and chromium-driver) driven by selenium, and the real twin-tune.

As a user would: the tab refuses to start before the printer is connected and says why in one line; a
capture without autotune output is twin-tune's one-line error; connected, it runs M303 and draws it live with
its cycles done, follows the whole run on one bar in a user's words, folds Marlin's lines away once the twin
is asked, shows the answer; the answer's gains edited are checked on the twin, and Apply stores the edit, which
the printer (M501 then M503 through OctoPrint's terminal) holds; a second autotune right after compares
against them. Screenshots go to twin-out/octoprint/ (the CI's artefacts); with HEATER_TWIN_WRITE_DOCS=1 also
to docs/octoprint/.

CI cost: one OctoPrint start, two autotunes of about half a minute each at --speed 10 (slow enough to watch the
graph and the cycles mid-run), two tunes and a quick proof by twin-tune.
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
AUTOTUNE_SPEED = "10"  # M303 at 10 x real time: its cycles end every 2 s or so, the tab is watched mid-run
INTERNAL_STEPS = ("fitting the structures", "profiling what the log leaves open", "replaying the log", "searching (")
EDIT_KD = 1.1  # the edit: the answer's Kd 10 % higher (a change any answer takes without a trip)
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
    with twin_printer(tmp_path, spawn, IDLE_SPEED, AUTOTUNE_SPEED) as link:
        server = start_octoprint(tmp_path, link, spawn)
        server.add_user(*USER)
        yield server, link


class Tab:
    """The Heater tuning tab in the browser, as a user sees and clicks it."""

    def __init__(self, driver, base: str):
        from selenium.common.exceptions import StaleElementReferenceException
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support import expected_conditions
        from selenium.webdriver.support.ui import WebDriverWait

        self.driver, self.base, self.by, self.ec = driver, base, By, expected_conditions
        # the live graph's elements are redrawn as readings come: one found may be gone when read
        self.wait = lambda timeout_s: WebDriverWait(driver, timeout_s,
                                                    ignored_exceptions=[StaleElementReferenceException])

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

    def answer(self, after_run: str, bar: list[tuple[int, str]] | None = None) -> str:
        """Wait for the answer of a run other than ``after_run``; the verdict. Fails on the tab's error. The bar's
        (percent, words) as seen on the way go to ``bar``."""
        def shown(driver) -> bool:
            error = self.element("heater_twin_error")
            assert not error.is_displayed(), f"the tab says: {error.text}"
            if bar is not None:
                bar.append(self.bar())
            answer = self.element("heater_twin_answer")
            return answer.is_displayed() and self.run() != after_run and self.element("heater_twin_verdict").text

        self.wait(TUNE_TIMEOUT_S).until(shown)
        return self.text("heater_twin_verdict")

    def bar(self) -> tuple[int, str]:
        """The run's bar as shown: (percent, its words), (-1, '') when hidden. Read in one script, so the page
        cannot change between its visibility, its percent and its words (three WebDriver calls raced the run's end:
        the bar seen shown, then its percent read as 0 after the answer had hidden it)."""
        shown = self.driver.execute_script(
            "var bar = document.getElementById('heater_twin_progress');"
            "if (!bar.offsetParent) return null;"
            "return [bar.getAttribute('data-percent'), document.getElementById('heater_twin_step').innerText.trim()];"
        )
        if shown is None:
            return -1, ""
        return int(shown[0]), shown[1]

    def mid_autotune(self) -> tuple[int, int]:
        """Wait until M303 is under way, its graph drawn and some but not all of its cycles done; (cycles done,
        readings drawn)."""
        def under_way(driver):
            cycles = re.fullmatch(r"(\d+) of (\d+) cycles done", self.text("heater_twin_cycles_done"))
            points = int(self.element("heater_twin_graph").get_attribute("data-points") or 0)
            if cycles and 0 < int(cycles[1]) < int(cycles[2]) and points and self.text("heater_twin_busy"):
                return int(cycles[1]), points
            return False

        return self.wait(TUNE_TIMEOUT_S).until(under_way)

    def edit(self, field: str, value: str) -> None:
        box = self.element(f"heater_twin_edit_{field}")
        box.clear()
        box.send_keys(value)

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
        from tools.plots.tab_figure import WIDTH_PX

        # the compact figure, made for the tab's width; twin-tune's full one a click away
        assert plot.get_attribute("naturalWidth") == str(WIDTH_PX), "the compact figure did not load"
        assert tab.element("heater_twin_plot_full").get_attribute("href").endswith(f"?plot={tab.run()}")
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
    # M303 live: its readings drawn, its cycles counted, on the run's one bar; Marlin's lines open below
    done, points = tab.mid_autotune()
    percent, words = tab.bar()
    assert words.startswith(f"Your printer's autotune (M303 E0 S210 C8): {done} of 8 cycles done"), words
    assert 0 < percent < 100 and points > done
    assert tab.element("heater_twin_console_fold").get_attribute("open") is not None
    tab.shot("autotune", "tab_plugin_heater_twin")
    later, _ = tab.mid_autotune()
    assert later >= done

    bar: list[tuple[int, str]] = []
    assert tab.answer(after_run="", bar=bar) == "New gains", tab.text("heater_twin_why")
    shown = [(p, w) for p, w in bar if p >= 0]
    assert [p for p, _ in shown] == sorted(p for p, _ in shown), shown  # one bar: it never restarts
    assert any(w.startswith("The twin: ") for _, w in shown), shown
    assert not [w for _, w in shown if any(step in w for step in INTERNAL_STEPS)], shown
    # the twin asked: Marlin's lines (its own #define gains) folded away, the whole autotune on the graph
    assert tab.element("heater_twin_console_fold").get_attribute("open") is None
    assert not tab.element("heater_twin_console").is_displayed()
    assert tab.text("heater_twin_cycles_done") == "8 of 8 cycles done"
    tab.shot("answer")
    check_plot(tab)

    answer = gains(tab.text("heater_twin_commands"))
    edited_kd = f"{answer[2] * EDIT_KD:.2f}"
    tab.edit("kd", edited_kd)
    assert not tab.element("heater_twin_apply").is_enabled(), "Apply took an edit the twin had not checked"
    tab.click("heater_twin_check")
    tab.wait(TUNE_TIMEOUT_S).until(tab.ec.visibility_of_element_located((tab.by.ID, "heater_twin_checked")))
    said = tab.text("heater_twin_checked")
    assert f"D{float(edited_kd):g} never trips on the " in said and "worst overshoot" in said, said
    shown_gains = gains(tab.text("heater_twin_commands"))
    assert shown_gains == (answer[0], answer[1], float(edited_kd))
    tab.shot("checked", "heater_twin_answer")

    tab.click("heater_twin_apply")
    tab.wait(PAGE_TIMEOUT_S).until(tab.ec.visibility_of_element_located((tab.by.ID, "heater_twin_applied")))
    assert tab.text("heater_twin_applied").startswith("The printer holds the new gains: M301 ")
    tab.shot("applied", "heater_twin_answer")
    stored = stored_gains(server)
    assert all(abs(s - g) <= M503_DIGIT_C + 1e-9 for s, g in zip(stored, shown_gains)), (stored, shown_gains)

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
