"""python -m tools.klipper_host.example_configs: a config the twin cannot serve is its one-line refusal, and the
counts say how far the served ones got (no klippy: the sessions are replaced by their outcomes)."""

from __future__ import annotations

from tools.klipper_host import example_configs
from protocol.klipper_mcu.dictionary import CHIPS
from tests.klipper_mcu.test_user_config import ENDER3


def test_a_refused_config_is_its_reason(tmp_path):
    path = tmp_path / "printer-stm32.cfg"
    path.write_text(ENDER3.replace("atmega1284p", "sam4e8e"))
    assert example_configs.run_config(path, 10.0) == (
        "refused", f"the twin cannot serve an MCU compiled for sam4e8e; it serves {', '.join(CHIPS)}")


def test_the_counts_say_how_far_the_served_configs_got(tmp_path, monkeypatch, capsys):
    outcomes = {"a.cfg": ("refused", "no"), "b.cfg": ("heat", ""), "c.cfg": ("ready", "No trigger on x"),
                "d.cfg": ("home", "not heating"), "e.cfg": ("failed", "Unknown command")}
    monkeypatch.setattr(example_configs, "config_folder", lambda: tmp_path)
    monkeypatch.setattr(example_configs, "run_config", lambda path, speed: outcomes[path.name])
    assert example_configs.main(list(outcomes)) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2] == "c.cfg: ready: No trigger on x"
    assert lines[-1] == "5 configs: 1 refused, 4 served; of those 3 reached ready, 2 reached home, 1 reached heat (at 10 x)"


def test_klippys_exception_is_named(tmp_path):
    log = tmp_path / "klippy.log"
    assert example_configs.klippy_exception(log) == ""
    log.write_text("Start\nTraceback (most recent call last):\n  File \"x.py\", line 1, in f\n    g()\n"
                   "TypeError: initializer for ctype 'struct serialqueue *' must be a cdata pointer\nmore\n")
    assert example_configs.klippy_exception(log) == (
        " [klippy.log: TypeError: initializer for ctype 'struct serialqueue *' must be a cdata pointer]")
