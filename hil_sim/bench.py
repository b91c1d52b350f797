"""The LOCKSTEP bench: flight software and simulated hardware in one process, one clock.

The flight executive runs on a ``SteppedClock``; before each of its frames the bench steps
the hardware rig to that frame's time (``Executive.run_lockstep(before_frame=...)``): the
emulated controllers read the commands the flight software sent during the previous frame,
the truth moves, and statuses, serial reports and rendered pairs are waiting when the frame
runs. Nothing is shared but the wires:

* CAN: a python-can ``virtual`` bus whose channel name is unique to this bench; the flight
  side opens its own end from ``[devices]`` like on the rover;
* serial: an in-memory pair (:mod:`hil_sim.hw.serial_pair`), the flight end handed to the
  driver factory as ``mast_port``;
* camera: :class:`hil_sim.hw.camera_server.SimCameraLink` handed in as ``camera_source``.

Faults of the flight software itself come through the same backdoor (``hil_sim.faults``):
``stuck_task`` wraps the executive's activation of its target task, so while it is active the
task either does not complete (``hang``: no work, no answer to the health pings) or is charged
``delay_s`` more than it took (``overrun``: the executive's timers, the schedule's and the
host's, jump by that much during the activation). The watchdog and the health task see exactly
what they would on the rover.

Runs are deterministic for a seed (virtual-bus order, seeded faults and truth; the executive's
budgets, overruns and slips on the stepped clock, the host's time of the work only a metric:
``fsw.executive.executive``). All CAN
traffic can be recorded with python-can's ``can.Logger`` (``.log``, ``.asc``, ``.blf``) with
bench-clock timestamps; ``cantools decode config/rover.dbc < run.log`` reads it.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from fsw.app import build_executive
from fsw.drivers.can_inproc import InprocBus
from fsw.drivers.resources import Endpoints, Resources
from fsw.executive.executive import Executive
from fsw.executive.lockstep import Lockstep
from fsw.framework.clock import SteppedClock
from fsw.framework.commands import CommandRequest, CommandResponse
from fsw.settings import FswConfig
from hil_sim.faults import FaultInjector, FaultSpec
from hil_sim.hw.camera_server import SimCameraLink
from hil_sim.hw.serial_pair import memory_serial_pair
from hil_sim.rig import HardwareConfig, HardwareRig, load_hardware

_ids = itertools.count(1)
#: Unix time of the stepped clock's zero (2026-01-01T00:00:00Z): the Unix time a lockstep run's
#: flight software sees, for MAVLink signing and the .tlog's stamps, unless its resources bring one.
LOCKSTEP_UNIX_EPOCH_S = 1_767_225_600.0


class _Sink:
    """A text stream that discards what it is given."""

    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        pass


class ExecutiveDriver:
    """Stepping and the ground's view of a lockstep executive, shared by the bench and the
    task test rig: ``exe`` is the executive, ``run`` steps (the deriving class says how)."""

    COMMAND_SOURCE = "bench"

    def __init__(self, exe: Executive) -> None:
        self.exe = exe
        self._seq = itertools.count(1)  # command sequence numbers

    def run(self, frames: int) -> None:
        raise NotImplementedError

    def run_until(self, done: Callable[[], bool], max_frames: int) -> int:
        """Run frame by frame until ``done()`` is true; returns the frames run (or raises)."""
        for n in range(1, max_frames + 1):
            self.run(1)
            if done():
                return n
        raise TimeoutError(f"condition not met within {max_frames} frames")

    def command(self, name: str, **args: Any) -> CommandResponse:
        return self.exe.commands.dispatch(CommandRequest(name, args, next(self._seq), self.COMMAND_SOURCE))

    def tlm(self, name: str) -> Any:
        return self.exe.telemetry.get(name)


class LockstepBench(ExecutiveDriver):
    """One flight executive and one hardware rig, stepped together."""

    def __init__(
        self,
        fsw: FswConfig,
        world: Any = None,
        seed: int = 0,
        hw: HardwareConfig | None = None,
        faults: tuple[FaultSpec, ...] = (),
        can_log: str | Path | None = None,
        camera: bool = True,
        quiet: bool = False,
        render: Any = None,
        resources: Resources | None = None,
        start: tuple[float, int] | None = None,
    ) -> None:
        """``start``: (clock s, first frame) of a resumed run (docs/hil.md, "Resuming a mission"):
        the clock starts at the time of the frame that wrote the checkpoint, and the executive
        runs the next frame first; the flight tasks restore themselves from the map store."""
        self.channel = f"safer-bench-{os.getpid()}-{next(_ids)}"
        self.faults = FaultInjector(seed, faults)
        self.sim_bus = InprocBus(channel=self.channel, receive_own_messages=False)
        self._tap = can.Bus(interface="virtual", channel=self.channel) if can_log else None
        self.logger = can.Logger(str(can_log)) if can_log else None
        flight_port, device_port = memory_serial_pair()
        self.rig = HardwareRig(world, fsw, hw or load_hardware(), seed, self.sim_bus, device_port, self.faults)
        render = render or (self.rig.render_pair if world is not None else None)  # a test may bring its own
        self.camera = SimCameraLink(render, self.faults) if camera and render is not None else None
        devices = dataclasses.replace(
            fsw.devices,
            can_interface="virtual",
            can_channel=self.channel,
            camera_source="sim" if self.camera is not None else "none",
        )
        self.cfg = dataclasses.replace(fsw, devices=devices)
        self.clock = SteppedClock(start[0] if start is not None else 0.0)
        # No map store unless the caller brings one: a bench run never restores another's map.
        res = self._on_clock(resources or Resources())
        # A radio of its own (unless the caller brings one), so benches never share an end.
        self._own_radio = None
        if res.radio_port is None:
            from fsw.drivers.radio import open_radio

            self._own_radio = res.radio_port = open_radio(f"inproc://{self.channel}-radio")
        ends = Endpoints(mast_port=flight_port, camera_source=self.camera)
        super().__init__(build_executive(self.cfg, self.clock, res, ends, map_store=False))
        self._t_last = self.clock.now()
        if start is not None:
            self.exe.frame = int(start[1])
        # the agents of the bench, on its one clock: this RECON-bot first (add_agent adds more)
        self.lockstep = Lockstep(self.clock)
        self.lockstep.add(self.exe, self.before_frame, align=False)
        self._agents: dict[str, Executive] = {self.cfg.agent.name: self.exe}
        self._install_task_faults()
        self.quiet = quiet
        if quiet:  # silence console-style tasks (they print every event to stdout)
            for task in self.exe.tasks.values():
                if hasattr(task, "out"):
                    task.out = _Sink()  # type: ignore[attr-defined]

    # -- faults of the flight tasks (stuck_task) -----------------------------------------------
    def _install_task_faults(self) -> None:
        exe = self.exe
        unknown = sorted({f.target for f in self.faults.faults if f.kind == "stuck_task"} - set(exe.tasks))
        if unknown:
            raise ValueError(f"stuck_task target {unknown[0]!r} is not a flight task ({', '.join(sorted(exe.tasks))})")
        self.faults.task_names = tuple(exe.tasks)
        schedule_timer = exe.timer  # the stepped clock
        self.base_host_timer: Callable[[], float] = exe.host_timer  # mission_run may swap it (CPU time)
        self._extra_s = 0.0  # time charged by overrun faults
        exe.timer = lambda: schedule_timer() + self._extra_s
        exe.host_timer = lambda: self.base_host_timer() + self._extra_s
        activate = exe._activate

        def faulty_activate(task: Any, k: int) -> None:
            f = self.faults.stuck_task(task.name) if self.faults.faults else None
            if f is None:
                activate(task, k)
            elif f.mode == "overrun":
                run = task.run

                def slow_run(frame: int) -> None:
                    try:
                        run(frame)
                    finally:
                        self._extra_s += f.delay_s

                task.run = slow_run
                try:
                    activate(task, k)
                finally:
                    del task.run  # the class's method again
                self.faults.count("task_overrun_activations")
            else:  # hang: the activation never completes (no work, no ping answered)
                self.faults.count("task_hung_activations")

        exe._activate = faulty_activate  # type: ignore[method-assign]

    def set_host_timer(self, timer: Callable[[], float]) -> None:
        """Measure the host's time of the tasks' activations and the slack-job slices with
        ``timer`` (e.g. ``time.thread_time``), overrun faults still charged."""
        self.base_host_timer = timer
        self.exe.jobs.host_timer = timer

    # -- stepping ---------------------------------------------------------------------------
    def before_frame(self, k: int) -> None:
        now = self.clock.now()
        self._log(self._t_last)  # what the flight side sent during the previous frame
        self.rig.step(now, now - self._t_last)
        self._t_last = now
        if self.camera is not None:
            self.camera.serve(now)
        self._log(now)

    def _log(self, now: float) -> None:
        if self._tap is None or self.logger is None:
            return
        while (msg := self._tap.recv(timeout=0.0)) is not None:
            msg.timestamp = now
            msg.channel = "can0"
            self.logger.on_message_received(msg)

    def run(self, frames: int) -> None:
        """Run ``frames`` frames of the RECON-bot, and the other agents' frames due meanwhile."""
        self.lockstep.run_frames(self.exe, frames)

    # -- more agents on the same clock -----------------------------------------------------------
    def add_agent(self, cfg: FswConfig, resources: Resources | None = None,
                  before_frame: Callable[[int], None] | None = None) -> Executive:
        """Build the executive of another agent (its own topology, ``[agent] kind``) on the bench's
        clock and step it with the RECON-bot from the next frame start on. Its devices are those
        of its ``[devices]`` section (``none``: the test hands in ``resources``). Agents of one bench
        have distinct names and MAVLink system ids. ``before_frame(k)`` runs before each of its
        frames (its hardware's turn, as the RECON-bot's rig has)."""
        name = cfg.agent.name
        if name in self._agents:
            raise ValueError(f"the bench already has an agent named {name!r}")
        sysid = cfg.mavlink.system_id
        taken = {e.cfg.mavlink.system_id: n for n, e in self._agents.items()}
        if sysid in taken:
            raise ValueError(f"agent {name!r}: MAVLink system id {sysid} is already agent {taken[sysid]!r}'s")
        exe = build_executive(cfg, self.clock, self._on_clock(resources or Resources()), map_store=False)
        self.lockstep.add(exe, before_frame)
        self._agents[name] = exe
        if self.quiet:
            for task in exe.tasks.values():
                if hasattr(task, "out"):
                    task.out = _Sink()  # type: ignore[attr-defined]
        return exe

    def _on_clock(self, res: Resources) -> Resources:
        """``res`` with the bench's Unix time (:data:`LOCKSTEP_UNIX_EPOCH_S` + the stepped clock)
        unless it brings its own: the host's would make every run's .tlog differ."""
        if res.unix_time is None:
            clock = self.clock
            res.unix_time = lambda: LOCKSTEP_UNIX_EPOCH_S + clock.now()
        return res

    def agent(self, name: str) -> Executive:
        """The executive of the bench's agent ``name``."""
        return self._agents[name]

    # -- the ground's view (run_until, command, tlm: ExecutiveDriver) ---------------------
    def events(self, suffix: str) -> list[Any]:
        return [e for e in self.exe.events.history if e.name.endswith(suffix)]

    def close(self) -> None:
        from fsw.drivers.factory import close_devices

        for exe in self._agents.values():
            close_devices(exe.ctx.res)
        if self._own_radio is not None:
            self._own_radio.close()
        for bus in (self.sim_bus, self._tap):
            if bus is not None:
                bus.shutdown()
        if self.logger is not None:
            self.logger.stop()

    def __enter__(self) -> LockstepBench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
