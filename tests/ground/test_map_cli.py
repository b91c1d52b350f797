"""``safer-map`` and the distribution experiments/bench as commands (issue 6, items 4, 10, 11)."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import pytest

from fsw.settings import DEFAULT_CONFIG, load_settings
from ground.map_cli import main as safer_map
from hil_sim.cli import main as safer_hil


@pytest.fixture
def npy(tmp_path: Path, viking_map: np.ndarray) -> Path:
    z = viking_map.copy()
    z[5:40, 100:180] = np.nan
    p = tmp_path / "m.npy"
    np.save(p, z)
    return p


def test_encode_decode_info_round_trip(tmp_path: Path, npy: Path, capsys):
    """Issue 6, item 4: encode / decode / info; the bound holds, NaN stays NaN."""
    out, back = tmp_path / "m.sqm", tmp_path / "back.npy"
    assert safer_map(["encode", str(npy), str(out), "--wheel-diameter", "0.1", "--cell-m", "0.02"]) == 0
    assert safer_map(["decode", str(out), str(back)]) == 0
    assert safer_map(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "leaves" in text and "error_bound_m" in text
    # Issue 25: encode reports the obstacles given and kept; info the relief loss bounds.
    line = next(t for t in text.splitlines() if t.startswith("obstacles"))
    given, kept = (int(v) for v in line.split(": ", 1)[1].split(";")[0].replace(" given,", "").split()[:2])
    assert given > 0 and kept == given
    bound = load_settings(DEFAULT_CONFIG).codec.error_bound_wheels * 0.1  # [codec] bound at this wheel
    assert "relief_loss_bound_hazards_m 0 " in text and f"relief_loss_bound_m {2 * bound:.4g} " in text
    z, r = np.load(npy), np.load(back)
    assert r.dtype == np.float32 and np.array_equal(np.isnan(z), np.isnan(r))
    k = np.isfinite(z)
    assert np.abs(r[k] - z[k]).max() <= 0.1
    assert safer_map(["encode", str(npy), str(out), "--max-error", "0.02"]) == 0
    assert np.abs(np.load(npy)[k] - z[k]).max() == 0.0  # input untouched


@pytest.mark.parametrize("case", ["truncated", "garbage", "missing", "npy_3d", "npy_text", "not_npy",
                                  "bad_option", "bad_config"])
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, npy: Path, case: str, capsys):
    """Issue 6, item 4: bad or truncated input -> one clear line on stderr, exit code 2."""
    good = tmp_path / "good.sqm"
    assert safer_map(["encode", str(npy), str(good)]) == 0
    capsys.readouterr()
    bad = tmp_path / "bad"
    argv = ["decode", str(bad), str(tmp_path / "o.npy")]
    if case == "truncated":
        bad.write_bytes(good.read_bytes()[:-10])
    elif case == "garbage":
        bad.write_bytes(b"\x00" * 500)
    elif case == "missing":
        pass
    elif case == "npy_3d":
        np.save(tmp_path / "c.npy", np.zeros((2, 2, 2)))
        argv = ["encode", str(tmp_path / "c.npy"), str(bad)]
    elif case == "npy_text":
        np.save(tmp_path / "t.npy", np.array([["a", "b"]]))
        argv = ["encode", str(tmp_path / "t.npy"), str(bad)]
    elif case == "not_npy":
        bad.write_text("hello")
        argv = ["encode", str(bad), str(tmp_path / "x.sqm")]
    elif case == "bad_option":
        argv = ["encode", str(npy), str(bad), "--wheel-diameter", "-3"]
    elif case == "bad_config":
        cfg = tmp_path / "c.toml"
        cfg.write_text("[codec]\nsplit_rule = 'magic'\n")
        argv = ["--config", str(cfg), "encode", str(npy), str(bad)]
    assert safer_map(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("safer-map: error:")


def test_help_explains(capsys):
    """Issue 6, item 4: --help."""
    with pytest.raises(SystemExit) as exc:
        safer_map(["--help"])
    assert exc.value.code == 0
    assert "NaN = unknown" in capsys.readouterr().out


def test_experiments_and_bench_run_small(tmp_path: Path, capsys):
    """Issue 6, items 10-11: the experiments compute their tables from real runs (small)."""
    red = tmp_path / "red"
    assert safer_hil(["experiment", "reduction", "--maps", "2", "--size", "64", "--dh", "2", "8",
                      "--terrains", "", "--missions", "", "--no-dem", "--out", str(red)]) == 0
    rows = list(csv.DictReader((red / "reduction.csv").open()))
    assert len(rows) == 4 and all(float(r["max_error_m"]) <= float(r["bound_m"]) for r in rows)
    assert all(r["kept"] == r["obst"] for r in rows)
    maps = list(csv.DictReader((red / "maps.csv").open()))
    assert len(maps) == 2 and all(int(m["jls_hazard_bytes"]) > 0 for m in maps)
    assert (red / "fig12_reduction.png").stat().st_size > 5000
    assert (red / "fig13_transmitted.png").exists() and "JPEG-LS" in (red / "report.md").read_text()
    res = (Path(os.environ["SAFER_RESULTS_DIR"]) / "reduction.md").read_text()
    assert "- commit: " in res and "obstacles >= w kept" in res
    link = tmp_path / "link"
    assert safer_hil(["experiment", "link", "--bytes", "3000", "--seeds", "2", "--losses", "0", "0.1",
                      "--bers", "1e-5", "--out", str(link)]) == 0
    rows = list(csv.DictReader((link / "link_goodput.csv").open()))
    assert [r["bit_exact"] for r in rows] == ["2/2"] * 3
    assert safer_hil(["bench", "codec", "--size", "64", "--repeat", "2", "--scenario", ""]) == 0
    assert "encode ms" in capsys.readouterr().out


@pytest.mark.slow
def test_reduction_experiment_on_a_mission_like_map(tmp_path: Path):
    """Issue 25: the hazard check on a scenario's map (truth on the flight grid, noise, holes)."""
    red = tmp_path / "red"
    assert safer_hil(["experiment", "reduction", "--maps", "0", "--terrains", "lab", "--missions", "", "--no-dem",
                      "--out", str(red)]) == 0
    (m,) = list(csv.DictReader((red / "maps.csv").open()))
    assert m["kind"] == "mission-like" and int(m["known"]) < int(m["cells"])
    assert int(m["obst"]) > 0 and m["kept"] == m["obst"] and float(m["worst_peak_loss_m"]) <= 0
    assert safer_hil(["experiment", "reduction", "--maps", "0", "--terrains", "nowhere", "--missions", "",
                      "--no-dem", "--out", str(red)]) == 2
    assert safer_hil(["experiment", "reduction", "--maps", "0", "--terrains", "", "--missions", "nowhere",
                      "--no-dem", "--out", str(red)]) == 2


def _rock_checkpoint(path: Path) -> np.ndarray:
    """A mission map checkpoint: noisy ground, one 0.3 m boulder, an unmapped corner."""
    from fsw.core.geometry import MapGrid
    from fsw.core.map import checkpoint
    from fsw.core.map.elevation_map import ElevationMap

    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:64, 0:64] * 0.03
    z = rng.normal(0.0, 0.01, (64, 64)) + 0.3 * np.sqrt(np.clip(1 - ((yy - 1.0) ** 2 + (xx - 0.9) ** 2) / 0.15**2,
                                                                  0, 1))
    z[:12, 40:] = np.nan
    emap = ElevationMap(MapGrid(-1.0, -2.0, 0.03, 64, 64))
    emap.z = z.copy()
    emap.n = np.isfinite(z).astype(np.int32)
    path.write_bytes(checkpoint.encode(emap, 3, 60.0))
    return z


@pytest.mark.slow  # two spawned worker processes
def test_reduction_experiment_reads_mission_map_files(tmp_path: Path, capsys):
    """Issue 25: mission maps saved as checkpoints are checked, in worker processes, at the
    receiving rover's wheel ([codec] receiver_wheel_diameter_m: the Cliff-bot's 0.12 m)."""
    ckpt = tmp_path / "map_000003.ckpt"
    z = _rock_checkpoint(ckpt)
    red = tmp_path / "red"
    assert safer_hil(["experiment", "reduction", "--maps", "0", "--terrains", "", "--missions", "", "--no-dem",
                      "--map-files", str(ckpt), "--jobs", "2", "--out", str(red)]) == 0
    (m,) = list(csv.DictReader((red / "maps.csv").open()))
    assert m["kind"] == "file" and int(m["known"]) == int(np.isfinite(z).sum())
    bound = load_settings(DEFAULT_CONFIG).codec.error_bound_wheels * 0.12
    assert float(m["wheel_m"]) == pytest.approx(0.12) and float(m["bound_m"]) == pytest.approx(bound)
    assert int(m["obst"]) == 1 and m["kept"] == "1" and float(m["max_error_m"]) <= float(m["bound_m"])
    assert float(m["worst_relief_loss_any_m"]) <= float(m["relief_loss_any_bound_m"])
    assert float(m["step_kept"]) == 1.0
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(ckpt.read_bytes()[:-4])
    capsys.readouterr()
    assert safer_hil(["experiment", "reduction", "--maps", "0", "--terrains", "", "--missions", "", "--no-dem",
                      "--map-files", str(bad), "--out", str(red)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "map checkpoint, unreadable" in err[0]


def test_encode_reduces_for_the_receiving_rovers_wheel(tmp_path: Path, capsys):
    """Issue 25: without --wheel-diameter the map is reduced for [codec] receiver_wheel_diameter_m."""
    z = _rock_checkpoint(tmp_path / "c.ckpt")
    npy, out = tmp_path / "m.npy", tmp_path / "m.sqm"
    np.save(npy, z.astype(np.float32))
    assert safer_map(["encode", str(npy), str(out), "--cell-m", "0.03"]) == 0
    assert safer_map(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "wheel_diameter_m   0.12" in text or "wheel_diameter_m 0.12" in " ".join(text.split())


def _checkpoint_file(tmp_path: Path) -> tuple[Path, np.ndarray]:
    from fsw.core.geometry import MapGrid
    from fsw.core.map import checkpoint
    from fsw.core.map.elevation_map import ElevationMap

    emap = ElevationMap(MapGrid(-1.0, -2.0, 0.05, 40, 30))
    z = np.full((30, 40), np.nan)
    z[5:20, 10:30] = np.linspace(0.0, 0.5, 20)[None, :]
    emap.z = z.copy()
    emap.n = np.isfinite(z).astype(np.int32)
    p = tmp_path / "map_000007.ckpt"
    p.write_bytes(checkpoint.encode(emap, 7, 123.4, state={"mission": {"phase": "MOVE", "step": 3}}))
    return p, z


def test_info_and_decode_read_a_map_checkpoint(tmp_path: Path, capsys):
    """Issue 29, item 1: checkpoints are read, not rejected as 'bad magic'; known cells and NaN kept."""
    p, z = _checkpoint_file(tmp_path)
    assert safer_map(["info", str(p)]) == 0
    text = capsys.readouterr().out
    assert "map checkpoint" in text and "30 x 40 (300 known)" in text and "123.4" in text and "MOVE" in text
    back = tmp_path / "back.npy"
    assert safer_map(["decode", str(p), str(back)]) == 0
    r = np.load(back)
    assert r.dtype == np.float32 and np.array_equal(np.isnan(r), np.isnan(z))
    assert np.allclose(r[np.isfinite(z)], z[np.isfinite(z)], atol=1e-6)


@pytest.mark.parametrize(("content", "says"), [("npy", "safer-map encode"), ("tlog", "safer-ground map"),
                                                ("bad_ckpt", "map checkpoint, unreadable")])
def test_other_files_are_named_with_the_command_that_reads_them(tmp_path: Path, npy: Path, content: str,
                                                                 says: str, capsys):
    if content == "npy":
        path = npy
    elif content == "tlog":
        path = tmp_path / "fsw.tlog"
        path.write_bytes(b"\x00" * 8 + b"\xfd" + b"\x00" * 40)
    else:
        good, _ = _checkpoint_file(tmp_path)
        path = tmp_path / "bad.ckpt"
        path.write_bytes(good.read_bytes()[:-5])
    assert safer_map(["info", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0]
