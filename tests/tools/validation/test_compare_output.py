"""twin-compare's output on the other kinds of log: every line within 120 columns, rows labelled,
the summary counting out-of-sample rows only (tools/cli/compare.py, tools/validation/tables.py)."""

import pytest

from tools.cli import compare as compare_cli
from tools.validation.tables import text_tables


@pytest.mark.slow
@pytest.mark.parametrize("name, counted", [("klippy_stats_chesleavens_cartesian_stm32f103.csv", 4),
                                           ("klipper_heattest_onionheater_heattest_200.csv", 2)])
def test_twin_compare_fits_in_120_columns(capsys, name, counted, hardware_logs):
    assert compare_cli.main([str(hardware_logs / name)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(len(line) for line in lines) <= 120
    assert lines[-1].startswith("summary: ") and f"/{counted} out-of-sample rows" in lines[-1]


def test_text_tables_split_wide_tables_repeating_the_key():
    columns = ["heater", *(f"column {i}" for i in range(12))]
    rows = [["extruder", *("x" * 14 for _ in range(12))], ["heater_bed", *("y" * 3 for _ in range(12))]]
    out = text_tables(columns, rows, width=60)
    assert max(len(line) for line in out) <= 60
    headers = [line for line in out if line.startswith("heater ")]
    assert len(headers) > 1  # split into several tables, each led by the key column
    assert sum(line.count("column") for line in headers) == 12 and sum(line.startswith("extruder") for line in out) \
        == len(headers)
