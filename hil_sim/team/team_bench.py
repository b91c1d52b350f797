"""The Cliff-bot's executive and hardware on the lockstep bench (docs/team.md, "Running a team mission").

:class:`CliffbotAgent` builds the Cliff-bot from its flight file (``config/cliffbot.toml``,
agent kind ``cliffbot``) as a second executive on the bench's one stepped clock
(``LockstepBench.add_agent``), from t = 0 (it waits for the map), with its hardware: the
Anchorbots' winches, its wheels and IMU (:class:`~hil_sim.team.cliffbot_rig.CliffbotRig`) on
a team CAN bus of its own, and its end (side ``b``) of the capped radio channel. The file's
``[cliffbot_site]`` is set from the scenario (anchors, start, targets, the map's height datum)
as a ground crew would before the mission.

Before each of its frames the rig takes the commands the flight side sent, moves the winches,
settles the Cliff-bot on the TRUE ground, judges it and puts the statuses on the bus.

The RECON-bot's side of a fix (until its flight code answers them, docs/team.md "Limits"):
:class:`FixDivert` is the RECON-bot's radio end; it hands the fix requests to the bench's
:class:`~hil_sim.team.team_run.ReconFixer` (mast aimed at the Cliff-bot's TRUE pose, the
stereo pair rendered, the flight ``CliffbotLocalizer`` run) and sends its answer ahead of the
map link's bytes; the RECON-bot answers ``busy`` (NO_FIX) until its own mission has ended.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np

from fsw.comm.link_packets import PacketError
from fsw.comm.team import fix_packets
from fsw.core.geometry import MapGrid
from fsw.drivers.can_inproc import InprocBus
from fsw.drivers.resources import Resources
from fsw.sections import CliffbotSiteConfig
from fsw.settings import DEFAULT_CONFIG, FswConfig, load_settings
from fsw.tasks.cliffbot.mission import CliffbotMissionTask
from hil_sim.faults import FaultInjector, FaultSpec
from hil_sim.radio_channel import ChannelPort, RadioChannel
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.team.team_run import ReconFixer, TeamSetup, TruthFixer, team_section
from hil_sim.world.world import World

CLIFFBOT_CONFIG = DEFAULT_CONFIG.parent / "cliffbot.toml"
BUSY = 2  # fix_packets.NO_FIX_REASONS index


class FixDivert(ChannelPort):
    """The RECON-bot's radio end: fix requests go to the bench's fixer, the rest to the flight code."""

    def __init__(self, channel: RadioChannel, side: str, clock: Callable[[], float]) -> None:
        super().__init__(channel, side, clock)
        self.requests: list[fix_packets.FixRequest] = []

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        while True:
            d = super()._recv_internal(timeout_s, max_bytes)
            if d is None or not fix_packets.is_fix_packet(d):
                return d
            try:
                p = fix_packets.decode(d)
            except PacketError:
                continue  # a damaged request is not answered: the Cliff-bot times out and asks again
            if isinstance(p, fix_packets.FixRequest):
                self.requests.append(p)


def cliffbot_config(path: str | Path, world: World, rig: CliffbotRig, datum_m: float, out: Path | None) -> FswConfig:
    """The Cliff-bot's flight file with the scenario's site, map grid and the run's files."""
    cfg = load_settings(path)
    if cfg.agent.kind != "cliffbot":
        raise ValueError(f"{path}: agent kind {cfg.agent.kind!r}, a team mission needs a 'cliffbot' file")
    assert world.team is not None
    a = rig.anchors
    site = CliffbotSiteConfig(
        anchor_a_xyz=tuple(float(v) for v in a[0][:3]), anchor_b_xyz=tuple(float(v) for v in a[1][:3]),
        start_xy=tuple(float(v) for v in world.team.cliffbot_start_xy), start_yaw_deg=math.degrees(rig.yaw),
        targets_xy=tuple(float(v) for v in world.team.targets_xyz[:, :2].ravel()), map_datum_m=datum_m)
    ckpt = ""
    if out is not None:
        shutil.rmtree(out / "cliffbot_checkpoints", ignore_errors=True)  # a bench run never resumes another's
        ckpt = str(out / "cliffbot_checkpoints")
    return dataclasses.replace(
        cfg, map=world.map_grid, cliffbot_site=site,
        checkpoint=dataclasses.replace(cfg.checkpoint, directory=ckpt),
        mavlink=dataclasses.replace(cfg.mavlink, tlog_path=str(out / "cliffbot.tlog") if out is not None else ""),
    )


class CliffbotAgent:
    """The Cliff-bot's executive and rig on a lockstep bench (module docstring)."""

    def __init__(self, bench: Any, world: World, channel: RadioChannel, divert: FixDivert, seed: int,
                 datum_m: float, out: Path | None = None, faults: tuple[FaultSpec, ...] = (),
                 config: str | Path = CLIFFBOT_CONFIG, recon_done: Callable[[], bool] = lambda: True,
                 fixer: ReconFixer | TruthFixer | None = None) -> None:
        base = load_settings(config)
        self.world, self.bench, self.channel, self.divert, self.seed = world, bench, channel, divert, seed
        self.grid = MapGrid.from_config(world.map_grid)
        self.rig = CliffbotRig(world, self.grid, base.tether, base.climber, faults=FaultInjector(seed, faults),
                               seed=seed)
        self.cfg = cliffbot_config(config, world, self.rig, datum_m, out)
        name = f"{bench.channel}-team"
        self.sim_bus = InprocBus(channel=name, receive_own_messages=False)
        self.flight_bus = InprocBus(channel=name, receive_own_messages=False)
        res = Resources(radio_port=ChannelPort(channel, "b", bench.clock.now), team_can=self.flight_bus)
        self.recon_done = recon_done
        self.fixer = fixer
        self.sent0 = {side: channel.stats(side).air_bytes for side in ("a", "b")}
        self.exe = bench.add_agent(self.cfg, res, before_frame=self.before_frame)
        task = self.exe.tasks["mission"]
        if not isinstance(task, CliffbotMissionTask):
            raise ValueError("the Cliff-bot's schedule has no task 'mission' of kind 'cliffbot_mission'")
        self.task = task
        self.est_path: list[tuple[float, float]] = []
        self._t_last = bench.clock.now()

    @property
    def mission(self) -> Any:
        return self.task.mission

    def before_frame(self, k: int) -> None:
        now = self.bench.clock.now()
        frames = []
        while (msg := self.sim_bus.recv(timeout=0.0)) is not None:
            frames.append((int(msg.arbitration_id), bytes(msg.data)))
        self.rig.to_rig(frames, now)
        self.rig.step(now - self._t_last, now)
        self._t_last = now
        for fid, data in self.rig.poll(now):
            self.sim_bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        self._answer_fixes(now)
        s = self.mission.nav.s
        self.est_path.append((float(s[0]), float(s[1])))

    def _answer_fixes(self, now: float) -> None:
        for req in self.divert.requests:
            if not self.recon_done():
                pkt = fix_packets.encode(fix_packets.NoFix(req.seq, BUSY))
            else:
                if self.fixer is None:
                    r = self.bench.rig.rover
                    self.fixer = ReconFixer(self.world, (r.x, r.y, r.yaw), self.seed)
                pkt = self.fixer.answer(req, self.rig, now)
            self.divert.send(pkt, now)
        self.divert.requests.clear()

    def finished(self) -> bool:
        """The Cliff-bot's mission has ended (DONE, or SAFE with no recovery of its own), or it
        still waits for a map that will not come (the RECON-bot's mission has ended)."""
        st = self.mission.state
        if st == "DONE" or (st == "SAFE" and self.cfg.cliffbot_mission.safe_recover_s <= 0):
            return True
        return st == "WAIT_MAP" and self.recon_done()

    def section(self, out: Path | None, t0: float) -> dict[str, Any]:
        """The summary's ``team`` section."""
        m = self.mission
        z = m.z if m.z is not None else np.full(self.grid.shape, np.nan)
        errors = self.fixer.errors if self.fixer is not None else []
        radio = self.exe.tasks.get("cb_radio")
        drv = self.exe.tasks.get("cb_drv")
        sec = team_section(
            self.world, self.grid, z, self.rig, m, errors,
            link_bytes_down=self.channel.stats("a").air_bytes - self.sent0["a"],
            link_bytes_up=self.channel.stats("b").air_bytes - self.sent0["b"],
            link_bad_packets=int(getattr(radio, "counts", {}).get("bad_packets", 0)),
            can_bad_frames=int(getattr(getattr(drv, "dev", None), "bad_frames", 0)),
            sim_s=self.bench.clock.now() - t0, est_path=self.est_path, out=out,
            setup=TeamSetup(tether=self.cfg.tether, climber=self.cfg.climber))
        sec["map_received"] = m.z is not None
        sec["agent"] = {"name": self.cfg.agent.name, "kind": self.cfg.agent.kind,
                        "mavlink_system_id": self.cfg.mavlink.system_id, "frames": self.exe.frame}
        if sec.get("picture") and out is not None:
            sec["picture"] = Path(sec["picture"]).name
        return sec

    def close(self) -> None:
        for bus in (self.sim_bus, self.flight_bus):
            bus.shutdown()
