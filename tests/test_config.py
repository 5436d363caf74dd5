"""Config loading, validation errors and the YAML round trip."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from capsule_mpc import ConfigError, dump_config, load_config
from capsule_mpc.config import packaged_config_path

PAPER = yaml.safe_load(packaged_config_path("paper").read_text())


def _write(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_paper_defaults_hold_the_papers_numbers():
    s = load_config()
    assert s.capsule.mass_kg == pytest.approx(0.0209)
    assert s.epm.size_m == pytest.approx((0.08, 0.06, 0.05))
    assert s.epm.n_blocks == 4
    assert (s.ipm.outer_diameter_m, s.ipm.inner_diameter_m) == (0.010, 0.006)
    assert s.friction.mu0 == 0.22 and s.friction.tether_drag_n == 0.03
    assert s.friction.v_star_mps == 0.2 and s.friction.d_c_m == pytest.approx(1e-5)
    assert s.friction.paper_c.coefficients == [-1.189e5, 1.173e4, -404.7, 7.44, 0.03222]
    assert s.friction.paper_c.validity_mps == (0.005, 0.04)
    assert s.plate.setup == "below_plate"


def test_round_trip_is_identical(tmp_path):
    s = load_config()
    path = tmp_path / "dumped.yaml"
    dump_config(s, path)
    again = load_config(path)
    assert again.model_dump() == s.model_dump()


@pytest.mark.parametrize(
    ("section", "key"),
    [(sec, key) for sec in ("capsule", "ipm", "plate") for key in PAPER[sec] if key != "grade"
     and key != "setup" and key != "gravity_mps2"],
)  # fmt: skip
def test_every_required_field_missing_is_named(tmp_path, section, key):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    del data[section][key]
    with pytest.raises(ConfigError, match=rf"{section}\.{key}: required field is missing"):
        load_config(_write(tmp_path, data))


def test_negative_mass_names_field_and_range(tmp_path):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data["capsule"]["mass_kg"] = -0.02
    with pytest.raises(ConfigError, match=r"capsule\.mass_kg: must be > 0, got -0\.02"):
        load_config(_write(tmp_path, data))


def test_unknown_key_is_rejected(tmp_path):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data["friction"]["mu_kinetic"] = 0.2
    with pytest.raises(ConfigError, match=r"friction\.mu_kinetic: unknown key"):
        load_config(_write(tmp_path, data))


def test_nan_is_rejected(tmp_path):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data["plate"]["epm_height_m"] = math.nan
    with pytest.raises(ConfigError, match=r"plate\.epm_height_m: must be a finite number"):
        load_config(_write(tmp_path, data))


def test_range_upper_bound_is_named(tmp_path):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data["friction"]["mu0"] = 3.0
    with pytest.raises(ConfigError, match=r"friction\.mu0: must be <= 2"):
        load_config(_write(tmp_path, data))


def test_cross_field_rules(tmp_path):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data["ipm"]["inner_diameter_m"] = 0.02
    with pytest.raises(ConfigError, match=r"ipm: inner_diameter_m: must be < outer_diameter_m"):
        load_config(_write(tmp_path, data))
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data["epm"]["magnetisation"][1] = [0.0, 0.0, 2.0]
    with pytest.raises(ConfigError, match=r"epm\.magnetisation: .*unit vector"):
        load_config(_write(tmp_path, data))


def test_base_inheritance_overrides_only_given_fields(tmp_path):
    path = tmp_path / "child.yaml"
    path.write_text("base: paper\nname: child\nplate:\n  setup: on_plate\n")
    s = load_config(path)
    assert s.name == "child" and s.plate.setup == "on_plate"
    assert s.plate.epm_height_m == load_config().plate.epm_height_m


def test_learned_model_from_file_and_inline(tmp_path):
    model = {"coefficients": [0.5, 0.03], "validity_mps": [0.005, 0.04], "degree": 1}
    (tmp_path / "model.yaml").write_text(yaml.safe_dump(model))
    path = tmp_path / "c.yaml"
    path.write_text("base: paper\nfriction:\n  learned: model.yaml\n")
    s = load_config(path)
    assert s.controller_friction().coefficients == [0.5, 0.03]
    # The dump inlines the learned model, so it re-loads anywhere.
    dumped = tmp_path / "elsewhere" / "d.yaml"
    dumped.parent.mkdir()
    dump_config(s, dumped)
    assert load_config(dumped).controller_friction().coefficients == [0.5, 0.03]


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "nope.yaml")
