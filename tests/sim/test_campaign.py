"""Monte-Carlo campaign through Dask and the CLI's output shapes."""

from __future__ import annotations

import csv
import json

import pytest

from app.cli.main import main
from app.sim.campaign import run_campaign, summarise, write_outputs
from app.sim.docking import DockingConfig
from app.sim.docking.outcomes import OUTCOMES


def test_small_campaign_on_two_dask_workers_writes_csv_json(tmp_path):
    cfg = DockingConfig(turbulence="light", vision=False, station_keep_s=0.5)
    seen = []
    rows = run_campaign(cfg, runs=8, workers=2, on_result=seen.append)
    assert len(rows) == 8 and len(seen) == 8
    assert [r["seed"] for r in rows] == list(range(8))
    summary = summarise(rows, cfg)
    assert summary["runs"] == 8
    assert summary["success_rate"] == sum(r["captured"] for r in rows) / 8
    assert summary["success_rate"] >= 0.75
    paths = write_outputs(tmp_path, rows, summary)
    with paths["csv"].open() as fh:
        assert len(list(csv.DictReader(fh))) == 8
    data = json.loads(paths["json"].read_text())
    for key in (
        "runs",
        "success_rate",
        "miss_p50_m",
        "miss_p95_m",
        "abort_rate",
        "mean_time_to_capture_s",
    ):
        assert key in data
    assert paths["png"].stat().st_size > 1000


def test_simulate_cli_json_shape(capsys):
    code = main(
        [
            "simulate",
            "--plant",
            "linear",
            "--turbulence",
            "none",
            "--truth-measurements",
            "--json",
            "--station-keep",
            "0.2",
        ]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {
        "outcome",
        "reason",
        "envelope",
        "lateral_speed_mps",
        "hose_whip_risk",
        "recoveries",
        "captured",
        "miss_distance_m",
        "closure_speed_mps",
        "time_to_capture_s",
        "aborts",
        "max_control_saturation",
        "peak_hose_tension_n",
        "hose_whip",
        "hose_released",
        "sim_time_s",
        "wall_time_s",
        "real_time_factor",
        "plant",
        "airframe",
        "trim",
    }
    assert out["plant"] == "linear" and "Aerosonde" in out["airframe"]
    assert out["outcome"] in OUTCOMES
    assert set(out["envelope"]) >= {"alpha_min_deg", "load_factor_max_g", "height_lost_m"}
    for key in ("altitude_ft", "kcas", "tas_mps", "alpha_deg", "throttle", "weight_lbs"):
        assert isinstance(out["trim"][key], float), key
    assert out["captured"] is True and isinstance(out["miss_distance_m"], float)
    assert isinstance(out["aborts"], int)
    # the run's simulated time covers the capture plus station keeping, in wall time > 0
    assert out["sim_time_s"] >= out["time_to_capture_s"] + 0.2 - 1e-6
    assert out["wall_time_s"] > 0
    assert out["real_time_factor"] == pytest.approx(
        out["sim_time_s"] / out["wall_time_s"], rel=1e-2
    )
    assert out["peak_hose_tension_n"] is None and out["hose_whip"] is False  # the reduced hose


def test_simulate_cli_multibody_hose_reports_the_contact(capsys):
    argv = ["simulate", "--plant", "linear", "--turbulence", "none", "--truth-measurements"]
    code = main([*argv, "--json", "--station-keep", "1", "--hose", "multibody"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["captured"] is True
    assert out["peak_hose_tension_n"] > 1000.0 and out["hose_whip"] is False


def test_summary_quotes_the_peak_tension_distribution_and_whips():
    tensions = [2100.0, 2300.0, float("nan"), 2500.0, 4400.0]
    rows = [
        {
            "seed": k,
            "outcome": "captured" if t == t else "aborted",
            "captured": t == t,
            "miss_distance_m": 0.1,
            "closure_speed_mps": 1.6,
            "time_to_capture_s": 10.0,
            "aborts": 0,
            "max_control_saturation": 0.5,
            "wall_time_s": 1.0,
            "sim_time_s": 10.0,
            "peak_hose_tension_n": t,
            "hose_whip": t > 4000.0,
        }
        for k, t in enumerate(tensions)
    ]
    s = summarise(rows)
    assert s["peak_tension_n"]["p50"] == pytest.approx(2400.0)  # of the four latched runs
    assert s["peak_tension_n"]["max"] == 4400.0
    assert 2500.0 < s["peak_tension_n"]["p95"] < 4400.0
    assert s["whip_runs"] == 1


def test_simulate_cli_plots(tmp_path, capsys):
    code = main(
        [
            "simulate",
            "--turbulence",
            "light",
            "--truth-measurements",
            "--plot",
            str(tmp_path),
            "--station-keep",
            "0.5",
        ]
    )
    assert code == 0
    assert sorted(p.name for p in tmp_path.glob("*.png")) == [
        "fig14_relative_position.png",
        "fig15_attitude.png",
        "fig16_controls.png",
    ]


def test_cli_bad_input_exit_code_2(capsys):
    assert main(["simulate", "--camera-hz", "-3", "--json"]) == 2
    assert main(["campaign", "--runs", "0"]) == 2
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--turbulence", "hurricane"])
    assert exc.value.code == 2


def test_simulate_cli_reports_the_jsbsim_plant_and_its_trim(capsys):
    code = main(
        ["simulate", "--plant", "jsbsim", "--turbulence", "none", "--truth-measurements", "--json"]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)  # nothing but the JSON on stdout
    assert out["plant"] == "jsbsim" and out["airframe"].startswith("A-4")
    t = out["trim"]
    assert t["altitude_ft"] == pytest.approx(15000.0, abs=1.0)
    assert t["kcas"] == pytest.approx(230.0, abs=0.5)
    assert 2.0 < t["alpha_deg"] < 5.0 and 0.2 < t["throttle"] < 0.8
