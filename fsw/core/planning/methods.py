"""The §7 mapping methods by id: ``make_planner("1" .. "5" | "oracle", ...)``."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, MastConfig
from fsw.core.planning.info_planners import InformationPlanner
from fsw.core.planning.nbv import NbvConfig
from fsw.core.planning.planners import METHODS, Planner
from fsw.core.planning.raster_planners import RasterPlanner
from fsw.core.planning.visibility import F64


def make_planner(method: str, n_views: int, cfg: NbvConfig, camera: CameraConfig,
                 mast: MastConfig, truth_z_m: F64 | None = None,
                 textured: NDArray[np.bool_] | None = None) -> Planner:
    """Planner for a §7 method id ``"1"``..``"5"`` or ``"oracle"`` (needs the truth arrays)."""
    if method in ("1", "2"):
        return RasterPlanner(method == "2", n_views, cfg, camera, mast)
    if method in ("3", "4", "5"):
        return InformationPlanner(method, cfg, camera, mast, use_interest=method == "5",
                                  straight_edge=method == "3")
    if method == "oracle":
        if truth_z_m is None or textured is None:
            raise ValueError("the oracle planner needs the true terrain and texture arrays")
        return InformationPlanner("oracle", cfg, camera, mast, truth_z_m=truth_z_m,
                                  textured=textured)
    raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
