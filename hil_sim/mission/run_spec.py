"""What a lockstep mission run is, before the bench starts: its spec (:class:`RunSpec`), the flight
configuration it runs with (:func:`mission_config`), its manifest in the out directory
(``run.json``: :func:`write_manifest`, :func:`read_manifest`) and the out directory made ready for
a new, fresh or resumed run (:func:`prepare_store`; docs/hil.md, "Resuming a mission").
:func:`hil_sim.mission.mission_run.run_mission` runs it."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fsw.core.geometry import MapGrid
from fsw.drivers.map_store import MapStore
from fsw.framework.storage import StorageError, describe
from fsw.settings import DEFAULT_CONFIG, FswConfig, load_settings
from hil_sim.faults import FaultSpec
from hil_sim.mission.run_dir import MANIFEST, check_room, has_mission

MODES = ("new", "fresh", "resume")


class MissionExistsError(ValueError):
    """The out directory holds a mission and neither resuming nor starting afresh was asked."""


@dataclass(frozen=True)
class RunSpec:
    scenario: str = "lab"
    method: str = "5"
    steps: int = 20
    seed: int = 0
    config: str = str(DEFAULT_CONFIG)
    transmit: bool = True
    out: Path | None = None
    hardware: str = str(DEFAULT_CONFIG.parent / "hil_hardware.toml")
    cpu_timer: bool = False  # time tasks in thread CPU time (benches on a loaded machine)
    camera: str = "config"  # config: as the files say; ideal: ideal pinhole pair; raw: real lenses, no rectification
    faults: tuple[FaultSpec, ...] = ()  # injected through the bench's fault backdoor
    safe_recover_s: float | None = None  # override of mission.safe_recover_s (None: the file's)


CAMERA_MODES = ("config", "ideal", "raw")


def mission_config(spec: RunSpec, world: Any) -> FswConfig:
    """The flight configuration of the run: the file, with the scenario's map and the method."""
    cfg = load_settings(spec.config)
    mav = cfg.mavlink
    if spec.out is not None:
        mav = dataclasses.replace(mav, tlog_path=str(spec.out / "fsw.tlog"))
    ckpt = cfg.checkpoint
    if spec.out is not None:
        ckpt = dataclasses.replace(ckpt, directory=str(spec.out / "checkpoints"))
    if spec.camera not in CAMERA_MODES:
        raise ValueError(f"camera mode {spec.camera!r}: expected one of {', '.join(CAMERA_MODES)}")
    camera = cfg.camera
    if spec.camera in ("ideal", "raw"):
        camera = dataclasses.replace(camera, calibration_file="")
    site, sync = cfg.cliffbot_site, cfg.map_sync
    if world.team is not None:  # a team scenario: the RECON-bot keeps the Cliff-bot out of its map
        from hil_sim.team.team_bench import recon_site

        site = recon_site(world, MapGrid.from_config(world.map_grid), cfg.tether)
        sync = dataclasses.replace(sync, enabled=True)  # and keeps the team's map in step (docs/sync.md)
    return dataclasses.replace(
        cfg,
        cliffbot_site=site,
        map_sync=sync,
        camera=camera,
        map=world.map_grid,
        mavlink=mav,
        checkpoint=ckpt,
        mission=dataclasses.replace(
            cfg.mission,
            method=spec.method,
            transmit=spec.transmit,
            auto_start=True,
            safe_recover_s=cfg.mission.safe_recover_s if spec.safe_recover_s is None else spec.safe_recover_s,
        ),
        nbv=dataclasses.replace(
            cfg.nbv, max_steps=spec.steps,
            # a team scenario: the RECON-bot's views favour what the Cliff-bot's task needs (docs/team.md)
            focus_regions=cfg.nbv.focus_regions or (world.team.focus_regions() if world.team is not None else ())),
    )


def write_manifest(spec: RunSpec) -> None:
    assert spec.out is not None
    d = {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(spec).items()}
    tmp = spec.out / (MANIFEST + ".tmp")
    try:
        tmp.write_text(json.dumps({"schema": 1, "spec": d}, indent=2) + "\n")
        tmp.replace(spec.out / MANIFEST)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise StorageError(exc.errno, f"{spec.out / MANIFEST} not written: {describe(exc)}") from None


def read_manifest(out: Path) -> RunSpec:
    """The ``RunSpec`` of the mission in ``out``; ``ValueError`` with the reason if unusable."""
    path = out / MANIFEST
    try:
        d = json.loads(path.read_text())["spec"]
        recover = d.get("safe_recover_s")
        return RunSpec(str(d["scenario"]), str(d["method"]), int(d["steps"]), int(d["seed"]), str(d["config"]),
                       bool(d["transmit"]), out, hardware=str(d.get("hardware", RunSpec.hardware)),
                       camera=str(d.get("camera", "config")),
                       faults=tuple(FaultSpec(**f) for f in d.get("faults", ())),
                       safe_recover_s=None if recover is None else float(recover))
    except FileNotFoundError:
        raise ValueError(f"{out} holds no mission to resume (no {MANIFEST})") from None
    except (OSError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path} is unreadable ({type(exc).__name__}: {exc})") from None


def prepare_store(spec: RunSpec, cfg: FswConfig, mode: str) -> tuple[MapStore | None, tuple[float, int] | None,
                                                                    dict[str, Any] | None]:
    """The run's map store, and for a resume the bench start (clock, frame) and bench state."""
    from fsw.tasks.mission_state import StateError, check_schema, fingerprint

    if spec.out is None:
        return None, None, None
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}")
    try:
        spec.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StorageError(exc.errno, f"{spec.out}: cannot be made ({describe(exc)})") from None
    store = MapStore(cfg.checkpoint, cfg.fusion)
    if mode == "new" and has_mission(spec.out):
        raise MissionExistsError(f"{spec.out} holds a mission; --resume {spec.out} continues it, --fresh deletes it")
    if mode != "resume":
        store.clear()  # (fresh) the old mission's files go first: their room counts
        check_room(spec.out, store)
        write_manifest(spec)
        return store, None, None
    check_room(spec.out, store)
    loaded = store.restore()
    if loaded.emap is None and loaded.skipped:
        reasons = "; ".join(f"{p.name}: {r}" for p, r in loaded.skipped)
        raise ValueError(f"no usable checkpoint in {store.dir} ({reasons})")
    if loaded.state is None:  # stopped before its first step ended: that step starts again
        store.clear()
        return MapStore(cfg.checkpoint, cfg.fusion), None, None
    try:
        check_schema(loaded.state, fingerprint(cfg))
        bench = loaded.state["hooks"]["bench"]
        start = (float(loaded.state["time_s"]), int(loaded.state["frame"]) + 1)
    except StateError as exc:
        raise ValueError(f"checkpoint {loaded.path} cannot be resumed: {exc}") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"checkpoint {loaded.path} has no usable bench state ({exc})") from None
    return store, start, bench
