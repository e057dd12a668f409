"""The figures the CLIs write: twin-tune's (tune_figure.py) and twin-compare's (compare_figure.py), and the marks
they share (marks.py). matplotlib is the ``plot`` extra: imported when a figure is drawn, not before."""
