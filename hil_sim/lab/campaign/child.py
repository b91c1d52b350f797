"""One campaign mission in its own process: ``python -m hil_sim.lab.campaign.child RESULT.json
PARENT_PID`` with the mission (JSON) on stdin. Always writes a row: the mission's results, or
``error`` with the exception when it raised (the parent records kills and timeouts).

The mission dies with its parent (a campaign worker, local or Dask): the kernel sends it
SIGTERM when the parent exits (``PR_SET_PDEATHSIG``, Linux), or it finds at start that the
parent is already gone; either way it removes its temporary folder (RESULT.json's, which the
parent made) and exits 143, so a killed worker leaves no mission running twice and no folder
behind.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import signal
import sys
import time
import traceback
from pathlib import Path
from typing import Any

TMP_PREFIX = "safer-campaign-"  # the folders run_isolated makes (the only ones an orphan removes)


def run_row(m: dict[str, Any]) -> dict[str, Any]:
    """Run the mission in this process; an exception becomes an ``error`` row."""
    from hil_sim.lab.campaign.table import failed_row, result_row

    t0 = time.perf_counter()
    try:
        from fsw.framework.params import build
        from hil_sim.faults import FaultSpec
        from hil_sim.mission.mission_run import RunSpec, run_mission

        faults = tuple(build(FaultSpec, f, source=m["id"]) for f in m["faults"])
        spec = RunSpec(
            scenario=m["scenario"], method=m["method"], steps=m["steps"], seed=m["seed"], config=m["config"],
            transmit=m["transmit"], out=None, faults=faults, safe_recover_s=m["safe_recover_s"],
        )
        summary = run_mission(spec, max_sim_s=m["max_sim_s"] or None)
    except Exception as exc:  # noqa: BLE001 - a failed mission is a recorded outcome
        tb = traceback.extract_tb(exc.__traceback__)
        where = f" at {Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else ""
        return failed_row(m, "error", f"{type(exc).__name__}: {exc}{where}", time.perf_counter() - t0)
    return result_row(m, summary)


PR_SET_PDEATHSIG = 1
ORPHAN_EXIT = 128 + signal.SIGTERM


def die_with_parent(parent_pid: int, folder: Path) -> None:
    """SIGTERM this process when its parent exits; on that signal (or a parent already gone)
    remove ``folder`` and exit ``ORPHAN_EXIT``."""

    def _orphaned(*_: object) -> None:
        shutil.rmtree(folder, ignore_errors=True)
        os._exit(ORPHAN_EXIT)

    signal.signal(signal.SIGTERM, _orphaned)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: only the start-up check below
        pass
    if os.getppid() != parent_pid:  # the parent died before the request took effect
        _orphaned()


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1].endswith(".json") and Path(sys.argv[1]).parent.name.startswith(TMP_PREFIX):
        die_with_parent(int(sys.argv[2]), Path(sys.argv[1]).parent)
    m = json.loads(sys.stdin.read())
    row = run_row(m)
    out = Path(sys.argv[1])
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(row))
    os.replace(tmp, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
