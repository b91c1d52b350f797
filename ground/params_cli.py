"""``safer-ground params``: the rover's MAVLink parameters (PARAM protocol) and the config keys they are.

A MAVLink parameter id has at most 16 characters, so every numeric or boolean key of the
flight configuration gets a short id (``fsw.comm.mavlink_params``); this prints the table
``ID  KEY  VALUE  SET`` for a configuration, ``SET`` = ``run time`` for the keys a signed
PARAM_SET applies at once, ``start-up`` for those it refuses (edit the config file).
``--grep TEXT`` keeps the rows whose id or key contains TEXT (case-insensitive).
"""

from __future__ import annotations

import argparse

from ground.dictionary import GroundDictionary

HELP = "list the rover's MAVLink parameters: short id, config key, value, whether PARAM_SET applies it"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--grep", default="", metavar="TEXT", help="only ids or keys containing TEXT")


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    from fsw.comm import mavlink_params as mp
    from fsw.settings import load_settings
    from fsw.tasks.mavlink_gcs import RUNTIME_KEYS

    cfg = load_settings(args.config)
    needle = args.grep.lower()
    for p in mp.build_table(cfg):
        if needle and needle not in p.pid.lower() and needle not in p.key.lower():
            continue
        live = p.path[0] == "mavlink" and len(p.path) == 2 and p.path[1] in RUNTIME_KEYS
        print(f"{p.pid:<16}  {p.key:<44}  {mp.value_of(cfg, p)!s:<12}  {'run time' if live else 'start-up'}")
    return 0
