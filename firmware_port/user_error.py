"""The error of a user's input, below every package so that each raises it: twin's checks of values
(twin/limits.py) and firmware_port's check of a user's lane law (firmware_port/law_check.py)."""


class UserError(ValueError):
    """A value a user gave (a flag, a file, a scenario, a capture, an argument, a lane law) that the twin cannot
    use. A command line says it in one line and exits 2 (tools/entry.py); any other exception there is a bug."""
