"""The Cliff-bot's hardware in ``safer-hil serve`` (docs/team.md, "Running a team mission", real time).

For a team scenario the real-time bench also plays the Anchorbots' winches, the Cliff-bot's
wheels and IMU (:class:`~hil_sim.team.cliffbot_rig.CliffbotRig`) on a second CAN hub (the team
bus, ``config/team.dbc``), renders the Cliff-bot at its TRUE pose in the RECON-bot's pairs, and
writes the Cliff-bot's flight file (``--cliffbot-config``): ``config/cliffbot.toml`` with its
``[cliffbot_bus]`` on that hub, its ``[cliffbot_site]`` from the scenario in the team's frame
(the RECON-bot's map frame), the RECON-bot's ``[map]`` grid, and a UDP radio to the RECON-bot
on loopback (the RECON-bot's flight file gets the other end in its ``[link]``).
"""

from __future__ import annotations

import contextlib
import math
import socket
from pathlib import Path
from typing import Any

import can

from fsw.core.geometry import MapGrid
from fsw.drivers.can_inproc import open_bus
from fsw.settings import FswConfig, load_settings
from hil_sim.faults import FaultInjector
from hil_sim.hw.can_hub import CanHub
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.team.team_bench import CLIFFBOT_CONFIG, TeamFrame, cliffbot_config
from hil_sim.world.world import World


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class TeamHardware:
    """The Cliff-bot's rig on its own CAN hub, stepped by the serve loop."""

    def __init__(self, world: World, recon_rig: Any, recon_cfg: FswConfig, seed: int, faults: FaultInjector,
                 config: str | Path = CLIFFBOT_CONFIG) -> None:
        cb = load_settings(config)
        self.world, self.recon_rig, self.config = world, recon_rig, Path(config)
        self.grid = MapGrid.from_config(recon_cfg.map)
        self.rig = CliffbotRig(world, self.grid, cb.tether, cb.climber, faults=faults, seed=seed)
        x0, y0, yaw0 = (float(v) for v in world.rover_start)
        self.frame = TeamFrame(x0, y0, yaw0, float(recon_rig.rover.z))
        self.hub = CanHub("127.0.0.1", 0).start()
        try:
            self.bus = open_bus(interface="udp_hub", channel=self.hub.channel)
        except Exception:
            self.hub.close()
            raise
        self.radio = (_free_udp_port(), _free_udp_port())  # RECON-bot's, Cliff-bot's
        self.t_prev = 0.0
        self._rendered_at = -1

    def step(self, now: float) -> None:
        frames = []
        while (msg := self.bus.recv(timeout=0.0)) is not None:
            frames.append((int(msg.arbitration_id), bytes(msg.data)))
        self.rig.to_rig(frames, now)
        self.rig.step(now - self.t_prev, now)
        self.t_prev = now
        for fid, data in self.rig.poll(now):
            with contextlib.suppress(can.CanError):  # a frame the hub could not take is lost, as on a wire
                self.bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        if len(self.rig.path) != self._rendered_at:
            self._rendered_at = len(self.rig.path)
            self.recon_rig.renderer().world = self.rig.world_now()

    def recon_link(self) -> dict[str, str]:
        """The RECON-bot's ``[link]`` keys: its end of the radio."""
        a, b = self.radio
        return {"transport": f"udp://127.0.0.1:{a}", "peer": f"udp://127.0.0.1:{b}"}

    def cliffbot_tables(self, recon_cfg: FswConfig) -> dict[str, dict[str, Any]]:
        """The keys of the Cliff-bot's flight file (``config/cliffbot.toml``) for these endpoints,
        by table."""
        cfg = cliffbot_config(self.config, self.world, self.rig, self.frame, None)
        s, m = cfg.cliffbot_site, recon_cfg.map
        a, b = self.radio
        return {
            "cliffbot_bus": {"can_interface": "udp_hub", "can_channel": self.hub.channel},
            "cliffbot_site": {"anchor_a_xyz": list(s.anchor_a_xyz), "anchor_b_xyz": list(s.anchor_b_xyz),
                              "start_xy": list(s.start_xy), "start_yaw_deg": round(s.start_yaw_deg, 6),
                              "targets_xy": list(s.targets_xy), "map_datum_m": 0.0},
            "map": {"origin_x_m": m.origin_x_m, "origin_y_m": m.origin_y_m, "cell_m": m.cell_m, "nx": m.nx,
                    "ny": m.ny},
            "link": {"transport": f"udp://127.0.0.1:{b}", "peer": f"udp://127.0.0.1:{a}"},
        }

    def recon_site(self, recon_cfg: FswConfig) -> dict[str, Any]:
        """The RECON-bot's ``[cliffbot_site]``: the Cliff-bot's site, with the team mask on (its fixer
        reads the Anchorbots' plates from the tether exits, docs/algorithm.md §5.2)."""
        return {**self.cliffbot_tables(recon_cfg)["cliffbot_site"], "mask_team": True}

    def truth(self) -> dict[str, object]:
        w = self.rig.winches
        return {"cliffbot_x_m": round(float(self.rig.xy[0]), 4), "cliffbot_y_m": round(float(self.rig.xy[1]), 4),
                "winch_commands": sum(n.rx_commands for n in w.values()),
                "winch_bad": sum(n.rx_bad for n in w.values()) + self.rig.rx_bad,
                "tether_violations": int(sum(self.rig.violations.values())),
                "cliffbot_yaw_deg": round(math.degrees(self.rig.yaw), 2)}

    def close(self) -> None:
        self.bus.shutdown()
        self.hub.close()
