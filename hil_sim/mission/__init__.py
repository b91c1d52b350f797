"""A lockstep mission on the bench: what a run is (``run_spec``), running it (``mission_run``), its summary and figures
(``mission_report``), its run directory and the bench's part of a checkpoint (``run_dir``,
``resume_state``) and the bench-side watch of a mission on unfamiliar ground (``ground_watch``)."""
