"""The twin against real hardware: comparisons, plant checks, the generated validation page, the golden transcript."""
