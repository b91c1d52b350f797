"""The team figures of a mission's summary (docs/team.md, "Running a team mission"; issue 28 item 5).

:class:`TeamFigures` is fed once per imaging cycle with each agent's own map after the cycle
(heights, NaN unknown) and the views the cycle took; :meth:`TeamFigures.section` gives the keys
the summary's ``team`` section gains:

* ``cells_by_agent``: the cells each agent's own views made known;
* ``sync_hash_equal``, ``sync_rounds``, ``sync_bytes``, ``sync_minimal_bytes``, ``sync_full_resends``
  (and ``sync_air_bytes``, ``sync_source``): the map sync's figures. A caller whose agents flew
  the sync gives them (``sync``: the lockstep team mission, ``sync_source`` "flown",
  ``fsw.comm.team.sync_end.team_figures``); without them both agents' maps are synced after the
  fact, one round per cycle, over the bench's radio channel (``sync_source`` "replay",
  ``hil_sim.team.team_sync.team_sync_figures``: the team-views harness, which has no radio);
* ``face_rmse_m``, ``face_rmse_gravity_m`` (and ``face_cells``): the face map against the truth and
  the gravity grid on the same cells (``hil_sim.team.face_eval.face_figures``), None when the
  mission keeps no face map (``face_note`` says why);
* ``views``: per cycle, each view's agent, pose, expected and obtained new cells, and the cycle's
  overlap (cells both agents' views measured / cells either measured; None with one agent).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.face_map import FaceMap
from hil_sim.link.radio_channel import RadioChannelConfig
from hil_sim.world.world import World

F32 = NDArray[np.float32]
AGENTS = ("recon", "cliffbot")


@dataclass
class TeamFigures:
    cell_m: float
    wheel_m: float
    seed: int = 0
    channel: RadioChannelConfig = field(default_factory=RadioChannelConfig)
    maps: dict[str, list[F32]] = field(default_factory=lambda: {a: [] for a in AGENTS})
    views: list[dict[str, Any]] = field(default_factory=list)

    def add_cycle(self, maps: dict[str, NDArray[np.floating]], views: list[dict[str, Any]],
                  overlap: float | None = None) -> None:
        """One imaging cycle: each agent's own map after it (an agent missing: it has no map of
        its own, all unknown) and the cycle's views (dicts with at least ``agent``)."""
        shape = next(iter(maps.values())).shape
        for a in AGENTS:
            m = maps.get(a)
            self.maps[a].append(np.full(shape, np.nan, np.float32) if m is None else np.asarray(m, np.float32))
        self.views.append({"cycle": len(self.views) + 1, "views": views, "overlap": overlap})

    def section(self, face: tuple[World, FaceMap, ElevationMap] | None = None,
                face_note: str = "", sync: dict[str, object] | None = None) -> dict[str, Any]:
        """The summary keys (module docstring); ``face``: the truth, the face map and the gravity
        grid of the same mission, in the world's frame; ``sync``: the flown sync's figures."""
        from hil_sim.team.face_eval import face_figures
        from hil_sim.team.team_sync import team_sync_figures

        cells = {a: int(np.isfinite(ms[-1]).sum()) if ms else 0 for a, ms in self.maps.items()}
        out: dict[str, Any] = {"cells_by_agent": cells}
        if sync is not None:
            out.update(sync)
        elif self.views:
            out.update(team_sync_figures(self.maps["recon"], self.maps["cliffbot"], self.channel, self.seed,
                                         cell_m=self.cell_m, wheel_m=self.wheel_m))
            out["sync_source"] = "replay"
        else:
            out.update({"sync_source": "none", "sync_hash_equal": None, "sync_rounds": 0, "sync_bytes": 0,
                        "sync_minimal_bytes": 0, "sync_full_resends": 0, "sync_air_bytes": 0})
        if face is not None:
            f = face_figures(face[0], face[1], face[2], cells)
            out.update({k: f[k] for k in ("face_rmse_m", "face_rmse_gravity_m", "face_cells")})
        else:
            out.update({"face_rmse_m": None, "face_rmse_gravity_m": None, "face_cells": 0,
                        "face_note": face_note or "no face map in this mission"})
        out["views"] = self.views
        return out
