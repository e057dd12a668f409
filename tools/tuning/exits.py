"""The exit status of twin-tune and twin-fit, and what each means: light (no tuning layer), so that a
command's ``--help`` prints them without importing numba or scipy."""

from __future__ import annotations

from tools.entry import INTERNAL_STATUS_HELP

EXIT_ANSWER = 0
EXIT_UNSAFE = 1
EXIT_NO_MODEL = 3
EXIT_CODES = """exit status:
  0  a verdict: new gains that beat yours on every plant the log allows, or keep your gains and why
     (also where the twin cannot model the heater well enough to beat them: no plant both fits the log
     and replays it, or your gains trip on one)
  1  no safe answer where your gains are not known: the firmware's autotune on the twin trips on some
     plant and nothing tried beats it (the report says where)
  2  bad input (an option, a log that cannot be read or fitted, a controller), said in one line
  3  neither a model nor a reference: no plant both fits the log and replays it, and it states no gains
     (--current-gains gives them)
""" + INTERNAL_STATUS_HELP + "\n"
