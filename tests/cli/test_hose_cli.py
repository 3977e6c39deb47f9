"""``aar-dock hose``: the issue's acceptance check (the printed shape and reel tension against
an independent continuous towed-cable solution built from the printed parameters), the output's
layout, plots and one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.cli.main import main
from tests.support.towed_cable_reference import Cable, lateral_modes, solve


def _run(capsys: pytest.CaptureFixture[str], *args: str) -> dict:  # type: ignore[type-arg]
    assert main(["hose", *args]) == 0
    return json.loads(capsys.readouterr().out)


def test_acceptance_against_the_continuous_towed_cable(capsys: pytest.CaptureFixture[str]) -> None:
    drogues = []
    for kcas in ("200", "230", "280"):
        out = _run(capsys, "--altitude-ft", "15000", "--kcas", kcas, "--json")
        h, d = out["hose"], out["drogue"]
        cable = Cable(
            h["length_m"], h["mass_per_m_kg"], h["diameter_m"], h["cd_normal"],
            h["cd_tangential"], d["mass_kg"], d["cd"], d["area_m2"],
            out["air_density_kgm3"], out["airspeed_mps"],
        )  # fmt: skip
        ref = solve(cable)
        nodes = np.array(out["nodes_m"])
        assert len(nodes) >= 10
        assert np.allclose(nodes[0], 0.0)
        s = np.linspace(0.0, h["length_m"], len(nodes))
        err = np.linalg.norm(nodes - ref.at(s), axis=1)
        assert err[-1] < 0.03 * h["length_m"]
        assert err.max() < 0.04 * h["length_m"]
        assert out["reel_tension_n"] == pytest.approx(ref.tension[0], rel=0.08)
        f_lat, _ = lateral_modes(cable, ref)
        assert out["swing"]["lateral_hz"] == pytest.approx(f_lat, rel=0.05)
        assert 0.1 < out["swing"]["lateral_hz"] < 1.0
        drogues.append(nodes[-1])
    # further aft (x aft grows) and higher (z down shrinks) as speed grows
    assert drogues[0][0] < drogues[1][0] < drogues[2][0]
    assert drogues[0][2] > drogues[1][2] > drogues[2][2]


def test_plot_and_text(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    out = _run(capsys, "--kcas", "230", "--json", "--plot", str(tmp_path / "p"))
    assert Path(out["plots"][0]).read_bytes()[:4] == b"\x89PNG"
    assert main(["hose", "--kcas", "230"]) == 0
    assert "reel tension" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args", [["--kcas", "900"], ["--altitude-ft", "nan"], ["--segments", "1"], ["--kcas", "x"]]
)
def test_bad_input_is_one_line_exit_2(capsys: pytest.CaptureFixture[str], args: list[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["hose", *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("aar-dock hose: error:") and err.count("\n") == 1
