"""The twin against real hardware: comparisons, plant checks, the golden transcript (tools/docs/validation.py writes
the validation page)."""
