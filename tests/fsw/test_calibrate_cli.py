"""`safer-hil calibration-target` and `safer-hil bench calibration`: usage errors are one
line and exit 2; the target command writes the pairs `safer-fsw calibrate` reads."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from hil_sim.cli import main as hil_main


@pytest.mark.parametrize("argv", [
    ["calibration-target", "--views", "0"],
    ["calibration-target", "--scenario", "nowhere"],
    ["calibration-target", "--hardware", "/nonexistent/hw.toml"],
    ["bench", "calibration", "--views", "2"],
    ["bench", "calibration", "--config", "/nonexistent/fsw.toml"],
])
def test_bad_arguments_exit_2_with_one_line(argv: list[str], tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert hil_main([*argv, *(["--out", str(tmp_path)] if argv[0] == "calibration-target" else [])]) == 2
    err = capsys.readouterr().err.strip()
    assert err and "\n" not in err and "Traceback" not in err


def test_target_pairs_are_written_for_calibrate(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert hil_main(["calibration-target", "--views", "2", "--out", str(tmp_path)]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["left_00.png", "left_01.png", "right_00.png", "right_01.png"]
    img = cv2.imread(str(tmp_path / "left_00.png"), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.shape == (480, 640)
    assert "safer-fsw calibrate" in capsys.readouterr().out
