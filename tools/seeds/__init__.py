"""Reproductions of the seed papers: one module per paper (seed002_benchmark.py holds seed 002's
benchmark), each with ``report(budget, progress)`` returning every printed number beside ours with a
verdict (report.py), and evidence where a printed number cannot be right. ``python -m tools.seeds
000`` prints one paper's report; ``python -m tools.seeds`` writes docs/seeds.md (tools/docs/seeds_page.py)."""
