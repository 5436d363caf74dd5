"""Bad input to the ``faults:`` switches: exit code 2, the field and its allowed
range named, nothing written -- for ``simulate``, ``compare`` and ``sweep`` alike.

Each case writes a scenario (``base: paper`` plus a ``faults:`` section) and runs the command
through ``capsule_mpc.cli.main``; every case is refused while the config is read, before any
simulation.
"""

from __future__ import annotations

import re

import pytest

from capsule_mpc.cli import main

COMMANDS = {
    "simulate": ["simulate", "--controller", "follow", "--no-progress", "--no-arm"],
    "compare": ["compare", "--controllers", "follow", "--no-progress", "--runs", "2"],
    "sweep": ["sweep", "--controllers", "follow", "--runs", "2"],
}
#: (id, field, value, what the message must say after "faults.FIELD: "); field None: the section.
CASES = [
    ("negative-rate", "camera_drop_burst_rate_hz", "-0.5", r"must be >= 0, got -0\.5"),
    ("rate-too-high", "arm_stall_rate_hz", "50", r"must be <= 5, got 50"),
    ("negative-probability", "solver_failure_probability", "-0.1", r"must be >= 0, got -0\.1"),
    ("probability-above-1", "solver_nan_probability", "1.5", r"must be <= 1, got 1\.5"),
    ("burst-longer-than-1s", "camera_drop_burst_max_s", "2.0", r"must be <= 1, got 2\.0"),
    ("zero-burst", "camera_drop_burst_max_s", "0", r"must be > 0, got 0"),
    ("outlier-too-big", "camera_outlier_m", "0.5", r"must be <= 0\.05, got 0\.5"),
    ("negative-latency", "latency_spike_ms", "-10", r"must be > 0, got -10"),
    ("late-too-long", "solver_late_ms", "5000", r"must be <= 1000, got 5000"),
    ("stall-too-long", "arm_stall_s", "3", r"must be <= 2, got 3"),
    ("unknown-fault", "camera_blackout_rate_hz", "0.1", r"unknown key \(not a field of this section\)"),
    ("bool-as-rate", "arm_stall_rate_hz", "true", r"must be a number"),
    ("nan-rate", "latency_spike_probability", ".nan", r"must be a finite number"),
    ("not-a-section", None, "0.5", r"Input should be a valid dictionary"),
]


def _params() -> list:
    return [
        pytest.param(command, field, value, says, id=f"{command}-{case_id}")
        for case_id, field, value, says in CASES
        for command in COMMANDS
    ]


@pytest.mark.parametrize(("command", "field", "value", "says"), _params())
def test_bad_fault_switch_exits_2_naming_it_and_writes_nothing(tmp_path, capsys, command, field, value, says):
    config = tmp_path / "c.yaml"
    body = f"faults: {value}\n" if field is None else f"faults:\n  {field}: {value}\n"
    message = r"faults: " + says if field is None else rf"faults\.{field}: " + says
    config.write_text("base: paper\n" + body)
    out = tmp_path / "out"
    try:
        code = main([*COMMANDS[command], "--config", str(config), "--out", str(out)])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    captured = capsys.readouterr()
    text = captured.err + captured.out
    assert code == 2, text
    assert re.search(message, text), text
    assert str(config) in text or "c.yaml" in text  # the file is named
    assert "Traceback" not in text
    assert not out.exists() or not any(out.iterdir())
