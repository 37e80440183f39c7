"""estim.navigate: the navigator on a survey's files from Python.

- A stationary vehicle (IMU reading gravity and the earth's rate, DVL at zero) stays
  where it started, within its own 3-sigma, and its sigmas grow only where nothing
  observes the state (north/east position).
- The same run equals `estim navigate --json` (the Rust binary the workspace's tests
  build) to 1e-12: the final solution and the counts.
- A-KIT trajectory 2 with its recorded IMU, `vehicles/akit.toml` and `--truth`:
  the evaluation equals the binary's (data from ESTIM_DATA_DIR or ../shared/data).
- Bad input raises EstimError naming the file and line or the key.
"""

import json
import math
import os
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

import estim

ROOT = pathlib.Path(__file__).resolve().parents[2]
REQUIRED = os.environ.get("ESTIM_REQUIRE_DATA") == "1"

LAT, DEPTH, HEADING = 32.5, 20.0, 30.0
OMEGA = 7.292115e-5  # WGS-84 earth rate [rad/s]


def somigliana(lat_deg):
    """WGS-84 normal gravity at the ellipsoid [m/s^2]."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    return 9.7803253359 * (1 + 0.00193185265241 * s2) / math.sqrt(1 - 0.00669437999013 * s2)


def write_stationary(folder, seconds=120.0):
    """IMU at 100 Hz and DVL at 5 Hz of a vehicle at rest, level, heading 30 deg."""
    lat, psi = math.radians(LAT), math.radians(HEADING)
    w = (
        OMEGA * math.cos(lat) * math.cos(psi),
        -OMEGA * math.cos(lat) * math.sin(psi),
        -OMEGA * math.sin(lat),
    )
    g = somigliana(LAT)
    imu = folder / "imu.csv"
    with imu.open("w") as f:
        f.write("time_s,acc_x_mps2,acc_y_mps2,acc_z_mps2,gyro_x_radps,gyro_y_radps,gyro_z_radps\n")
        for k in range(int(seconds * 100) + 1):
            f.write(f"{1000 + k / 100:.2f},0,0,{-g!r},{w[0]!r},{w[1]!r},{w[2]!r}\n")
    dvl = folder / "dvl.csv"
    with dvl.open("w") as f:
        f.write("time_s,x_mps,y_mps,z_mps\n")
        for k in range(1, int(seconds * 5)):
            f.write(f"{1000 + k / 5:.1f},0,0,0\n")
    vehicle = folder / "vehicle.toml"
    vehicle.write_text(
        "[initial]\n"
        f"latitude_deg = {LAT}\nlongitude_deg = 34.9\ndepth_m = {DEPTH}\n"
        f"attitude_deg = [0.0, 0.0, {HEADING}]\n"
    )
    return imu, dvl, vehicle


def estim_binary():
    """The workspace's `estim` binary, or None."""
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    for candidate in (os.environ.get("ESTIM_BIN"), target / "release" / "estim"):
        if candidate and pathlib.Path(candidate).is_file():
            return pathlib.Path(candidate)
    return None


def binary_or_skip():
    exe = estim_binary()
    if exe is None:
        reason = "no estim binary (build it: cargo build --release -p estim-cli, or set ESTIM_BIN)"
        if REQUIRED:
            pytest.fail(reason)
        pytest.skip(reason)
    return exe


def test_a_vehicle_at_rest_stays_where_it_started(tmp_path):
    imu, dvl, vehicle = write_stationary(tmp_path)
    out = estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle)
    assert out["status"] == "ok"
    n = len(out["time_s"])
    assert n == 599 and set(out["kind"]) == {"dvl"}
    assert out["dvl"] == {"accepted": 599, "gated": 0, "recovered": 0}
    assert out["velocity_ned_mps"].shape == (n, 3)
    # Position error [m] against the start, within 3 sigma of the run's own sigma.
    r = 6378137.0 + 0.0
    north = math.radians(out["latitude_deg"][-1] - LAT) * r
    east = math.radians(out["longitude_deg"][-1] - 34.9) * r * math.cos(math.radians(LAT))
    sigma = out["position_sigma_m"][-1]
    assert abs(north) < 3 * sigma[0] and abs(east) < 3 * sigma[1]
    assert abs(out["depth_m"][-1] - DEPTH) < 3 * sigma[2] + 0.05
    # The DVL observes the velocity: its sigma settles well below its start.
    assert np.all(out["velocity_sigma_mps"][-1] < out["velocity_sigma_mps"][0])
    # Nothing observes the horizontal position: its sigma never shrinks.
    assert np.all(np.diff(out["position_sigma_m"][:, 0]) >= -1e-12)
    assert out["attitude_deg"][-1][2] == pytest.approx(HEADING, abs=0.5)
    assert out["evaluation"] is None and out["errors"] is None
    assert len(out["dvl_nis"]) == 599


def test_the_same_run_as_the_binary(tmp_path):
    exe = binary_or_skip()
    imu, dvl, vehicle = write_stationary(tmp_path)
    out = estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle, rate_hz=1.0)
    cli = subprocess.run(
        [exe, "navigate", "--imu", imu, "--dvl", dvl, "--vehicle", vehicle, "--rate", "1", "--json"],
        capture_output=True,
        check=True,
        text=True,
    )
    summary = json.loads(cli.stdout)
    final = summary["final"]
    assert final["time_s"] == pytest.approx(out["time_s"][-1], rel=1e-15)
    for key in ("latitude_deg", "longitude_deg", "depth_m"):
        assert final[key] == pytest.approx(out[key][-1], rel=1e-12), key
    assert final["heading_deg"] == pytest.approx(out["attitude_deg"][-1][2], rel=1e-12)
    np.testing.assert_allclose(out["position_sigma_m"][-1], final["position_sigma_m"], rtol=1e-12)
    assert final["heading_sigma_deg"] == pytest.approx(out["attitude_sigma_deg"][-1][2], rel=1e-12)
    assert summary["solutions"] == len(out["time_s"])
    assert summary["updates"]["dvl"]["accepted"] == out["dvl"]["accepted"]
    assert summary["updates"]["dvl"]["gated"] == out["dvl"]["gated"]
    assert out["kind"].count("rate") > 100


def akit_files(n):
    """Trajectory n's recorded IMU, DVL and reference, or skip (fail in CI)."""
    root = os.environ.get("ESTIM_DATA_DIR") or str(ROOT.parent / "shared" / "data")
    folder = pathlib.Path(root) / "a-kit" / f"Trajectory{n}"
    files = [folder / f"{kind}_trajectory{n}.csv" for kind in ("IMU", "DVL", "GT")]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        reason = f"A-KIT data missing: {', '.join(missing)} (set ESTIM_DATA_DIR)"
        if REQUIRED:
            pytest.fail(reason)
        pytest.skip(reason)
    return files


def test_akit_trajectory_2_with_its_recorded_imu_equals_the_binary():
    imu, dvl, gt = akit_files(2)
    exe = binary_or_skip()
    vehicle = ROOT / "vehicles" / "akit.toml"
    out = estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle, truth=gt)
    cli = subprocess.run(
        [exe, "navigate", "--imu", imu, "--dvl", dvl, "--vehicle", vehicle, "--truth", gt, "--json"],
        capture_output=True,
        check=True,
        text=True,
    )
    expected = json.loads(cli.stdout)["evaluation"]
    got = out["evaluation"]
    for key in ("horizontal_position_rmse_m", "position_rmse_m", "nees_average", "truth_time_offset_s"):
        assert got[key] == pytest.approx(expected[key], rel=1e-12), key
    assert got["epochs"] == expected["epochs"] and got["nees_states"] == 9
    assert got["truth_time_offset_source"] == expected["truth_time_offset"]["source"]
    bias = expected["truth_velocity_bias"]
    assert got["truth_velocity_bias_removed"] == bias["removed"]
    for a, b in zip(got["truth_velocity_bias_mps"], bias["bias_mps"]):
        assert abs(a - b) <= 1e-12 * max(1.0, abs(b))
    errors = out["errors"]
    assert errors["error"].shape == (got["epochs"], 9) == errors["sigma"].shape
    # The horizontal RMSE is the one of the error rows.
    horizontal = np.sqrt(np.mean(np.sum(errors["error"][:, :2] ** 2, axis=1)))
    assert horizontal == pytest.approx(got["horizontal_position_rmse_m"], rel=1e-5)
    # Navigation-grade on the recorded IMU (docs/results.md: 1.07 m).
    assert got["horizontal_position_rmse_m"] < 2.0


def test_bad_input_names_what_was_wrong(tmp_path):
    imu, dvl, vehicle = write_stationary(tmp_path, seconds=5.0)
    with pytest.raises(estim.EstimError, match="nowhere.csv"):
        estim.navigate(imu=tmp_path / "nowhere.csv", dvl=dvl, vehicle=vehicle)
    bad = tmp_path / "bad.toml"
    bad.write_text("[initial]\nlatitude_deg = 32.5\n\n[imu]\nwarp_factor = 9\n")
    with pytest.raises(estim.EstimError, match=r"bad\.toml:5.*warp_factor"):
        estim.navigate(imu=imu, dvl=dvl, vehicle=bad)
    with pytest.raises(estim.EstimError, match="no DVL file"):
        estim.navigate(imu=imu, vehicle=vehicle)
    with pytest.raises(estim.EstimError, match="rate_hz"):
        estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle, rate_hz=-1.0)
    with pytest.raises(estim.EstimError, match="init_from_truth needs"):
        estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle, init_from_truth=True)
    rows = (tmp_path / "imu.csv").read_text().splitlines()
    rows[3] = rows[3].replace(",0,0,", ",zero,0,", 1)
    (tmp_path / "imu.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(estim.EstimError, match=r"imu\.csv.*4"):
        estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle)


def test_a_diverging_run_raises_instead_of_returning(tmp_path):
    """An IMU whose z axis is reversed (gravity read upward, as an unflipped file
    reads): the DVL at rest contradicts it, the health checks stop the run, and no
    solution is returned."""
    imu, dvl, vehicle = write_stationary(tmp_path, seconds=120.0)
    rows = imu.read_text().splitlines()
    flipped = [rows[0]] + [r.replace(",-", ",", 1) for r in rows[1:]]
    imu.write_text("\n".join(flipped) + "\n")
    with pytest.raises(estim.EstimError, match="diverged at t = ") as raised:
        estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle)
    assert "no solution is returned" in str(raised.value)


def test_the_survey_checks_of_the_binary_hold_in_python(tmp_path):
    """The library's survey checks, as `estim navigate` applies them: a DVL file on
    another clock (Unix seconds beside relative ones) or without lock and nothing else
    aiding raises; an `imu.rate_hz` that does not fit the IMU file (100 Hz declared,
    the file at 100 Hz is fine; 10 Hz declared is not) is a UserWarning and an entry of
    `warnings`, and the run equals the one without the key; a spike of the IMU log is
    one too, naming its data row."""
    imu, dvl, vehicle = write_stationary(tmp_path, seconds=20.0)
    plain = estim.navigate(imu=imu, dvl=dvl, vehicle=vehicle)
    assert plain["warnings"] == []
    unix = tmp_path / "unix.csv"
    rows = dvl.read_text().splitlines()
    unix.write_text(
        "\n".join([rows[0]] + [f"{1.7e9 + float(r.split(',')[0])},0,0,0" for r in rows[1:]])
        + "\n"
    )
    with pytest.raises(estim.EstimError, match=r"unix\.csv: none of its .* records falls in the IMU's span.*dvl\.time_offset_s"):
        estim.navigate(imu=imu, dvl=unix, vehicle=vehicle)
    lost = tmp_path / "lost.csv"
    lost.write_text("\n".join([rows[0]] + [f"{r.split(',')[0]},nan,nan,nan" for r in rows[1:]]) + "\n")
    with pytest.raises(estim.EstimError, match=r"lost\.csv: none of its .* rows has bottom lock.*nothing would aid"):
        estim.navigate(imu=imu, dvl=lost, vehicle=vehicle)
    right = tmp_path / "right.toml"
    right.write_text(vehicle.read_text() + "\n[imu]\nrate_hz = 100.0\n")
    assert estim.navigate(imu=imu, dvl=dvl, vehicle=right)["warnings"] == []
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(vehicle.read_text() + "\n[imu]\nrate_hz = 10.0\n")
    with pytest.warns(UserWarning, match=r"imu\.rate_hz = 10\.0 Hz.*100\.0000 Hz"):
        out = estim.navigate(imu=imu, dvl=dvl, vehicle=wrong)
    assert [w["code"] for w in out["warnings"]] == ["imu_rate_mismatch"]
    assert out["warnings"][0]["file"].endswith("imu.csv")
    for key in ("latitude_deg", "longitude_deg", "depth_m"):
        np.testing.assert_allclose(out[key], plain[key], rtol=0, atol=1e-9)
    # One wild IMU sample (data row 1001, t = 1010 s): 5 m/s^2 on x, integrated as
    # logged and named.
    spiked = tmp_path / "spiked.csv"
    rows = imu.read_text().splitlines()
    cells = rows[1001].split(",")
    cells[1] = "5"
    rows[1001] = ",".join(cells)
    spiked.write_text("\n".join(rows) + "\n")
    with pytest.warns(UserWarning, match=r"spiked\.csv: 1 spike\(s\).*sample 1001 acc x \+5\.0000 m/s\^2"):
        out = estim.navigate(imu=spiked, dvl=dvl, vehicle=vehicle)
    assert [w["code"] for w in out["warnings"]] == ["imu_spike"]
