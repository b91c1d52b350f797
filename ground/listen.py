"""``safer-ground listen URL``: a live terminal view of the rover over MAVLink.

Plain ANSI (no curses): the screen is redrawn in place on a terminal; when stdout is not a
terminal (a pipe, a file), only the final screen is printed at exit, which is how the
capture in docs/ground.md was made. Shows the link (heartbeat age, rate, lost frames,
reconnections), mode, pose and mast, SYS_STATUS, per-task timing against budgets, every
channel coloured by its limits, and the latest events coloured by severity.
"""

from __future__ import annotations

import argparse
import fnmatch
import math
import os
import sys
import time
from typing import Any

from ground.dictionary import GroundDictionary
from ground.state import SEVERITY_NAMES, Fleet, GroundState, vehicle_name

HELP = "live terminal view: mode, events, channels coloured by limits, task timing"
RESET, BOLD, DIM = "\x1b[0m", "\x1b[1m", "\x1b[2m"
RED, YELLOW, GREEN, CYAN = "\x1b[31m", "\x1b[33m", "\x1b[32m", "\x1b[36m"
SEV_COLOUR = {0: RED + BOLD, 1: RED + BOLD, 2: RED + BOLD, 3: RED, 4: YELLOW, 5: CYAN, 6: "", 7: DIM}


class Painter:
    def __init__(self, colour: bool) -> None:
        self.colour = colour

    def __call__(self, text: str, style: str) -> str:
        return f"{style}{text}{RESET}" if self.colour and style else text


def render(st: GroundState, d: GroundDictionary, url: str, now: float, paint: Painter,
           reconnects: int = 0, error: str | None = None, timeout_s: float = 3.0, n_events: int = 12,
           channels: tuple[str, ...] = (), rows: int | None = None, steps: int | None = None,
           fleet: Fleet | None = None) -> str:
    """The whole screen as text (pure: the tests and the docs capture use it). ``channels``:
    shell patterns of the channels shown (all if empty); ``rows``: the terminal's height, the
    channel table is cut to fit so the header stays on screen; ``steps``: the mission's N;
    ``fleet``: every vehicle heard, one line of them under the header when there are several."""
    out: list[str] = []
    age = None if st.heartbeat_s is None else now - st.heartbeat_s
    if age is None:
        link = paint("WAITING for a heartbeat", YELLOW)
    elif age > timeout_s:
        link = paint(f"LINK LOST (no heartbeat for {age:.1f} s)", RED + BOLD)
    else:
        link = paint("LINK UP", GREEN + BOLD) + f" heartbeat {age:.1f} s ago"
    out.append(f"{paint('safer-ground', BOLD)} {url}  {link}  sys {st.system_id or '-'}  "
               f"{st.rate_bps(now) / 1000:.1f} kbit/s  lost {st.loss_pct():.1f} %  reconnects {reconnects}")
    if error:
        out.append(paint(f"  link error: {error}", RED))
    if fleet is not None and len(fleet.vehicles) > 1:
        out.append("Vehicles " + "   ".join(_vehicle(sid, v, now, timeout_s, v is st, paint)
                                           for sid, v in fleet.vehicles.items()))
    hb = st.heartbeat
    flags = []
    if hb is not None:
        for bit, name in ((128, "armed"), (4, "auto"), (32, "HIL")):
            if hb.base_mode & bit:
                flags.append(name)
    dict_state = {None: paint("waiting", DIM), True: paint("ok", GREEN),
                  False: paint("MISMATCH (showing raw keys)", RED)}[st.dictionary_ok]
    out.append(f"Mode {paint(st.mode(), BOLD)}  status {st.status()}  {' '.join(flags)}   "
               f"dictionary {d.source}: {dict_state}")
    pose = "-"
    if st.position_ned is not None:
        n, e, dn = st.position_ned
        yaw = "" if st.yaw_ned is None else f"  yaw {math.degrees(-st.yaw_ned):6.1f} deg"
        pose = f"x {n:6.2f}  y {-e:6.2f}  z {-dn:5.2f} m{yaw}"
    mast = "-" if st.mast is None else f"pan {math.degrees(st.mast[0]):6.1f}  tilt {math.degrees(st.mast[1]):6.1f} deg"
    step = st.channels.get("mission.step")
    step_text = "" if step is None else f"   step {step[0]:.0f}" + ("" if steps is None else f" of {steps}")
    out.append(f"Pose {pose}   Mast {mast}{step_text}")
    s = st.sys_status
    if s is not None:
        out.append(f"System load {s.load / 10:5.1f} %  slips {s.errors_count1}  overruns {s.errors_count2}  "
                   f"comm errors {s.errors_comm}  auth rejected {s.errors_count3}  events dropped {s.errors_count4}")
    out.append("")
    out.append(paint(f"{'task':<14}{'last ms':>9}{'max ms':>9}{'budget':>9}{'overruns':>10}", BOLD))
    for task, budget in d.budgets_ms.items():
        last = st.channels.get(f"{task}.exec_last_ms", (math.nan, 0))[0]
        mx = st.channels.get(f"{task}.exec_max_ms", (math.nan, 0))[0]
        ovr = st.channels.get(f"{task}.overruns", (math.nan, 0))[0]
        style = RED if (mx == mx and mx > budget) or (ovr == ovr and ovr > 0) else ""
        out.append(paint(f"{task:<14}{last:9.3f}{mx:9.3f}{budget:9.2f}{ovr:10.0f}", style))
    out.append("")
    out.append(paint("channels (red: out of limits, dim: older than 10 s)", BOLD))
    cells = []
    names = [n for n in sorted(st.channels) if not channels or any(fnmatch.fnmatch(n, p) for p in channels)]
    for name in names:
        value, t = st.channels[name]
        info = d.by_name(name) if st.dictionary_ok is not False else None
        style = ""
        if info is not None and info.limit_state(value) != "ok":
            style = RED + BOLD
        elif now - t > 10.0:
            style = DIM
        text = f"{name[:26]:<26} {value:>12.6g} {info.units if info else '':<5}"
        cells.append(paint(text, style))
    table = ["  ".join(cells[i:i + 2]) for i in range(0, len(cells), 2)]
    events = list(st.events)[-n_events:]
    if rows is not None:  # the header, the tasks and the events stay; the channel table gives way
        room = max(1, rows - len(out) - 3 - len(events) - 1)
        if len(table) > room:
            hidden = len(cells) - 2 * (room - 1)
            table = table[:room - 1] + [paint(f"... {hidden} more channels (--channels PATTERN filters)", DIM)]
    out.extend(table)
    out.append("")
    out.append(paint("events (newest last)", BOLD))
    for ev in events:
        sev = SEVERITY_NAMES.get(ev.severity, str(ev.severity))
        out.append(paint(f"{now - ev.time_s:6.1f} s ago  {sev:<9} {ev.text}", SEV_COLOUR.get(ev.severity, "")))
    return "\n".join(out)


def _vehicle(sid: int, v: GroundState, now: float, timeout_s: float, shown: bool, paint: Painter) -> str:
    age = None if v.heartbeat_s is None else now - v.heartbeat_s
    link = "" if age is not None and age <= timeout_s else paint(" LOST", RED)
    text = f"{vehicle_name(sid)} (sys {sid}) {v.mode()}{link}"
    return paint(f"[{text}]", BOLD) if shown else text


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("url", nargs="+", help="udpin:HOST:PORT (rover sends here, the default rover url is "
                                          "udpout:127.0.0.1:14550), udpout:HOST:PORT (rover listens) or "
                                          "serial:DEVICE; or a .tlog file to replay. Several: one link each "
                                          "(e.g. the RECON-bot's and the Cliff-bot's), or .tlog files replayed "
                                          "together in time order")
    p.add_argument("--speed", type=float, default=0.0, metavar="X",
                   help="tlog replay: X times the logged pace on a terminal (0: straight to the last screen)")
    p.add_argument("--baud", type=int, default=57600, help="serial line rate")
    p.add_argument("--refresh", type=float, default=0.5, metavar="S", help="screen refresh period")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S", help="heartbeat age that counts as link lost")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="exit after S seconds (default: Ctrl-C)")
    p.add_argument("--no-color", action="store_true", help="no ANSI colours")
    p.add_argument("--channels", action="append", default=[], metavar="PATTERN",
                   help="show only channels matching this shell pattern (repeatable), e.g. 'mission.*'")
    p.add_argument("--system", type=int, default=None, metavar="ID",
                   help="the vehicle shown in full when several share the link (MAVLink system id: 1 the "
                        "RECON-bot, 2 the Cliff-bot; default the lowest heard); the others get one line")
    p.add_argument("--steps", type=int, default=None, metavar="N",
                   help="N in 'step k of N': the value mission.step reaches at the end (imaging steps + 1 "
                        "for the panorama)")


def _terminal_rows() -> int | None:
    """The terminal's height less one line, or None when stdout has no terminal size."""
    try:
        return os.get_terminal_size(sys.stdout.fileno()).lines - 1
    except (OSError, ValueError, AttributeError):
        return None


def replay(args: argparse.Namespace, d: GroundDictionary) -> int:
    """The screens of a .tlog: at ``--speed`` times the logged pace on a terminal, else the last one."""
    from fsw.comm.mavlink_tlog import TlogError
    from ground.tlog import load_messages

    messages = []
    for url in args.url:
        try:
            got, note = load_messages(url)
        except (TlogError, OSError) as exc:
            print(f"safer-ground listen: {exc}", file=sys.stderr)
            return 2
        if note:
            print(f"safer-ground listen: warning: {note}", file=sys.stderr)
        messages += got
    messages.sort(key=lambda lm: lm.time_s)  # stable: each log keeps its own order
    title = " + ".join(args.url)
    tty = sys.stdout.isatty()
    paint = Painter(tty and not args.no_color)
    fleet = Fleet(d)
    kw = {"channels": tuple(args.channels), "steps": args.steps, "fleet": fleet}
    t_log0, t_wall0, next_draw = messages[0].time_s, time.monotonic(), messages[0].time_s
    try:
        for lm in messages:
            fleet.feed(lm.msg, lm.time_s)
            st = fleet.pick(args.system) or GroundState(d)
            if tty and args.speed > 0 and lm.time_s >= next_draw:
                next_draw = lm.time_s + args.refresh * args.speed
                time.sleep(max(0.0, (lm.time_s - t_log0) / args.speed - (time.monotonic() - t_wall0)))
                screen = render(st, d, title, lm.time_s, paint, timeout_s=args.timeout,
                                rows=_terminal_rows(), **kw)  # type: ignore[arg-type]
                sys.stdout.write("\x1b[H\x1b[2J" + screen + "\n")
                sys.stdout.flush()
    except KeyboardInterrupt:
        return 130
    st = fleet.pick(args.system) or GroundState(d)
    print(render(st, d, title, messages[-1].time_s, paint, timeout_s=args.timeout, **kw))  # type: ignore[arg-type]
    return 0


class MultiLink:
    """Several :class:`~ground.link.GroundLink` (one per vehicle link) read as one."""

    def __init__(self, links: list[Any]) -> None:
        self.links = links
        self._next = 0

    def recv(self, timeout_s: float) -> Any:
        """One message from the links in turn (each waits its share of ``timeout_s``)."""
        for _ in range(len(self.links)):
            link = self.links[self._next]
            self._next = (self._next + 1) % len(self.links)
            msg = link.recv(timeout_s=timeout_s / len(self.links))
            if msg is not None:
                return msg
        return None

    @property
    def reconnects(self) -> int:
        return sum(link.reconnects for link in self.links)

    @property
    def error(self) -> str | None:
        return next((f"{link.url}: {link.error}" for link in self.links if link.error), None)

    def close(self) -> None:
        for link in self.links:
            link.close()


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    from ground.link import GroundLink, LinkError

    if args.refresh <= 0 or args.timeout <= 0 or (args.duration is not None and args.duration < 0) or args.speed < 0:
        print("safer-ground listen: --refresh, --timeout, --duration and --speed must be positive", file=sys.stderr)
        return 2
    logs = [u.endswith(".tlog") for u in args.url]
    if all(logs):
        return replay(args, d)
    if any(logs):
        print("safer-ground listen: give links or .tlog files, not both", file=sys.stderr)
        return 2
    links: list[GroundLink] = []
    try:
        for url in args.url:
            links.append(GroundLink(url, args.baud))
    except LinkError as exc:
        for open_link in links:
            open_link.close()
        print(f"safer-ground listen: {exc}", file=sys.stderr)
        return 2
    link = MultiLink(links)
    title = " + ".join(args.url)
    tty = sys.stdout.isatty()
    paint = Painter(tty and not args.no_color)
    fleet = Fleet(d)
    t0 = time.monotonic()
    next_draw = t0
    try:
        while args.duration is None or time.monotonic() - t0 < args.duration:
            msg = link.recv(timeout_s=min(0.1, args.refresh))
            now = time.monotonic()
            if msg is not None:
                fleet.feed(msg, now)
            if tty and now >= next_draw:
                next_draw = now + args.refresh
                screen = render(fleet.pick(args.system) or GroundState(d), d, title, now, paint, link.reconnects,
                                link.error, args.timeout, channels=tuple(args.channels), rows=_terminal_rows(),
                                steps=args.steps, fleet=fleet)
                sys.stdout.write("\x1b[H\x1b[2J" + screen + "\n")
                sys.stdout.flush()
    except KeyboardInterrupt:
        pass
    finally:
        link.close()
    if not tty:
        print(render(fleet.pick(args.system) or GroundState(d), d, title, time.monotonic(), paint,
                     link.reconnects, link.error, args.timeout, channels=tuple(args.channels), steps=args.steps,
                     fleet=fleet))
    return 0
