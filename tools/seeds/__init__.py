"""Seed papers re-run: one module per seed, reproductions as library functions."""
