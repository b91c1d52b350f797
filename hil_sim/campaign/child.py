"""One campaign mission in its own process: ``python -m hil_sim.campaign.child RESULT.json``
with the mission (JSON) on stdin. Always writes a row: the mission's results, or ``error``
with the exception when it raised (the parent records kills and timeouts)."""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any


def run_row(m: dict[str, Any]) -> dict[str, Any]:
    """Run the mission in this process; an exception becomes an ``error`` row."""
    from hil_sim.campaign.table import failed_row, result_row

    t0 = time.perf_counter()
    try:
        from fsw.framework.params import build
        from hil_sim.faults import FaultSpec
        from hil_sim.mission_run import RunSpec, run_mission

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


def main() -> int:
    m = json.loads(sys.stdin.read())
    row = run_row(m)
    out = Path(sys.argv[1])
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(row))
    os.replace(tmp, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
