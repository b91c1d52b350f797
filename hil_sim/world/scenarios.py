"""``load_scenario``: build (and cache) the :class:`World` a scenario spec names.

Worlds are deterministic for ``(spec, seed)`` and read-only, so one cached instance is
shared by every caller in a process (a lockstep run, the renderer and the tests).
"""

from __future__ import annotations

import functools

from hil_sim.world.config import ScenarioConfig, ScenarioError, load_scenario_config
from hil_sim.world.world import World


def load_scenario(spec: str, seed: int | None = 0) -> World:
    """The world for ``spec`` (``lab``, ``cliff``, ``mars``, ``file:PATH``, a ``.toml`` path,
    each optionally followed by ``?key=value&...`` overrides) built with ``seed``.

    ``seed=None`` takes the scenario file's default seed. Raises :class:`ScenarioError` or
    ``fsw.framework.params.ConfigError`` (both ``ValueError``) with a one-line reason on bad input.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ScenarioError("empty scenario spec (try: lab, cliff, mars, file:PATH)")
    if seed is not None and (not isinstance(seed, int) or seed < 0):
        raise ScenarioError(f"seed must be a non-negative integer, got {seed!r}")
    cfg, _ = load_scenario_config(spec)
    return _build_cached(spec.strip(), cfg.scenario.seed if seed is None else seed)


@functools.lru_cache(maxsize=8)
def _build_cached(spec: str, seed: int) -> World:
    cfg, _ = load_scenario_config(spec)
    return build_world(cfg, seed)


def build_world(cfg: ScenarioConfig, seed: int) -> World:
    """Build the world for an already validated scenario config (no caching)."""
    kind = cfg.scenario.kind
    if kind == "lab":
        from hil_sim.world.lab import build_lab

        return build_lab(cfg, seed)
    if kind == "cliff":
        from hil_sim.world.cliff import build_cliff

        return build_cliff(cfg, seed)
    if kind == "mars":
        from hil_sim.world.mars_scene import build_mars

        return build_mars(cfg, seed)
    if kind == "file":
        from hil_sim.world.dem import build_from_dem

        return build_from_dem(cfg, seed)
    if kind == "terrain":
        from hil_sim.world.terrain import build_terrain

        return build_terrain(cfg, seed)
    if kind == "cliff_team":
        from hil_sim.world.cliff_team import build_cliff_team

        return build_cliff_team(cfg, seed)
    raise ScenarioError(f"unknown scenario kind {kind!r}")  # config validation prevents this
