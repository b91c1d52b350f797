"""The bench's Cliff-bot on two tethers: the true pose follows the winches, violations are flagged."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from fsw.comm.team.team_can import Attitude, TeamCan, WinchStatus
from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.world import load_scenario

GRID = MapGrid(-2.5, -9.0, 0.04, 256, 256)


@pytest.fixture(scope="module")
def world() -> Any:
    return load_scenario("cliff-team", 3)


def _drive(rig: CliffbotRig, codec: TeamCan, rate: float, seconds: float, t0: float = 0.0) -> float:
    now = t0
    for k in range(round(seconds / 0.1)):
        now = t0 + 0.1 * (k + 1)
        frames = [codec.winch_command(w, rate, True, False, k + 1) for w in ("WINCH_A", "WINCH_B")]
        rig.to_rig(frames, now)
        rig.step(0.1, now)
    return now


def test_paying_out_lowers_the_cliffbot_over_the_lip(world: Any) -> None:
    rig = CliffbotRig(world, GRID, TetherConfig(), ClimberConfig())
    codec = TeamCan()
    y0 = float(rig.xy[1])
    _drive(rig, codec, 0.1, 6.0)
    assert float(rig.xy[1]) < y0 - 0.4  # down the fall line, away from the anchors
    assert rig.violations["slack"] == 0
    roll, pitch, _ = rig.attitude_deg()
    assert pitch < -20.0  # nose down on the face
    statuses = [codec.decode(f, d, epoch=None) for f, d in rig.poll(10.0)]
    winches = [s for s in statuses if isinstance(s, WinchStatus)]
    assert len(winches) == 2 and all(s.tension_n > 0 for s in winches)
    assert any(isinstance(s, Attitude) for s in statuses)


def test_spool_and_tension_violations_are_counted(world: Any) -> None:
    rig = CliffbotRig(world, GRID, TetherConfig(spool_m=2.2, t_max_n=30.0), ClimberConfig())
    codec = TeamCan()
    _drive(rig, codec, 0.1, 8.0)
    assert rig.violations["tension"] > 0  # over 30 N on the face
    rig.winches["WINCH_A"].paid_out_m = 2.3  # past the spool (a slip would do this)
    rig.step(0.1, 9.0)
    assert rig.violations["spool"] >= 1


def test_a_world_without_a_team_is_refused() -> None:
    with pytest.raises(ValueError, match="no team"):
        CliffbotRig(load_scenario("lab", 0), GRID, TetherConfig(), ClimberConfig())


def test_bad_wheel_frames_are_counted(world: Any) -> None:
    rig = CliffbotRig(world, GRID, TetherConfig(), ClimberConfig())
    codec = TeamCan()
    rig.to_rig([codec.wheel_command(0.0, 0.0, False, 1)], 0.05)
    fid, data = codec.wheel_command(1.0, 1.0, True, 2)
    rig.to_rig([(fid, data[:5])], 0.1)  # a short frame: refused by the decoder
    rig.to_rig([(fid, data[:-1] + bytes([data[-1] ^ 0xFF]))], 0.1)  # a bad checksum: refused by the sequence check
    assert rig.rx_bad == 1 and rig.wheel_cmd == (0.0, 0.0) and not rig.wheels_enabled
    assert np.isfinite(rig.xy).all()


def test_a_cliffbot_at_rest_is_settled_once_where_settle_puts_it(world: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """Winches holding still ask ``settle`` the same question (lengths, pose) every frame: the rig
    asks it once and keeps the answer; the pose and the tethers are still ``settle``'s, and new
    lengths are settled afresh."""
    import hil_sim.team.cliffbot_rig as rig_module

    real = rig_module.settle
    calls: list[tuple[float, float]] = []

    def counted(*args: Any, **kw: Any) -> Any:
        calls.append(args[3])
        return real(*args, **kw)

    monkeypatch.setattr(rig_module, "settle", counted)
    rig = CliffbotRig(world, GRID, TetherConfig(), ClimberConfig())
    codec = TeamCan()
    now = _drive(rig, codec, 0.1, 1.0)
    assert len(calls) == 10  # paying out: new lengths every frame
    now = _drive(rig, codec, 0.0, 1.0, now)  # the winches stop
    asked, xy = len(calls), rig.xy.copy()
    now = _drive(rig, codec, 0.0, 2.0, now)
    assert len(calls) == asked and np.array_equal(rig.xy, xy)
    lengths = (rig.winches["WINCH_A"].paid_out_m, rig.winches["WINCH_B"].paid_out_m)
    want = real(rig.z, rig.grid, rig.anchors, lengths, rig.xy, rig.tcfg)
    assert want is not None and np.array_equal(want[0], rig.xy)
    assert want[1].lengths_m == rig.state.lengths_m and want[1].statics == rig.state.statics
    rig.winches["WINCH_A"].paid_out_m += 0.05
    _drive(rig, codec, 0.0, 0.1, now)
    assert len(calls) == asked + 1 and calls[-1][0] == lengths[0] + 0.05
    assert rig.state.lengths_m[0] == pytest.approx(lengths[0] + 0.05, abs=2e-3)


def test_the_body_the_cameras_see_stands_as_its_attitude_sensor_says(world: Any) -> None:
    """Lowered over the lip, the body the RECON-bot's cameras render (and its fixes are judged
    against) is tilted with the ground under it: its up axis is the attitude sensor's (noise
    aside), its heading the rig's; at the start on the plateau it stands level."""
    from fsw.core.geometry import normal_from_attitude

    rig = CliffbotRig(world, GRID, TetherConfig(), ClimberConfig())
    level = rig.cliffbot_truth()
    assert abs(level.R[2, 2] - 1.0) < 0.02
    _drive(rig, TeamCan(), 0.1, 6.0)
    roll, pitch, yaw = rig.attitude_deg()
    body = rig.cliffbot_truth()
    assert pitch < -20.0
    np.testing.assert_allclose(body.R[:, 2], normal_from_attitude(np.radians(yaw), np.radians(roll), np.radians(pitch)),
                               atol=1e-9)
    assert abs(np.degrees(np.arctan2(body.R[1, 0], body.R[0, 0])) - yaw) < 1e-6
    np.testing.assert_allclose(body.R.T @ body.R, np.eye(3), atol=1e-12)
