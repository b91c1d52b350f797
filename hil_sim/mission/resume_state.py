"""The bench's part of a mission checkpoint: world truth and random generators (docs/hil.md).

A lockstep resume is deterministic only if the simulated world continues exactly where it
stood when the flight software wrote its step checkpoint: the true rover (pose, wheels,
slip noise and its generator), the true mast, the renderer's noise generator, the fault
injector's generator, the radio channel's generator, the bench clock and frame. The flight
software knows nothing of this: the bench registers ``checkpoint_hooks["bench"]`` as a
resource, the sequencer stores what it returns in the same checkpoint as the map
(``fsw.tasks.mission_checkpoint``), and ``restore_bench`` puts it back before the first
resumed frame. The CAN motor controllers and the serial mast controller are separate nodes
that go on running while the flight computer restarts, so their state (enabled, set-points,
latched faults, status timing) is restored too; the flight software's drivers start afresh.

State is taken generically from an object's plain attributes (numbers, booleans, strings,
None, numeric numpy arrays, numpy generators); references to other objects are not state.
"""

from __future__ import annotations

from typing import Any

import numpy as np

SECTION = "bench"


class BenchStateError(ValueError):
    """A bench section that does not fit this bench (missing or malformed parts)."""


def attrs_state(obj: Any, only: tuple[str, ...] | None = None) -> dict[str, Any]:
    """The plain attributes of ``obj`` (or just those named in ``only``) as JSON-able values."""
    out: dict[str, Any] = {}
    for k, v in vars(obj).items():
        if only is not None and k not in only:
            continue
        if isinstance(v, np.random.Generator):
            out[k] = {"rng": v.bit_generator.state}
        elif isinstance(v, np.ndarray) and v.dtype.kind in "biuf":
            out[k] = {"array": v.tolist(), "dtype": v.dtype.str}
        elif isinstance(v, (set, frozenset)) and all(isinstance(e, str) for e in v):
            out[k] = {"set": sorted(v)}
        elif v is None or isinstance(v, (bool, int, float, str)):
            out[k] = {"v": v}
        elif isinstance(v, (np.floating, np.integer, np.bool_)):
            out[k] = {"v": v.item()}
    return out


def restore_attrs(obj: Any, state: dict[str, Any]) -> None:
    """Put ``attrs_state`` values back (attributes that are not in ``state`` keep theirs)."""
    for k, d in state.items():
        if not hasattr(obj, k):
            raise BenchStateError(f"{type(obj).__name__} has no attribute {k!r}")
        if "rng" in d:
            getattr(obj, k).bit_generator.state = d["rng"]
        elif "set" in d:
            setattr(obj, k, set(d["set"]))
        elif "array" in d:
            setattr(obj, k, np.asarray(d["array"], dtype=np.dtype(d["dtype"])))
        else:
            setattr(obj, k, d["v"])


# Objects whose state is only some of their attributes (the renderer's textures are not state).
_ONLY: dict[str, tuple[str, ...]] = {"renderer": ("_rng",), "faults": ("rng",)}


def _parts(bench: Any, extra: dict[str, Any]) -> dict[str, Any]:
    """The stateful objects of a bench run, by name."""
    rig = bench.rig
    parts: dict[str, Any] = {"rover": rig.rover, "mast": rig.mast, "faults": bench.faults,
                             "motors": rig.motors, "mast_ctrl": rig.mast_ctrl}
    parts.update({f"axis.{name}": ax for name, ax in rig.motors.axes.items()})
    if getattr(rig, "imu", None) is not None:
        parts["imu"] = rig.imu  # the attitude sensor's noise stream, bias and counter
    if rig.world is not None and bench.camera is not None:
        parts["renderer"] = rig.renderer()
    parts.update(extra)
    return parts


def bench_state(
    bench: Any, extra: dict[str, Any] | None = None, counters: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The bench section of a checkpoint (called by the sequencer through the hook)."""
    return {
        "t_last_s": bench._t_last,
        "rig_now_s": bench.rig.now,
        "parts": {name: attrs_state(obj, _ONLY.get(name)) for name, obj in _parts(bench, extra or {}).items()},
        "counters": dict(counters or {}),
    }


def restore_bench(bench: Any, state: dict[str, Any], extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Restore a bench (built with the checkpoint's clock and frame) from its section; returns
    the runner's counters. ``BenchStateError`` if the section does not fit."""
    try:
        parts = _parts(bench, extra or {})
        missing = sorted(set(state["parts"]) ^ set(parts))
        if missing:
            raise BenchStateError(f"bench parts differ: {', '.join(missing)}")
        for name, obj in parts.items():
            restore_attrs(obj, state["parts"][name])
        bench._t_last = float(state["t_last_s"])
        bench.rig.now = float(state["rig_now_s"])
        return dict(state["counters"])
    except BenchStateError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise BenchStateError(f"malformed bench state ({type(exc).__name__}: {exc})") from None
