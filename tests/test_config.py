"""Config loading, validation errors and the YAML round trip."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from capsule_mpc import ConfigError, dump_config, load_config
from capsule_mpc.cli.reference import iter_config_fields
from capsule_mpc.config import config_from_dict, packaged_config_path
from capsule_mpc.config._loader import MOVED_KEYS, REMOVED_KEYS
from capsule_mpc.experiments.info import scenario_figures
from capsule_mpc.path_reach import check_epm_height
from capsule_mpc.path_reach import format_mm as _mm

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
    [
        (sec, key)
        for sec in ("capsule", "ipm", "plate")
        for key in PAPER[sec]
        if key != "grade" and key != "setup" and key != "gravity_mps2"
    ],
)
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


@pytest.mark.parametrize(("old", "new"), list(MOVED_KEYS.items()))
def test_a_moved_key_is_refused_naming_where_it_went(tmp_path, old, new):
    *sections, key = old.split(".")
    nested: dict = {key: 1}
    for section in reversed(sections):
        nested = {section: nested}
    path = _write(tmp_path, {"base": "paper", **nested})
    with pytest.raises(
        ConfigError, match=rf"^invalid config .*\n  {re.escape(old)}: moved to {re.escape(new)}$"
    ):
        load_config(path)
    with pytest.raises(ConfigError, match=rf"{re.escape(old)}: moved to {re.escape(new)}"):
        config_from_dict({**PAPER, **nested})


def test_every_moved_key_names_a_field():
    fields = {row[0] for row in iter_config_fields()}
    assert set(MOVED_KEYS.values()) <= fields
    assert not set(MOVED_KEYS) & fields


def test_the_nested_mpc_sections_load_and_round_trip(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("base: paper\nplace:\n  approach_speed_mps: 0.02\n")
    s = load_config(path)
    assert s.place.approach_speed_mps == 0.02
    assert s.place.max_moves == 8  # the others default
    dumped = dump_config(s)
    assert load_config(_write(tmp_path, yaml.safe_load(dumped))).model_dump() == s.model_dump()


@pytest.mark.parametrize("old", sorted(REMOVED_KEYS))
def test_a_removed_key_is_refused_naming_it_and_where_its_measurement_is(tmp_path, old):
    section, key = old.split(".")
    path = _write(tmp_path, {"base": "paper", section: {key: 1}})
    with pytest.raises(ConfigError, match=rf"{re.escape(old)}: removed \("):
        load_config(path)
    fields = {row[0] for row in iter_config_fields()}
    assert old not in fields


def test_base_inheritance_overrides_only_given_fields(tmp_path):
    path = tmp_path / "child.yaml"
    path.write_text("base: paper\nname: child\nplate:\n  setup: on_plate\n")
    s = load_config(path)
    assert s.name == "child" and s.plate.setup == "on_plate"
    assert s.plate.epm_height_m == load_config().plate.epm_height_m


def test_learned_model_from_file_and_inline(tmp_path):
    model = {"coefficients": [0.5, 0.03], "validity_mps": [0.005, 0.04], "degree": 1, "force_model": "dipole"}
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


@pytest.mark.parametrize(
    ("section", "key", "value", "message"),
    [
        ("capsule", "mass_kg", True, r"capsule\.mass_kg: must be a number .*got True"),
        ("capsule", "mass_kg", "0.0209", r"capsule\.mass_kg: must be a number .*got '0\.0209'"),
        ("plate", "size_m", [0.4, "0.3"], r"plate\.size_m\.1: must be a number"),
        ("friction", "mu0", False, r"friction\.mu0: must be a number"),
        ("mpc", "horizon", 20.0, r"mpc\.horizon: must be an integer .*got 20\.0"),
        ("mpc", "horizon", True, r"mpc\.horizon: must be an integer .*got True"),
        ("sim", "seed", "3", r"sim\.seed: must be an integer .*got '3'"),
        ("mpc", "compile_c", "yes", r"mpc\.compile_c: must be true or false, got 'yes'"),
        ("mpc", "height_control", 1, r"mpc\.height_control: must be true or false, got 1"),
    ],
)
def test_numbers_and_flags_are_not_coerced(tmp_path, section, key, value, message):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data.setdefault(section, {})[key] = value
    with pytest.raises(ConfigError, match=message):
        load_config(_write(tmp_path, data))


def test_programmatic_numbers_still_validate():
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    data["capsule"]["mass_kg"] = np.float32(0.02)
    data["capsule"]["length_m"] = 1  # an int is a number
    data["mpc"] = {"horizon": np.int64(15)}
    s = config_from_dict(data)
    assert s.capsule.mass_kg == pytest.approx(0.02) and s.capsule.length_m == 1.0
    assert s.mpc.horizon == 15 and type(s.mpc.horizon) is int
    with pytest.raises(ValueError, match="must be a number"):
        s.capsule.mass_kg = True  # assignment is validated too


def test_exponent_floats_are_numbers(tmp_path):
    # YAML 1.1 (PyYAML) reads 1e-5 and -1.189e5 as strings; the number fields read them as numbers.
    path = tmp_path / "c.yaml"
    path.write_text(
        "base: paper\nfriction:\n  d_c_m: 2e-5\n"
        "  paper_c:\n    coefficients: [-1.189e5, 3E2]\n    degree: 1\n"
    )
    s = load_config(path)
    assert s.friction.d_c_m == 2e-5
    assert s.friction.paper_c.coefficients == [-118900.0, 300.0]
    path.write_text('base: paper\nfriction:\n  d_c_m: "2e-5"\n')  # quoted: still a string
    with pytest.raises(ConfigError, match=r"friction\.d_c_m: must be a number"):
        load_config(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "base: paper\ncapsule:\n  mass_kg: 0.02\n  mass_kg: 0.03\n",
            "line 4: duplicate key 'mass_kg' (first given at line 3)",
        ),
        (
            "base: paper\nname: a\nplate: {}\nname: b\n",
            "line 4: duplicate key 'name' (first given at line 2)",
        ),
        (
            "base: paper\nlimits: {speed_mps: 0.05, speed_mps: 0.06}\n",
            "line 2: duplicate key 'speed_mps' (first given at line 2)",
        ),
    ],
)
def test_duplicate_keys_are_refused_with_their_line(tmp_path, text, message):
    path = tmp_path / "dup.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert str(exc.value) == f"{path}: {message}"


def test_merge_keys_may_be_overridden(tmp_path):
    path = tmp_path / "merge.yaml"
    path.write_text(
        "base: paper\ncapsule:\n  <<: {mass_kg: 0.02, length_m: 0.036, diameter_m: 0.014}\n  mass_kg: 0.03\n"
    )
    assert load_config(path).capsule.mass_kg == 0.03


def test_binary_and_bom_files(tmp_path):
    binary = tmp_path / "scenario.yaml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    with pytest.raises(ConfigError, match=r"scenario\.yaml: not a UTF-8 text file \(byte 0x89 at offset 0\)"):
        load_config(binary)
    bom = tmp_path / "bom.yaml"
    bom.write_bytes(b"\xef\xbb\xbfbase: paper\nname: bom\n")
    assert load_config(bom).name == "bom"


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"plate": {"epm_height_m": 0.3}},
            r"plate\.epm_height_m: must be within the EPM workspace heights "
            r"\[0\.085, 0\.105\] m \(limits\.workspace_min_m\[2\], limits\.workspace_max_m\[2\]",
        ),
        (
            {"plate": {"epm_height_m": 0.03}, "limits": {"workspace_min_m": [-0.18, -0.13, 0.0]}},
            r"plate\.epm_height_m: must be >= 0\.035 m \(half the EPM height 0\.025 \+ plate\.thickness_m "
            r"0\.003 \+ half the capsule diameter 0\.007",
        ),
        (
            {"force_map": {"height_offsets_m": [0.0, 0.01]}},
            r"force_map\.height_offsets_m: must span the EPM's true height offsets \[-0\.001, 0\.001\] m",
        ),
        (
            {"force_map": {"height_offsets_m": [-0.002, 0.002]}, "plant": {"preset": "hard"}},
            r"force_map\.height_offsets_m: must span the EPM's true height offsets \[-0\.003, 0\.003\] m",
        ),
        (
            {"force_map": {"height_offsets_m": [-0.002, 0.002]}, "plant": {"epm_height_offset_m": 0.004}},
            r"\[0, 0\.004\] m",
        ),
    ],
)
def test_epm_height_within_what_the_models_cover(tmp_path, changes, message):
    data = yaml.safe_load(yaml.safe_dump(PAPER))
    for section, values in changes.items():
        data.setdefault(section, {}).update(values)
    with pytest.raises(ConfigError, match=message) as exc:
        load_config(_write(tmp_path, data))
    assert "got {" not in str(exc.value)  # a rule across fields names its fields, not the section's dict
    data["force_map"] = {"height_offsets_m": [-0.005, 0.0, 0.005]}
    data["plate"]["epm_height_m"] = 0.095
    data["plant"] = {"preset": "ideal"}
    data.pop("limits", None)
    assert load_config(_write(tmp_path, data)).force_map.height_offsets_m == [-0.005, 0.0, 0.005]


@pytest.mark.parametrize(
    ("lead_m", "text"),
    [(-1e-15, "+0.0"), (1e-15, "+0.0"), (-0.0, "+0.0"), (-0.04914, "-49.1"), (0.00006, "+0.1")],
)
def test_leads_print_without_a_negative_zero(lead_m, text):
    # The rest lead's y of a symmetric rig is 0 up to the root finder's noise of either sign.
    assert _mm(lead_m) == text


def test_check_epm_height_refuses_what_the_force_map_cannot_hold(scenario):
    rest = check_epm_height(scenario)  # the paper rig: rest lead -17 mm (finite-magnet model)
    assert rest == pytest.approx([-0.01696, 0.0], abs=2e-5)
    high = scenario.model_copy(
        update={
            "plate": scenario.plate.model_copy(update={"epm_height_m": 0.3}),
            "limits": scenario.limits.model_copy(update={"workspace_max_m": (0.18, 0.13, 0.35)}),
        }
    )
    with pytest.raises(ConfigError) as exc:
        check_epm_height(high)
    assert str(exc.value) == (
        "plate.epm_height_m: cannot be 0.3 m: the capsule's rest lead there is (-49.1, +0.0) mm "
        "(finite-magnet model) and the controller may command leads up to limits.max_lead_m = 25 mm "
        "from it, 74.1 mm from the EPM axis, beyond the force map's |lead| <= "
        "force_map.lead_half_range_m = 45 mm; this rig allows heights in [0.035, 0.116] m"
    )
    wide = high.model_copy(
        update={
            "plate": high.plate.model_copy(update={"epm_height_m": 0.135}),
            "force_map": high.force_map.model_copy(update={"lead_half_range_m": 0.1}),
        }
    )
    with pytest.raises(ConfigError, match=r"does not hold the capsule .* heights in \[0\.035, 0\.129\d?\] m"):
        check_epm_height(wide)


def test_paper_yaml_comment_matches_info(scenario):
    """The comment on plate.epm_height_m quotes what `capsule-mpc info` prints."""
    text = packaged_config_path("paper").read_text()
    quoted = re.search(r"F_N = ([\d.]+) m g directly under the\s+# EPM centre and ([\d.]+) m g at the", text)
    assert quoted is not None
    with warnings.catch_warnings():  # the friction law's range notes, which info prints as notes
        warnings.simplefilter("ignore")
        forces = scenario_figures(scenario)["forces"]
    assert f"{forces['finite_lead_0mm']['normal_over_weight']:.2f}" == quoted.group(1)
    assert f"{forces['finite_equilibrium']['normal_over_weight']:.2f}" == quoted.group(2)


#: The sections the MPC controller owns (its sliding MPC, estimator and phases).
CONTROLLER_SECTIONS = ("mpc", "estimator", "break_loose", "place")
#: Their settings in all: a new one must replace one (an option stays only with a measured gain).
CONTROLLER_SETTINGS_BUDGET = 33


def test_the_controller_settings_stay_within_their_budget():
    fields = [row[0] for row in iter_config_fields()]
    owned = [f for f in fields if f.split(".")[0] in CONTROLLER_SECTIONS]
    assert {f.split(".")[0] for f in owned} == set(CONTROLLER_SECTIONS)
    assert len(owned) <= CONTROLLER_SETTINGS_BUDGET, owned


@pytest.mark.parametrize("section, key", [("break_loose", "preload"), ("mpc", "input_jerk_tol_mps2")])
def test_a_null_that_is_not_the_default_survives_a_dump(tmp_path, section, key):
    """A field set to null whose default is not null (the pre-load switched off) dumps as null, so the
    config.yaml beside a run (and a campaign's workers) re-load what ran, not the default."""
    s = load_config(_write(tmp_path, {"base": "paper", section: {key: None}}))
    assert getattr(getattr(s, section), key) is None
    again = load_config(_write(tmp_path, yaml.safe_load(dump_config(s))))
    assert getattr(getattr(again, section), key) is None
    assert again.model_dump() == s.model_dump()


def test_a_run_prepared_with_overrides_keeps_a_null_that_is_not_the_default(tmp_path):
    """``--plant`` and ``--speed`` rebuild the scenario from its data: the pre-load switched off in
    the file stays off in the run."""
    from capsule_mpc.experiments.runs import prepare_run

    path = _write(tmp_path, {"base": "paper", "name": "off", "break_loose": {"preload": None}})
    scenario, _, _ = prepare_run(path, None, 0.02, "ideal")
    assert scenario.break_loose.preload is None and scenario.plant.preset == "ideal"
