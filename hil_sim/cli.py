"""``safer-hil``: the HIL bench, its benchmarks and the paper's experiments.

Each subcommand lives in its own module under ``hil_sim.commands`` with ``HELP`` (one
line), ``add_arguments(parser)`` and ``run(args) -> int``. Modules import their heavy
dependencies inside ``run`` so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# (group, name) -> module. Group "" is a top-level subcommand.
COMMANDS: dict[tuple[str, str], str] = {
    ("", "demo"): "hil_sim.commands.demo",
    ("", "run"): "hil_sim.commands.run",
    ("", "render"): "hil_sim.commands.render",
    ("", "serve"): "hil_sim.commands.serve",
    ("", "cliffbot"): "hil_sim.commands.cliffbot",
    ("", "send-map"): "hil_sim.commands.send_map",
    ("", "relay"): "hil_sim.commands.relay",
    ("", "calibration-target"): "hil_sim.commands.calibration_target",
    ("", "campaign"): "hil_sim.commands.campaign",
    ("bench", "render"): "hil_sim.lab.bench.bench_render",
    ("bench", "lockstep"): "hil_sim.lab.bench.bench_lockstep",
    ("bench", "perception"): "hil_sim.lab.bench.bench_perception",
    ("bench", "nbv"): "hil_sim.lab.bench.bench_nbv",
    ("bench", "codec"): "hil_sim.lab.bench.bench_codec",
    ("bench", "e2e"): "hil_sim.lab.bench.bench_e2e",
    ("bench", "calibration"): "hil_sim.lab.bench.bench_calibration",
    ("bench", "stereo-real"): "hil_sim.lab.bench.bench_stereo_real",
    ("bench", "cycle"): "hil_sim.lab.bench.bench_cycle",
    ("bench", "planner"): "hil_sim.lab.bench.bench_planner",
    ("experiment", "coverage"): "hil_sim.lab.experiments.experiment_coverage",
    ("experiment", "reduction"): "hil_sim.lab.experiments.experiment_reduction",
    ("experiment", "link"): "hil_sim.lab.experiments.experiment_link",
    ("experiment", "resume"): "hil_sim.lab.experiments.experiment_resume",
    ("experiment", "terrain"): "hil_sim.lab.experiments.experiment_terrain",
    ("experiment", "ground"): "hil_sim.lab.experiments.experiment_ground",
    ("experiment", "close-edge"): "hil_sim.lab.experiments.experiment_close_edge",
    ("experiment", "camera-path"): "hil_sim.lab.experiments.experiment_camera_path",
    ("experiment", "registration"): "hil_sim.lab.experiments.experiment_registration",
    ("experiment", "fiducials"): "hil_sim.lab.experiments.experiment_fiducials",
    ("experiment", "team"): "hil_sim.lab.experiments.experiment_team",
    ("experiment", "team-mission"): "hil_sim.lab.experiments.experiment_team_mission",
    ("experiment", "sync"): "hil_sim.lab.experiments.experiment_sync",
    ("experiment", "face-map"): "hil_sim.lab.experiments.experiment_face_map",
    ("experiment", "team-sensing"): "hil_sim.lab.experiments.experiment_team_sensing",
    ("experiment", "prediction"): "hil_sim.lab.prediction_check",
}

GROUP_HELP = {
    "bench": "benchmarks that print figures (speed, accuracy)",
    "experiment": "the paper's experiments: CSV, markdown tables and PNG plots",
}


def build_parser(only: tuple[str, str] | None = None) -> argparse.ArgumentParser:
    """The command line of every subcommand, or of ``only`` (``(group, name)``) alone: its module
    is then the only one imported. :func:`main` builds that when the arguments name a command, so
    a mission's start does not import the forty command modules (the lab's pandas among them) to
    parse its own options; the help of the whole tool and a misspelt command get every one."""
    parser = argparse.ArgumentParser(
        prog="safer-hil",
        description="MIT-SAFER hardware-in-the-loop bench: simulated worlds and hardware, "
        "lockstep missions, benchmarks and the paper's experiments.",
    )
    top = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    groups: dict[str, argparse._SubParsersAction[argparse.ArgumentParser]] = {}
    for (group, name), modname in COMMANDS.items():
        if only is not None and (group, name) != only:
            continue
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
            continue  # not built yet
        if group:
            if group not in groups:
                gp = top.add_parser(group, help=GROUP_HELP[group], description=GROUP_HELP[group])
                groups[group] = gp.add_subparsers(dest="sub", metavar="WHAT", required=True)
            sub = groups[group]
        else:
            sub = top
        p = sub.add_parser(
            name,
            help=mod.HELP,
            description=getattr(mod, "DESCRIPTION", mod.HELP),
            formatter_class=DefaultsOnce,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _hint=getattr(mod, "resume_hint", None))
    return parser


class DefaultsOnce(argparse.ArgumentDefaultsHelpFormatter):
    """Adds "(default: X)" only where the help does not already say the default and X is a value."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if "default" in text.lower() or action.default in (None, "", argparse.SUPPRESS):
            return text
        return super()._get_help_string(action)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser(named_command(sys.argv[1:] if argv is None else argv)).parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted" + _resume_hint(args), file=sys.stderr)
        return 130
    except ModuleNotFoundError as exc:
        if exc.name != "pandas":
            raise
        print("safer-hil: the lab's tables need pandas: pip install -e '.[lab]'", file=sys.stderr)
        return 1


def named_command(argv: Sequence[str]) -> tuple[str, str] | None:
    """The ``(group, name)`` of :data:`COMMANDS` that the arguments begin with, if any."""
    if argv and ("", argv[0]) in COMMANDS:
        return "", argv[0]
    if len(argv) > 1 and (argv[0], argv[1]) in COMMANDS:
        return argv[0], argv[1]
    return None


def _resume_hint(args: argparse.Namespace) -> str:
    """``; continue it with: safer-hil run --resume DIR`` when an interrupted run left a mission
    (the run command's ``resume_hint``; other commands have none)."""
    hint = getattr(args, "_hint", None)
    return hint(args) if hint is not None else ""


if __name__ == "__main__":
    sys.exit(main())
