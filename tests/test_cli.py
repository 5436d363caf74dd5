"""The command line."""

from __future__ import annotations

import json

import pytest

from capsule_mpc.cli import main


def test_info_prints_key_figures(capsys, table):
    assert main(["info", "--json"]) == 0
    fig = json.loads(capsys.readouterr().out)
    assert fig["epm_dipole_moment_abs_am2"] == pytest.approx(240.6, rel=1e-3)
    assert set(fig["controller_mu_at_paper_speeds"]) == {"0.005", "0.02", "0.045"}
    assert fig["forces"]["finite_lead_0mm"]["normal_n"] > 0


def test_bad_config_exits_2_with_message(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("base: paper\ncapsule:\n  mass_kg: -1\n")
    assert main(["info", "--config", str(bad)]) == 2
    assert "capsule.mass_kg: must be > 0" in capsys.readouterr().err
