"""The user-facing tools: CLIs, tuning, identification, log parsers, plots, benchmarks."""
