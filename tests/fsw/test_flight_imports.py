"""What the flight process imports (issue 15: its peak RSS must stay under 200 MB): a process
that builds the executive from the default config loads neither scipy.stats (~45 MB: the
registration's chi-square quantile comes from scipy.special) nor pymavlink.mavutil (6 MB:
the ground tools' connections), nor the recorders' libraries (foxglove, mcap, rerun: the
bench and the ground record missions, never the flight process)."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("scipy.stats", "pymavlink.mavutil", "hil_sim", "ground", "foxglove", "mcap", "rerun")


def test_the_flight_executive_does_not_import_heavy_or_bench_modules() -> None:
    code = (
        "import sys\n"
        "from fsw.settings import load_settings\n"
        "from fsw.app import build_executive\n"
        "build_executive(load_settings())\n"
        f"print(sorted(m for m in sys.modules if m.split('.')[0] in {{h.split('.')[0] for h in {HEAVY!r}}} "
        f"and any(m == h or m.startswith(h + '.') for h in {HEAVY!r})))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout[-2000:]
