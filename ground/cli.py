"""``safer-ground``: the operator's MAVLink tools for the RECON-bot (docs/ground.md).

Subcommands: ``listen`` (live view), ``send`` (signed command), ``plot`` (PNG plots of a
.tlog), ``map`` (map preview from a .tlog), ``params`` (the MAVLink parameter table), ``gcs-check``
(behave as a stock ground station and report what was answered), ``rerun`` (a mission's MCAP
as a rerun recording), ``record`` (a Foxglove recording from a .tlog),
``keygen`` (a new signing key). Channel names,
limits, commands and budgets come from the flight configuration (``--config``). Exit code 2
on usage errors, bad files and bad configuration.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from fsw.settings import DEFAULT_CONFIG

SUBCOMMANDS = {"listen": "ground.listen", "send": "ground.send", "plot": "ground.plot", "map": "ground.map_image",
               "params": "ground.params_cli", "gcs-check": "ground.gcs_check", "rerun": "ground.rerun_cli",
               "record": "ground.record_cli"}
KEYGEN_HELP = "write a new random 32-byte signing key (hex, mode 0600); give the same file to the rover"


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.ArgumentDefaultsHelpFormatter
    p = argparse.ArgumentParser(prog="safer-ground", formatter_class=fmt,
                description="Ground tools for the MIT-SAFER RECON-bot over MAVLink 2 (pymavlink, common dialect): "
                            "watch it live, send signed commands, plot and extract maps from .tlog logs.")
    p.add_argument("--config", default=str(DEFAULT_CONFIG),
                   help="flight configuration the rover runs (dictionary: channel names, limits, commands)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, modname in SUBCOMMANDS.items():
        mod = importlib.import_module(modname)
        sp = sub.add_parser(name, help=mod.HELP, description=(mod.__doc__ or mod.HELP).strip(),
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(sp)
        sp.set_defaults(_module=mod)
    k = sub.add_parser("keygen", help=KEYGEN_HELP, description=KEYGEN_HELP)
    k.add_argument("file", metavar="FILE", nargs="?",
                   help="key file to create (refuses to overwrite; its folder is created, mode 0700)")
    k.add_argument("--out", metavar="FILE", help="the same as FILE")
    k.add_argument("--passphrase-stdin", action="store_true",
                   help="derive the key from a passphrase read from stdin, as MAVProxy's `signing key "
                        "PASSPHRASE` does (SHA-256), so MAVProxy can sign commands too")
    k.set_defaults(_module=None)
    return p


def _keygen(path: str, from_stdin: bool) -> int:
    from pathlib import Path

    from fsw.comm.mavlink_signing import key_from_passphrase, write_key

    key = None
    path = str(Path(path).expanduser())
    if from_stdin:
        passphrase = sys.stdin.readline().strip()
        if len(passphrase) < 8 or not passphrase.isascii() or any(c.isspace() for c in passphrase):
            print("safer-ground keygen: the passphrase must be one ASCII word of at least 8 characters "
                  "(MAVProxy's `signing key` takes one word)", file=sys.stderr)
            return 2
        key = key_from_passphrase(passphrase)
    try:
        Path(path).parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        write_key(path, key)
    except FileExistsError:
        print(f"safer-ground keygen: {path} exists; not overwritten", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"safer-ground keygen: {path}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"{path}: new signing key (mode 0600). Set [mavlink] key_file on the rover to a copy of it.")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args._module is None:
        if (args.file is None) == (args.out is None):
            parser.error("keygen: give the key file once, as FILE or --out FILE")
        return _keygen(args.file or args.out, args.passphrase_stdin)
    from fsw.framework.params import ConfigError
    from ground.dictionary import load_dictionary

    try:
        d = load_dictionary(args.config)
    except ConfigError as err:
        print(f"safer-ground: config error: {err}", file=sys.stderr)
        return 2
    except (KeyError, TypeError, ImportError) as err:  # e.g. a task kind this build does not have
        print(f"safer-ground: config error: {args.config}: {err}", file=sys.stderr)
        return 2
    try:
        return int(args._module.run(args, d))
    except BrokenPipeError:
        return 0
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
