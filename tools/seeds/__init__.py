"""Reproductions of the seed papers: one module per paper, ``reproduce()`` returning the paper's
printed numbers beside ours, and evidence where a printed number cannot be right."""
