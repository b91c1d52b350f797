"""``safer-hil serve``: the multi-process, real-time bench. This process plays the hardware.

It steps the hardware rig (true rover and mast over the scenario's terrain, the twelve CAN
motor controllers, the serial mast controller) on the real-time clock and serves:

* CAN through a hub on ``127.0.0.1:PORT`` (:mod:`hil_sim.hw.can_hub`; python-can interface
  ``udp_hub``), or with ``--can-multicast IFACE`` on python-can ``udp_multicast`` pinned to
  that interface;
* the mast's serial line on a pty (``/dev/pts/N``, optionally symlinked) or on
  ``socket://127.0.0.1:PORT``;
* rendered stereo pairs on ``tcp://127.0.0.1:PORT`` (:mod:`fsw.comm.camera_frames`).

It prints the endpoints and writes a flight config (``--flight-config``: the base config with
its ``[devices]`` table pointing at them), so the flight software connects with unchanged
code: ``safer-fsw run --config FILE``. The true state is printed every ``--report-period``
seconds and at exit as ``TRUTH {json}``. Stop with Ctrl-C (or SIGTERM) or ``--duration``.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

HELP = "multi-process real-time bench: play the hardware over a loopback CAN hub, a pty/socket and a camera socket"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scenario", default="lab", help="world spec (lab, cliff, mars, file:PATH) or 'flat' (level ground, no camera)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of world, truth errors and faults")
    p.add_argument("--config", default=None, help="flight config the hardware is sized from (default config/fsw.toml)")
    p.add_argument("--hardware", default=None, help="hardware config (default config/hil_hardware.toml)")
    p.add_argument("--faults", default=None, help="TOML file with [[faults]] tables to inject")
    p.add_argument("--can-port", type=int, default=43113, help="CAN hub (or multicast) UDP port (0: any free)")
    p.add_argument("--can-bind", default="127.0.0.1", metavar="HOST",
                   help="address of the CAN hub; another than 127.0.0.1 lets flight software on other machines "
                        "join the bus (docs/hil.md)")
    p.add_argument("--can-multicast", default=None, metavar="IFACE",
                   help="CAN on udp_multicast on this network interface instead of the hub")
    p.add_argument("--can-group", default="239.74.163.2", help="--can-multicast: the group address")
    p.add_argument("--serial", choices=("pty", "tcp"), default="pty", help="mast serial line transport")
    p.add_argument("--serial-port", type=int, default=0, help="tcp: port to listen on (0: any free)")
    p.add_argument("--pty-link", default=None, help="pty: also make this symlink to the slave device")
    p.add_argument("--camera-port", type=int, default=0, help="camera server port (0: any free)")
    p.add_argument("--camera-timeout", type=float, default=8.0, metavar="S",
                   help="the flight config's [devices] camera_timeout_s: this bench renders a pair in 0.3-3.2 s "
                        "of CPU (pose dependent; a real camera ~0.1 s, the flight default 2 s)")
    p.add_argument("--rate-hz", type=float, default=50.0, help="hardware model update rate")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--report-period", type=float, default=1.0, metavar="S", help="truth report period (0: none)")
    p.add_argument(
        "--flight-config", default=None, metavar="FILE", help="write the flight config for these endpoints here"
    )
    p.add_argument("--can-log", default=None, metavar="FILE", help="record the CAN traffic (.log/.asc/.blf)")
    m = p.add_argument_group("ground link (written into --flight-config's [mavlink] and [checkpoint])")
    m.add_argument("--mavlink-url", default=None, metavar="URL",
                   help="the rover's MAVLink link, e.g. udpout:127.0.0.1:14550 or udpin:127.0.0.1:14560")
    m.add_argument("--key-file", default=None, metavar="FILE", help="signing key (safer-ground keygen)")
    m.add_argument("--tlog", default=None, metavar="FILE", help="telemetry log of every frame sent and received")
    m.add_argument("--checkpoint-dir", default=None, metavar="DIR", help="where the map checkpoints go")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="the mission's folder: the flight writes DIR/fsw.tlog and DIR/checkpoints (unless --tlog, "
                        "--checkpoint-dir say otherwise); when serve stops, it writes DIR/summary.json, map.png and "
                        "coverage.png as a lockstep run does, from the newest checkpoint against the truth")
    t = p.add_argument_group("team scenarios (cliff-team): the Cliff-bot's hardware and flight file")
    t.add_argument("--cliffbot-config", default=None, metavar="FILE",
                   help="write the Cliff-bot's flight file for this bench here (safer-fsw run --config FILE)")


def link_keys(args: argparse.Namespace) -> dict[str, dict[str, str]]:
    """The [mavlink] and [checkpoint] keys the serve options set (only those given)."""
    mav = {k: v for k, v in (("url", args.mavlink_url), ("key_file", args.key_file), ("tlog_path", args.tlog))
           if v is not None}
    ck = {"directory": args.checkpoint_dir} if args.checkpoint_dir is not None else {}
    return {name: keys for name, keys in (("mavlink", mav), ("checkpoint", ck)) if keys}


def set_keys(text: str, table: str, values: dict[str, str]) -> str:
    """``text`` (TOML) with ``values`` set in ``[table]`` (existing lines replaced, others added)."""
    lines = text.splitlines(keepends=True)
    start = next((i for i, ln in enumerate(lines) if ln.split("#", 1)[0].strip() == f"[{table}]"), None)
    if start is None:
        return text + f"\n[{table}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in values.items())
    end = next((j for j in range(start + 1, len(lines)) if lines[j].lstrip().startswith("[")), len(lines))
    todo = dict(values)
    for j in range(start + 1, end):
        key = lines[j].split("=", 1)[0].strip()
        if "=" in lines[j] and key in todo:
            lines[j] = f"{key} = {json.dumps(todo.pop(key))}  # set by safer-hil serve\n"
    lines[start + 1:start + 1] = [f"{k} = {json.dumps(v)}  # set by safer-hil serve\n" for k, v in todo.items()]
    return "".join(lines)


def devices_table(base: dict, endpoints: dict) -> str:
    """The ``[devices]`` TOML table: the base config's values with the endpoints set."""
    values = {**base, **endpoints}
    lines = ["[devices]  # written by safer-hil serve"]
    for k, v in values.items():
        lines.append(f"{k} = {json.dumps(v) if isinstance(v, str) else repr(v).lower() if isinstance(v, bool) else v}")
    return "\n".join(lines) + "\n"


def write_flight_config(base_path: Path, out: Path, endpoints: dict,
                        tables: dict[str, dict[str, str]] | None = None) -> None:
    """Copy ``base_path`` to ``out`` with its ``[devices]`` table replaced (comments kept) and
    the keys of ``tables`` (table -> key -> value) set."""
    import tomllib

    text = base_path.read_text()
    base = tomllib.loads(text).get("devices", {})
    lines = text.splitlines(keepends=True)
    start = next((i for i, ln in enumerate(lines) if ln.strip().startswith("[devices]")), None)
    table = devices_table(base, endpoints)
    if start is None:
        new = text + "\n" + table
    else:
        end = next((j for j in range(start + 1, len(lines)) if lines[j].lstrip().startswith("[")), len(lines))
        new = "".join(lines[:start]) + table + "\n" + "".join(lines[end:])
    for name, values in (tables or {}).items():
        new = set_keys(new, name, values)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(new)


def _open_can(args: argparse.Namespace) -> tuple[Any, Any, dict[str, Any]]:
    """The hub (None with --can-multicast), this process's bus on it, and the flight config's CAN keys."""
    from fsw.drivers.can_inproc import open_bus
    from hil_sim.hw.can_hub import CanHub

    own = args.can_log is not None  # a logger sees our frames too
    if args.can_multicast is not None:
        kw = {"interface": "udp_multicast", "channel": args.can_group, "port": args.can_port, "fd": False,
              "interface_name": args.can_multicast}
        ends = {"can_interface": "udp_multicast", "can_channel": args.can_group, "can_udp_port": args.can_port,
                "can_multicast_interface": args.can_multicast}
        return None, open_bus(**kw), ends
    hub = CanHub(args.can_bind, args.can_port).start()
    try:
        bus = open_bus(interface="udp_hub", channel=hub.channel, receive_own_messages=own)
    except Exception:
        hub.close()
        raise
    return hub, bus, {"can_interface": "udp_hub", "can_channel": hub.channel}


def run(args: argparse.Namespace) -> int:
    import can

    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.faults import FaultInjector, load_faults
    from hil_sim.hw.camera_server import CameraServer
    from hil_sim.hw.ports import PtyDevicePort, TcpDevicePort
    from hil_sim.rig import DEFAULT_HARDWARE, HardwareRig, load_hardware

    if args.rate_hz <= 0 or (args.duration is not None and args.duration <= 0) or not args.camera_timeout > 0:
        print("safer-hil serve: --rate-hz, --duration and --camera-timeout must be positive", file=sys.stderr)
        return 2
    if args.out is not None:
        args.tlog = args.tlog or str(args.out / "fsw.tlog")
        args.checkpoint_dir = args.checkpoint_dir or str(args.out / "checkpoints")
        if args.scenario == "flat":
            print("safer-hil serve: --out needs a scenario (a 'flat' bench has no truth to report against)",
                  file=sys.stderr)
            return 2
    if link_keys(args) and not args.flight_config:
        print("safer-hil serve: --mavlink-url, --key-file, --tlog and --checkpoint-dir go into the flight "
              "config: give --flight-config FILE too", file=sys.stderr)
        return 2
    base_cfg = Path(args.config or DEFAULT_CONFIG)
    try:
        fsw = load_settings(base_cfg)
        hw = load_hardware(args.hardware or DEFAULT_HARDWARE)
        faults = load_faults(args.faults) if args.faults else ()
        world = None
        if args.scenario != "flat":
            from hil_sim.world import load_scenario

            world = load_scenario(args.scenario, args.seed)
    except (ConfigError, ValueError) as err:
        print(f"safer-hil serve: {err}", file=sys.stderr)
        return 2
    if not 0 <= args.can_port < 65536 or (args.can_multicast is not None and args.can_port == 0):
        print("safer-hil serve: --can-port must be 0-65535 (1-65535 with --can-multicast)", file=sys.stderr)
        return 2
    try:
        hub, bus, can_ends = _open_can(args)
    except (can.CanError, OSError, ValueError) as err:
        print(f"safer-hil serve: cannot open the CAN bus: {err}", file=sys.stderr)
        return 2
    port = PtyDevicePort(args.pty_link) if args.serial == "pty" else TcpDevicePort("127.0.0.1", args.serial_port)
    serial_url = port.path if isinstance(port, PtyDevicePort) else port.url
    injector = FaultInjector(args.seed, faults)
    if world is not None and world.team is not None:  # the RECON-bot maps on the scenario's grid
        import dataclasses

        fsw = dataclasses.replace(fsw, map=world.map_grid)
    rig = HardwareRig(world, fsw, hw, args.seed, bus, port, injector)
    team = None
    if world is not None and world.team is not None:
        from hil_sim.team.team_serve import TeamHardware

        try:
            team = TeamHardware(world, rig, fsw, args.seed, injector)
        except (can.CanError, OSError, ValueError, ConfigError) as err:
            print(f"safer-hil serve: cannot set up the Cliff-bot's hardware: {err}", file=sys.stderr)
            port.close()
            bus.shutdown()
            if hub is not None:
                hub.close()
            return 2
    camera = (
        CameraServer(rig.render_pair, injector, "127.0.0.1", args.camera_port).start() if world is not None else None
    )
    logger = can.Logger(args.can_log) if args.can_log else None
    if logger is not None:  # the bus echoes our own frames when logging: the log has every frame
        rig.motors.tap = logger.on_message_received
    endpoints = {
        **can_ends,
        "serial_url": serial_url,
        "camera_source": f"tcp://{camera.address[0]}:{camera.address[1]}" if camera else "none",
    }
    if camera is not None:  # the bench's renderer, not a real camera, sets how long a pair takes
        endpoints["camera_timeout_s"] = args.camera_timeout
    print(f"safer-hil serve: hardware up (scenario {args.scenario}, seed {args.seed}, {args.rate_hz:g} Hz)")
    print(f"  CAN     {bus.channel_info} (DBC config/rover.dbc)")
    print(f"  serial  {serial_url}" + (f" (link {args.pty_link})" if args.pty_link else ""))
    print(f"  camera  {endpoints['camera_source']}")
    if team is not None:
        print(f"  team    CAN udp_hub {team.hub.channel} (DBC config/team.dbc), radio udp 127.0.0.1:{team.radio[0]}"
              f" <-> 127.0.0.1:{team.radio[1]}")
    if args.flight_config:
        tables = link_keys(args)
        if team is not None:
            m = fsw.map
            tables = {**tables, "link": team.recon_link(), "cliffbot_site": team.recon_site(fsw),
                      "map": {"origin_x_m": m.origin_x_m, "origin_y_m": m.origin_y_m, "cell_m": m.cell_m,
                              "nx": m.nx, "ny": m.ny},
                      # a team keeps its map in step both ways, as the lockstep team mission does
                      "map_sync": {"enabled": True}}
        write_flight_config(base_cfg, Path(args.flight_config), endpoints, tables)
        print(f"  flight  safer-fsw run --config {args.flight_config}")
    if team is not None and args.cliffbot_config:
        text = team.config.read_text(encoding="utf-8")
        for name, values in team.cliffbot_tables(fsw).items():
            text = set_keys(text, name, values)
        Path(args.cliffbot_config).parent.mkdir(parents=True, exist_ok=True)
        Path(args.cliffbot_config).write_text(text, encoding="utf-8")
        print(f"  cliffbot  safer-fsw run --config {args.cliffbot_config}")
    print("READY", flush=True)

    stop = {"flag": False}

    def _stop(*_: object) -> None:
        stop["flag"] = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    period = 1.0 / args.rate_hz
    t0 = time.monotonic()
    k, t_prev, t_report = 0, 0.0, 0.0
    datum_m = float(rig.rover.z)  # the true body height at the start: the flight map's height origin
    try:
        while not stop["flag"]:
            k += 1
            deadline = t0 + k * period
            time.sleep(max(0.0, deadline - time.monotonic()))
            now = time.monotonic() - t0
            rig.step(now, now - t_prev)
            t_prev = now
            if team is not None:
                team.step(now)
            if args.report_period and now - t_report >= args.report_period:
                t_report = now
                tr = rig.truth()
                print(
                    f"[{now:8.2f}] x {tr['x_m']:.3f} y {tr['y_m']:.3f} yaw {tr['yaw_deg']:.1f} deg  "
                    f"pan {tr['pan_deg']:.1f} tilt {tr['tilt_deg']:.1f} lift {tr['lift_m']:.3f}  "
                    f"can rx {rig.motors.rx_commands} tx {rig.motors.tx_frames}  mast acks {rig.mast_ctrl.acks}",
                    flush=True,
                )
            if args.duration is not None and now >= args.duration:
                break
    finally:
        print(
            "TRUTH "
            + json.dumps(
                {
                    **rig.truth(),
                    "can_commands": rig.motors.rx_commands,
                    "can_bad": rig.motors.rx_bad,
                    "mast_moves": rig.mast_ctrl.moves,
                    "camera_served": camera.served if camera else 0,
                    **(team.truth() if team is not None else {}),
                }
            ),
            flush=True,
        )
        if camera is not None:
            camera.close()
        if team is not None:
            team.close()
        port.close()
        bus.shutdown()
        if hub is not None:
            hub.close()
        if logger is not None:
            logger.stop()
    if args.out is not None and world is not None:
        return _report(args, world, fsw.mission.method, datum_m)
    return 0


def _report(args: argparse.Namespace, world: Any, method: str, datum_m: float) -> int:
    """The real-time mission's summary.json and pictures (``hil_sim.mission.mission_report.checkpoint_report``)."""
    from fsw.framework.storage import StorageError
    from hil_sim.mission.mission_report import checkpoint_report

    try:
        s = checkpoint_report(args.out, Path(args.checkpoint_dir), world, scenario=args.scenario, seed=args.seed,
                              method=method, datum_m=datum_m)
    except (ValueError, StorageError) as exc:
        print(f"safer-hil serve: {exc}", file=sys.stderr)
        return 1
    rmse = "n/a" if s["map_rmse_m"] is None else f"{1000 * s['map_rmse_m']:.1f} mm"
    print(f"report: {args.out / 'summary.json'} ({len(s['steps'])} steps, {s['mapped_cells']} cells mapped, "
          f"RMSE {rmse}; map.png, coverage.png)", flush=True)
    return 0
