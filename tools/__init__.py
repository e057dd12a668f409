"""The user-facing tools: CLIs, tuning, identification, log parsers, plots, benchmarks."""

import os

# The twin's matrices are 2x2 to 5x5: OpenBLAS's threads only cost there (on a busy 2-core machine a 4x4
# expm took 60 ms with them, 0.05 ms without). Read when numpy loads; a value the user set stays.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
