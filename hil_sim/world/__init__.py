"""World truth for the HIL bench: scenarios, terrain, texture and the Cliff-bot.

``load_scenario(spec, seed)`` builds a :class:`World` (docs/world.md). Specs: ``lab``,
``cliff``, ``mars``, ``file:PATH`` (a DEM), a path to a scenario ``.toml``; any of them may
carry ``?key=value&...`` overrides of the scenario's config keys.
"""

from hil_sim.world.cliffbot import ArucoMarker, CliffbotTruth, Quad
from hil_sim.world.config import ScenarioError
from hil_sim.world.scenarios import load_scenario
from hil_sim.world.world import World

__all__ = ["ArucoMarker", "CliffbotTruth", "Quad", "ScenarioError", "World", "load_scenario"]
