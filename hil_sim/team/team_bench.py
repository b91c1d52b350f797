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

The RECON-bot answers the fix requests in its flight code (``fsw.tasks.fixer.task``); the
bench renders the Cliff-bot at its TRUE pose in the RECON-bot's camera pairs, and
:class:`FixWatch` (the RECON-bot's radio end) notes every FIX it sends so the run judges it
against the truth at that instant (position and heading error, NEES against its covariance).
"""

from __future__ import annotations

import dataclasses
import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np
from numpy.typing import NDArray

from fsw.comm.link_packets import PacketError
from fsw.comm.team import fix_packets
from fsw.comm.team.sync_end import FlightSync
from fsw.comm.team.sync_end import team_figures as sync_team_figures
from fsw.core.geometry import MapGrid, wrap_angle
from fsw.core.team.tether import TetherConfig, anchor_points, tether_state
from fsw.drivers.camera import CameraDriver, make_source
from fsw.drivers.can_inproc import InprocBus
from fsw.drivers.resources import Resources
from fsw.sections import CliffbotSiteConfig
from fsw.settings import DEFAULT_CONFIG, FswConfig, load_settings
from fsw.tasks.cliffbot.mission import CliffbotMissionTask
from fsw.tasks.cliffbot.sensing import CliffbotSensingTask
from hil_sim.faults import FaultInjector, FaultSpec
from hil_sim.link.radio_channel import ChannelPort, RadioChannel
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.team.team_eval import FixError, fix_error, unknown_at_entry
from hil_sim.team.team_figures import TeamFigures
from hil_sim.team.team_run import TeamSetup, team_section
from hil_sim.team.team_sensing import CliffbotHeadCamera
from hil_sim.world.world import World

CLIFFBOT_CONFIG = DEFAULT_CONFIG.parent / "cliffbot.toml"
# the rig's plain state (its truth grid, anchors and codec are rebuilt from the scenario)
RIG_STATE = ("rng", "xy", "wheels_enabled", "t_wheel_cmd", "t_status", "counter", "now", "rx_bad")
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class TeamFrame:
    """The team's frame is the RECON-bot's map frame: its odometry, which starts at its start pose
    (``world.rover_start``) with heights from its start body height (``datum_m``). The Cliff-bot's
    site is surveyed in it; the bench converts to judge on the truth (world frame)."""

    x0: float
    y0: float
    yaw0: float
    datum_m: float

    def _r(self, yaw: float) -> F64:
        c, s_ = math.cos(yaw), math.sin(yaw)
        return np.array([[c, -s_], [s_, c]])

    def to_map(self, xy: F64) -> F64:
        """World points (N, 2) to the team's frame."""
        p = np.asarray(xy, float).reshape(-1, 2) - np.array([self.x0, self.y0])
        return p @ self._r(-self.yaw0).T

    def to_world(self, xy: F64) -> F64:
        """Team-frame points (N, 2) to the world."""
        return np.asarray(xy, float).reshape(-1, 2) @ self._r(self.yaw0).T + np.array([self.x0, self.y0])


def truth_map(world: World, grid: MapGrid, frame: TeamFrame) -> F64:
    """The TRUE ground as a map in the team's frame on ``grid`` (a perfect RECON-bot's map):
    the world's mean ground over each cell (``World.ground_on_grid``), heights from the datum."""
    return np.asarray(world.ground_on_grid(grid, (frame.x0, frame.y0, frame.yaw0)), float) - frame.datum_m


class FixWatch(ChannelPort):
    """The RECON-bot's radio end: notes the FIX packets it sends (for the judging), nothing else."""

    def __init__(self, channel: RadioChannel, side: str, clock: Callable[[], float]) -> None:
        super().__init__(channel, side, clock)
        self.sent: list[fix_packets.Fix] = []

    def _send_internal(self, datagram: bytes) -> None:
        if fix_packets.is_fix_packet(datagram):
            try:
                p = fix_packets.decode(datagram)
            except PacketError:
                p = None
            if isinstance(p, fix_packets.Fix):
                self.sent.append(p)
        super()._send_internal(datagram)


def team_site(world: World, anchors: F64, yaw_rad: float, frame: TeamFrame,
              mask_team: bool = False) -> CliffbotSiteConfig:
    """The scenario's site in the team's frame: the tether exits ``anchors`` (2, 3, world), the
    Cliff-bot's start (heading ``yaw_rad`` in the world) and targets."""
    assert world.team is not None
    a = np.asarray(anchors, float)
    axy = frame.to_map(a[:, :2])
    yaw = math.degrees(wrap_angle(yaw_rad - frame.yaw0))
    return CliffbotSiteConfig(
        anchor_a_xyz=(float(axy[0, 0]), float(axy[0, 1]), float(a[0, 2]) - frame.datum_m),
        anchor_b_xyz=(float(axy[1, 0]), float(axy[1, 1]), float(a[1, 2]) - frame.datum_m),
        start_xy=tuple(float(v) for v in frame.to_map(world.team.cliffbot_start_xy)[0]), start_yaw_deg=yaw,
        targets_xy=tuple(float(v) for v in frame.to_map(world.team.targets_xyz[:, :2]).ravel()), map_datum_m=0.0,
        mask_team=mask_team)


def recon_site(world: World, grid: MapGrid, tcfg: TetherConfig) -> CliffbotSiteConfig:
    """The site as the RECON-bot is told it before its mission (the ground crew's survey, with
    the team mask on): the same as the Cliff-bot's, its start heading away from the anchors'
    midpoint, heights from the ground under the RECON-bot's start."""
    assert world.team is not None
    x0, y0, yaw0 = (float(v) for v in world.rover_start)
    frame = TeamFrame(x0, y0, yaw0, float(world.ground_at(x0, y0)))
    anchors = anchor_points(world.ground_on_grid(grid), grid, world.team.anchors_xy, tcfg)
    d = np.asarray(world.team.cliffbot_start_xy, float) - anchors[:, :2].mean(axis=0)
    return team_site(world, anchors, math.atan2(float(d[1]), float(d[0])), frame, mask_team=True)


def cliffbot_config(path: str | Path, world: World, rig: CliffbotRig, frame: TeamFrame,
                    out: Path | None, sync: bool = True) -> FswConfig:
    """The Cliff-bot's flight file with the scenario's site (in the team's frame), the map grid and
    the run's files; its map sync on only if ``sync`` (the RECON-bot's is: a team syncs both ends
    or neither)."""
    cfg = load_settings(path)
    if cfg.agent.kind != "cliffbot":
        raise ValueError(f"{path}: agent kind {cfg.agent.kind!r}, a team mission needs a 'cliffbot' file")
    site = team_site(world, rig.anchors, rig.yaw, frame)
    ckpt = ""
    if out is not None:
        shutil.rmtree(out / "cliffbot_checkpoints", ignore_errors=True)  # a bench run never resumes another's
        ckpt = str(out / "cliffbot_checkpoints")
    return dataclasses.replace(
        cfg, map=world.map_grid, cliffbot_site=site,
        map_sync=dataclasses.replace(cfg.map_sync, enabled=cfg.map_sync.enabled and sync),
        checkpoint=dataclasses.replace(cfg.checkpoint, directory=ckpt),
        mavlink=dataclasses.replace(cfg.mavlink, tlog_path=str(out / "cliffbot.tlog") if out is not None else ""),
    )


class CliffbotAgent:
    """The Cliff-bot's executive and rig on a lockstep bench (module docstring)."""

    def __init__(self, bench: Any, world: World, channel: RadioChannel, watch: FixWatch, seed: int,
                 datum_m: float, out: Path | None = None, faults: tuple[FaultSpec, ...] = (),
                 config: str | Path = CLIFFBOT_CONFIG, recon_done: Callable[[], bool] = lambda: True,
                 resume: dict[str, Any] | None = None) -> None:
        """``resume``: the team's part of the RECON-bot's checkpoint (:meth:`state`): the Cliff-bot
        starts from the checkpoint it held then and its hardware goes on from where it stood."""
        base = load_settings(config)
        self.world, self.bench, self.channel, self.watch, self.seed = world, bench, channel, watch, seed
        x0, y0, yaw0 = (float(v) for v in world.rover_start)
        self.frame = TeamFrame(x0, y0, yaw0, datum_m)
        self.grid = MapGrid.from_config(world.map_grid)
        self.rig = CliffbotRig(world, self.grid, base.tether, base.climber, faults=FaultInjector(seed, faults),
                               seed=seed)
        self.cfg = cliffbot_config(config, world, self.rig, self.frame, out, sync=bench.cfg.map_sync.enabled)
        name = f"{bench.channel}-team"
        self.sim_bus = InprocBus(channel=name, receive_own_messages=False)
        self.flight_bus = InprocBus(channel=name, receive_own_messages=False)
        if resume is not None:
            self._write_checkpoint(resume)
        rover = bench.rig.rover
        self.head = CliffbotHeadCamera(self.rig, self.cfg.cliffbot_sensing, seed,
                                       recon=lambda: (float(rover.x), float(rover.y), float(rover.yaw)),
                                       now=bench.clock.now)
        camera = CameraDriver(make_source("sim", self.head), timeout_s=self.cfg.cliffbot_sensing.capture_timeout_s)
        res = Resources(radio_port=ChannelPort(channel, "b", bench.clock.now), team_can=self.flight_bus,
                        camera=camera)
        self.recon_done = recon_done
        self.errors: list[FixError] = []  # each FIX sent, against the truth
        self.recon_errors: list[tuple[float, float]] = []  # the RECON-bot's own error at each FIX sent
        self._rendered_at = -1
        self.sent0 = {side: channel.stats(side).air_bytes for side in ("a", "b")}
        self.exe = bench.add_agent(self.cfg, res, before_frame=self.before_frame)
        task = self.exe.tasks["mission"]
        if not isinstance(task, CliffbotMissionTask):
            raise ValueError("the Cliff-bot's schedule has no task 'mission' of kind 'cliffbot_mission'")
        self.task = task
        self.est_path: list[tuple[float, float]] = []
        self.unknown_at_entry: set[tuple[int, int]] = set()  # cells entered unknown (_note_entered)
        self._t_last = bench.clock.now()
        self.figures = TeamFigures(self.grid.cell, self.cfg.climber.wheel_d_m, seed, channel.cfg)
        self._cycles = 0
        self._recon_z: NDArray[np.float64] | None = None
        self._sensed = 0  # the Cliff-bot's answered view requests noted
        if resume is not None:
            self._restore_bench(resume)

    # -- the whole team's resume (docs/team.md, "Running a team mission") ----------------------
    def state(self) -> dict[str, Any]:
        """The team's part of a RECON-bot checkpoint (JSON-able): the Cliff-bot's checkpoint as it
        stands now (its flight state: a restarted Cliff-bot continues from it), and its
        hardware's (the Anchorbots' winches, the rig's noise generators and counters, its clock),
        the run's byte baselines and executive frame."""
        from fsw.tasks.cliffbot import checkpoint
        from hil_sim.mission.resume_state import attrs_state

        rig = self.rig
        m = self.mission
        return {
            "cliffbot": checkpoint.snapshot(m, self.bench.clock.now()),
            "map": None if m.z is None else np.asarray(m.z, float).tolist(),
            "rig": attrs_state(rig, RIG_STATE), "wheel_cmd": list(rig.wheel_cmd),
            "faults": attrs_state(rig.faults, ("rng",)),
            "winches": {name: attrs_state(w) for name, w in rig.winches.items()},
            "path": [list(p) for p in rig.path], "violations": dict(rig.violations),
            "hazard_cells": [list(c) for c in sorted(rig.hazard_cells)],
            "wheel_rad": list(rig.wheel_rad), "sent0": dict(self.sent0), "frame": self.exe.frame,
            "est_path": [list(p) for p in self.est_path],
            "unknown_at_entry": sorted([int(a), int(b)] for a, b in self.unknown_at_entry),
            "sync": None if (s := self._sync("cb_radio")) is None else s.state(),
        }

    def _write_checkpoint(self, st: dict[str, Any]) -> None:
        """The Cliff-bot's checkpoint of ``st`` in its directory (before its executive starts)."""
        from fsw.tasks.cliffbot import checkpoint

        store = checkpoint.CheckpointFile(self.cfg.checkpoint.directory)
        z = None if st.get("map") is None else np.asarray(st["map"], np.float64)
        err = store.save(dict(st["cliffbot"]), z)
        if not err and isinstance(st.get("sync"), dict):  # its map sync end's state
            err = store.save_sync(st["sync"])
        if err:
            raise ValueError(f"the Cliff-bot's checkpoint cannot be written: {err}")

    def _restore_bench(self, st: dict[str, Any]) -> None:
        from hil_sim.mission.resume_state import BenchStateError, restore_attrs

        rig = self.rig
        try:
            restore_attrs(rig, st["rig"])
            restore_attrs(rig.faults, st["faults"])
            for name, w in rig.winches.items():
                restore_attrs(w, st["winches"][name])
            rig.path = [(float(x), float(y)) for x, y in st["path"]]
            rig.violations = {k: int(v) for k, v in st["violations"].items()}
            rig.hazard_cells = {(int(a), int(b)) for a, b in st["hazard_cells"]}
            rig.wheel_rad = [float(v) for v in st["wheel_rad"]]
            rig.wheel_cmd = (float(st["wheel_cmd"][0]), float(st["wheel_cmd"][1]))
            rig.state = tether_state(rig.z, rig.grid, rig.anchors, rig.xy, rig.tcfg, rig.ccfg.footprint_m) or rig.state
            self.sent0 = {str(k): int(v) for k, v in st["sent0"].items()}
            self.exe.frame = int(st["frame"])
            self.est_path = [(float(x), float(y)) for x, y in st["est_path"]]
            self.unknown_at_entry = {(int(a), int(b)) for a, b in st.get("unknown_at_entry", [])}
        except (KeyError, TypeError, ValueError) as exc:
            raise BenchStateError(f"the team's bench state is malformed ({type(exc).__name__}: {exc})") from None
        self._rendered_at = -1

    def _sync(self, task: str) -> FlightSync | None:
        """The map sync end of a radio task (``radio``: the RECON-bot's, ``cb_radio``: the Cliff-bot's)."""
        t = (self.bench.exe if task == "radio" else self.exe).tasks.get(task)
        s = getattr(t, "sync", None)
        return s if isinstance(s, FlightSync) else None

    def sync_settled(self) -> bool:
        """Both agents' replicas of the team's map are equal (or the team does not sync)."""
        a, b = self._sync("radio"), self._sync("cb_radio")
        return a is None or b is None or a.end.replica_hash() == b.end.replica_hash()

    @property
    def mission(self) -> Any:
        return self.task.mission

    def before_frame(self, k: int) -> None:
        now = self.bench.clock.now()
        frames = []
        while (msg := self.sim_bus.recv(timeout=0.0)) is not None:
            frames.append((int(msg.arbitration_id), bytes(msg.data)))
        self.rig.to_rig(frames, now)
        n0 = len(self.rig.path)
        self.rig.step(now - self._t_last, now)
        self._note_entered(n0)
        self._t_last = now
        for fid, data in self.rig.poll(now):
            self.sim_bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        self._judge_fixes()
        self._render_truth()
        self._note_cycle()
        s = self.mission.est.s
        self.est_path.append((float(s[0]), float(s[1])))

    def _note_entered(self, n0: int) -> None:
        """The cells the rig's true path entered this step that the Cliff-bot's map did not know
        from a sensor then (its map now: the plane under its body carried on does not count)."""
        new = self.rig.path[max(n0, 1):]
        if not new:
            return
        m = self.mission
        known = None
        if m.z is not None and m.z.shape == self.grid.shape:
            known = np.isfinite(m.z)
            if m.carried is not None and m.carried.shape == known.shape:
                known &= ~m.carried
        self.unknown_at_entry |= unknown_at_entry(self.frame.to_map(np.asarray(new, float)), known, self.grid)

    def _judge_fixes(self) -> None:
        """Each FIX the RECON-bot sent, against the Cliff-bot's true pose now (flight heights are
        in the RECON-bot's datum)."""
        from fsw.core.localization.localization import so3_log

        if not self.watch.sent:
            return
        cb = self.rig.cliffbot_truth()
        cam = self.bench.rig.camera_pose().t
        fr = self.frame
        rz = np.eye(3)
        rz[:2, :2] = fr._r(fr.yaw0)
        recon = self._recon_error()
        for f in self.watch.sent:
            self.recon_errors.append(recon)
            p = np.asarray(f.position, float)
            t = np.array([*fr.to_world(p[:2])[0], p[2] + fr.datum_m])
            r = rz @ fix_packets.rotation(f.rotvec)
            self.errors.append(fix_error(t, so3_log(r @ cb.R.T), f.yaw + fr.yaw0 - cb.yaw, f.cov, cb.t,
                                         float(np.linalg.norm(cb.t - cam))))
        self.watch.sent.clear()


    def _recon_error(self) -> tuple[float, float]:
        """The RECON-bot's own pose error now (its estimate against the truth): heading (deg) and
        place (cm), what a fix would carry without the Anchorbots' plates (docs/algorithm.md §5.2)."""
        motion = self.bench.exe.tasks.get("motion")
        odo = getattr(motion, "odo", None)
        if odo is None:
            return math.nan, math.nan
        x, y, yaw = (float(v) for v in odo.pose)
        truth = self.bench.rig.rover
        t = self.frame.to_map(np.array([[truth.x, truth.y]]))[0]
        dyaw = math.degrees(wrap_angle(yaw - (truth.yaw - self.frame.yaw0)))
        return round(dyaw, 3), round(100 * math.hypot(x - float(t[0]), y - float(t[1])), 2)

    def _recon_pose(self) -> dict[str, Any] | None:
        """Where the RECON-bot stands at the end, in the team's frame: its estimate ``(x, y, yaw)``
        with covariance (relative to its map, and ``frame_cov`` against its start), and the truth
        (``safer-hil experiment fiducials --missions``)."""
        motion = self.bench.exe.tasks.get("motion")
        odo = getattr(motion, "odo", None)
        if odo is None or not hasattr(motion, "mcfg"):
            return None
        truth = self.bench.rig.rover
        t = self.frame.to_map(np.array([[truth.x, truth.y]]))[0]
        return {"estimate": [float(v) for v in odo.pose],
                "cov": np.asarray(odo.covariance(motion.mcfg), float).tolist(),
                "frame_cov": np.asarray(odo.frame_covariance(motion.mcfg), float).tolist(),
                "truth": [float(t[0]), float(t[1]), float(wrap_angle(truth.yaw - self.frame.yaw0))]}

    def _note_cycle(self) -> None:
        """After each of the RECON-bot's imaging steps: its map and its view; after each of the
        Cliff-bot's view requests answered: its own map and its views (the team figures)."""
        records = getattr(self.bench.exe.tasks.get("mission"), "records", [])
        perception = self.bench.exe.tasks.get("perception")
        if len(records) > self._cycles and perception is not None:
            emap = perception.map
            z = np.where(emap.mapped, emap.z, np.nan)
            self._recon_z = z
            for r in records[self._cycles:]:
                self.figures.add_cycle({"recon": z}, [{"agent": "recon", "pose": dict(r.pose), "how": r.view,
                                                       "expected_new_cells": round(float(r.expected_new_cells), 1),
                                                       "obtained_new_cells": int(r.obtained_new_cells)}])
            self._cycles = len(records)
        sense = next((t for t in self.exe.tasks.values() if isinstance(t, CliffbotSensingTask)), None)
        if sense is None or sense.answered <= self._sensed:
            return
        answered = sense.answered
        self._sensed = answered
        own = sense.own_map()
        maps = {"cliffbot": own} if self._recon_z is None else {"recon": self._recon_z, "cliffbot": own}
        s = self.mission.est.s
        self.figures.add_cycle(maps, [{"agent": "cliffbot", "request": answered,
                                       "pose": {"x": round(float(s[0]), 3), "y": round(float(s[1]), 3),
                                                "yaw_deg": round(math.degrees(float(s[2])), 1)},
                                       "how": f"head scan, pans {list(self.cfg.cliffbot_sensing.pan_deg)} deg",
                                       "views_merged": int(sense.merged),
                                       "own_cells": int(np.isfinite(own).sum())}])

    def _render_truth(self) -> None:
        """The RECON-bot's camera sees the Cliff-bot where it truly is."""
        if len(self.rig.path) != self._rendered_at:
            self._rendered_at = len(self.rig.path)
            self.bench.rig.renderer().world = self.rig.world_now()

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
        errors = self.errors
        radio = self.exe.tasks.get("cb_radio")
        drv = self.exe.tasks.get("cb_drv")
        sec = team_section(
            self.world, self.grid, z, self.rig, m, errors,
            link_bytes_down=self.channel.stats("a").air_bytes - self.sent0["a"],
            link_bytes_up=self.channel.stats("b").air_bytes - self.sent0["b"],
            link_bad_packets=int(getattr(radio, "counts", {}).get("bad_packets", 0)),
            can_bad_frames=int(getattr(getattr(drv, "dev", None), "bad_frames", 0)),
            sim_s=self.bench.clock.now() - t0, est_path=self.est_path, out=out,
            setup=TeamSetup(tether=self.cfg.tether, climber=self.cfg.climber), to_map=self.frame.to_map,
            unknown_at_entry=frozenset(self.unknown_at_entry))
        sec["map_received"] = m.z is not None
        sec["recon_pose"] = self._recon_pose()
        sec["fix_recon_yaw_err_deg"] = [e[0] for e in self.recon_errors]
        sec["fix_recon_pos_err_cm"] = [e[1] for e in self.recon_errors]
        sec.update(self.figures.section(None, "no face map in the lockstep mission: the RECON-bot's flight fuses "
                                              "into the gravity grid only",
                                        sync=sync_team_figures(self._sync("radio"), self._sync("cb_radio"))))
        sec["agent"] = {"name": self.cfg.agent.name, "kind": self.cfg.agent.kind,
                        "mavlink_system_id": self.cfg.mavlink.system_id, "frames": self.exe.frame}
        if sec.get("picture") and out is not None:
            sec["picture"] = Path(sec["picture"]).name
        return sec

    def close(self) -> None:
        mavlink = self.exe.tasks.get("mavlink")
        if mavlink is not None:
            mavlink.close()  # flush and close cliffbot.tlog: its last second holds how the mission ended
        for bus in (self.sim_bus, self.flight_bus):
            bus.shutdown()
