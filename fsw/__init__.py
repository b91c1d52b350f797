"""MIT-SAFER flight software for the RECON-bot."""

import os

# A cyclic executive wants single-threaded BLAS: OpenBLAS threads spin on a busy machine and
# turn a 0.3 ms matrix product into 20 ms (measured, docs/nbv.md). Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
