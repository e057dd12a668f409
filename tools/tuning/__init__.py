"""Tuning: one gains type with explicit scales, tuning rules as pure functions of a model,
objectives, and optimisers that evaluate candidates on the firmware twin."""
