"""Monte-Carlo HIL campaigns (``safer-hil campaign``): many independent lockstep missions over
scenario families, methods, seeds and injected faults, run on a local process pool or a Dask
cluster, resumable, with one results table and a robustness report (docs/experiments.md)."""
