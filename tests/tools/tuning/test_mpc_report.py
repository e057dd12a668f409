"""docs/firmware.md's generated MPC section (tools/docs/mpc_report.py): the markers are there,
the writer (benchfuncs.write_section) replaces only what lies between them, and the section's verdicts follow from its own
numbers (the run itself is python -m tools.docs.mpc_report --doc docs/firmware.md, ~40 s)."""

from __future__ import annotations

import re
from pathlib import Path

from tools.validation.doc_compare import write_section
from tools.docs.mpc_report import BEGIN, COMMAND, END, HOLD_BAND_C

DOC = Path(__file__).resolve().parents[3] / "docs" / "firmware.md"
ROW = re.compile(r"^\| (\d) \| (PID|MPC)[^|]* \| ([\d.]+) \| [^|]* \| ([^|]*) \| [^|]* \| (yes|no) \|$", re.M)


def test_the_writer_keeps_the_markers_and_the_rest(tmp_path):
    path = tmp_path / "doc.md"
    path.write_text(f"intro\n{BEGIN} (x) -->\nold\n{END}\nafter\n")
    write_section(path, "new body\n", BEGIN, END)
    assert path.read_text() == f"intro\n{BEGIN} (x) -->\nnew body\n{END}\nafter\n"


def test_the_sections_verdicts_follow_from_its_numbers():
    text = DOC.read_text()
    section = text[text.index(BEGIN):text.index(END)]
    assert f"Written by `{COMMAND}`." in section
    rows = ROW.findall(section)
    assert len(rows) == 6, rows  # per noise level: PID by M303, MPC by M306 T, MPC by twin-tune
    for _, _, _, hold, verdict in rows:
        if hold.startswith("halted"):
            assert verdict == "no"
            continue
        low, high = (float(x) for x in hold.split(".."))
        assert verdict == ("yes" if max(abs(low), abs(high)) <= HOLD_BAND_C else "no")
    for noise in ("0", "1"):  # the report's first criterion, as the doc states it: every MPC row below PID's
        pid = [float(value) for n, firmware, value, _, _ in rows if n == noise and firmware == "PID"]
        mpc = [float(value) for n, firmware, value, _, _ in rows if n == noise and firmware == "MPC"]
        assert len(pid) == 1 and len(mpc) == 2 and max(mpc) < pid[0]
