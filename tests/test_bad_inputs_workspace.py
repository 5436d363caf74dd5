"""Paths whose EPM would have to leave its workspace are refused before any run.

The waypoint reader keeps the capsule inside the plate and the workspace box; the EPM leads it
by about 15.5 mm toward -x on the shipped rig (the nominal dipole model; about 17 mm on the
plant), plus a friction part along the direction of travel (about 2.7 mm sideways when moving
along y at 0.02 m/s). Every CLI case goes through ``capsule_mpc.cli.main``: exit 2, a one-line
message naming the waypoint (number, index, coordinates), the EPM position and the workspace
bound, and nothing written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capsule_mpc import ConfigError
from capsule_mpc.cli import main
from capsule_mpc.config import load_config, packaged_config_path
from capsule_mpc.path_reach import EPM_WORKSPACE_MARGIN_M, check_epm_workspace, epm_positions_needed
from capsule_mpc.paths import ReferencePath, path_from_scenario

REPO = Path(__file__).resolve().parents[1]
RECTANGLE = str(REPO / "configs" / "rectangle.yaml")


def waypoints(tmp_path: Path, rows: list[tuple[float, float]]) -> Path:
    f = tmp_path / "wp.csv"
    f.write_text("x_m,y_m\n" + "".join(f"{x},{y}\n" for x, y in rows))
    return f


def refused(capsys, out: Path, argv: list[str]) -> str:
    """Run the command, check it was refused with exit 2 and wrote nothing; return the message."""
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())
    assert "results in" not in captured.out
    return err


@pytest.mark.parametrize(
    ("rows", "needle", "bound"),
    [
        # A path along the -x edge, then up. The capsule is inside (x >= -0.18) but
        # the EPM, 16 mm further toward -x, is not.
        (
            [(-0.10, 0.0), (-0.179, 0.0), (-0.179, 0.12)],
            "waypoint 2 of 3 (index 1) at (-0.179, 0) m needs the EPM at (-0.1953, 0.0000) m "
            "(arriving along -x at 0.02 m/s",
            "x >= -0.18 m (limits.workspace_min_m[0])",
        ),
        # Starting at rest near the -x edge: the start pose already needs the EPM outside.
        (
            [(-0.17, 0.0), (-0.10, 0.0)],
            "waypoint 1 of 2 (index 0) at (-0.17, 0) m needs the EPM at (-0.1855, 0.0000) m (at rest (start)",
            "x >= -0.18 m (limits.workspace_min_m[0])",
        ),
        # Up to the +y edge: moving along +y the EPM leads the capsule by 2.7 mm in y.
        (
            [(0.0, 0.08), (0.0, 0.1295)],
            "waypoint 2 of 2 (index 1) at (0, 0.1295) m needs the EPM at (-0.0155, 0.1322) m "
            "(arriving along +y at 0.02 m/s",
            "y <= 0.13 m (limits.workspace_max_m[1])",
        ),
        # Down to the -y edge, mirrored.
        (
            [(0.05, -0.08), (0.05, -0.1295)],
            "waypoint 2 of 2 (index 1) at (0.05, -0.1295) m needs the EPM at (0.0345, -0.1322) m "
            "(arriving along -y at 0.02 m/s",
            "y >= -0.13 m (limits.workspace_min_m[1])",
        ),
    ],
    ids=["minus-x-corner", "minus-x-start-at-rest", "plus-y-edge", "minus-y-edge"],
)
def test_simulate_refuses_a_path_whose_epm_leaves_the_workspace(tmp_path, capsys, rows, needle, bound):
    wp = waypoints(tmp_path, rows)
    out = tmp_path / "X"
    argv = ["simulate", "--config", RECTANGLE, "--controller", "follow", "--waypoints", str(wp)]
    err = refused(capsys, out, [*argv, "--out", str(out), "--no-progress"])
    assert f"waypoints file {wp}: " in err and needle in err and bound in err
    assert "move the path" in err and "mm in from that edge" in err


def test_the_message_lists_every_other_failing_waypoint(tmp_path, capsys):
    wp = waypoints(tmp_path, [(-0.10, 0.0), (-0.179, 0.0), (-0.179, 0.06), (-0.05, 0.06), (-0.175, 0.12)])
    out = tmp_path / "X"
    argv = ["simulate", "--config", RECTANGLE, "--controller", "mpc", "--waypoints", str(wp)]
    err = refused(capsys, out, [*argv, "--out", str(out), "--no-progress"])
    assert "waypoint 2 of 5 (index 1)" in err and err.endswith("(also waypoints 3, 5)")  # not 4, at x = -0.05


def test_a_configured_closed_path_near_the_edge_is_refused(tmp_path, capsys):
    """No waypoint file: the config's own rectangle, shifted toward -x (its start corner fails)."""
    cfg = tmp_path / "edge.yaml"
    cfg.write_text(f"base: {RECTANGLE}\npath: {{origin_m: [-0.12, 0.0]}}\n")
    out = tmp_path / "X"
    err = refused(
        capsys, out, ["simulate", "--config", str(cfg), "--controller", "follow", "--out", str(out)]
    )
    assert "capsule-mpc: path: waypoint 1 of 4 (index 0) at (-0.17, -0.03) m" in err
    assert "limits.workspace_min_m[0]" in err


def test_compare_and_plan_refuse_it_too(tmp_path, capsys):
    wp = waypoints(tmp_path, [(-0.10, 0.0), (-0.179, 0.0), (-0.179, 0.12)])
    for command in ("compare", "plan"):
        out = tmp_path / command
        err = refused(
            capsys, out, [command, "--config", RECTANGLE, "--waypoints", str(wp), "--out", str(out)]
        )
        assert "waypoint 2 of 3 (index 1) at (-0.179, 0) m" in err


def test_the_margin_alone_refuses_a_waypoint(tmp_path, capsys):
    """The EPM would be inside the box, but closer to its face than the margin the controllers need."""
    scenario = load_config(RECTANGLE)
    probe = ReferencePath(np.array([[0.0, 0.05], [0.0, 0.10]]), False, scenario.path.speed_mps)
    lead_y = epm_positions_needed(scenario, probe)[-2].lead_m[1]  # arriving along +y
    end_y = scenario.limits.workspace_max_m[1] - lead_y - EPM_WORKSPACE_MARGIN_M / 2
    assert end_y + lead_y < scenario.limits.workspace_max_m[1]  # inside the box itself
    wp = waypoints(tmp_path, [(0.0, 0.05), (0.0, round(end_y, 6))])
    out = tmp_path / "X"
    argv = ["simulate", "--config", RECTANGLE, "--controller", "follow", "--waypoints", str(wp)]
    err = refused(capsys, out, [*argv, "--out", str(out)])
    assert f"less a {EPM_WORKSPACE_MARGIN_M * 1e3:g} mm margin" in err and "waypoint 2 of 2" in err


# --- the check itself (no run) -----------------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper", "rectangle", "pipe"])
def test_shipped_configs_and_their_paths_pass(name):
    for config in (REPO / "configs" / f"{name}.yaml", packaged_config_path(name)):  # repo's and packaged
        scenario = load_config(config)
        check_epm_workspace(scenario, path_from_scenario(scenario))


def test_the_plus_x_edge_is_reachable_because_the_epm_trails_toward_minus_x():
    """On this rig every lead points toward -x, so a capsule on the +x face keeps the EPM inside."""
    scenario = load_config(RECTANGLE)
    x_max = scenario.limits.workspace_max_m[0]
    path = ReferencePath(np.array([[x_max - 0.05, 0.0], [x_max, 0.0], [x_max, 0.05]]), False, 0.02)
    check_epm_workspace(scenario, path)
    needs = epm_positions_needed(scenario, path)
    assert all(x_max - 0.018 < n.epm_m[0] < x_max - 0.014 for n in needs if n.index > 0)


def test_needs_follow_the_direction_of_travel():
    """At rest: the model's equilibrium lead; sliding: the friction part points along the motion."""
    scenario = load_config(RECTANGLE)
    square = ReferencePath(np.array([[0.0, 0.0], [0.05, 0.0], [0.05, 0.05], [0.0, 0.05]]), True, 0.02)
    needs = epm_positions_needed(scenario, square)
    assert [n.index for n in needs] == [0, 0, 0, 0, 1, 1, 2, 2, 3, 3]
    by_motion = {n.motion: n.lead_m for n in needs}
    rest = by_motion["at rest (start)"]
    np.testing.assert_allclose(rest, by_motion["at rest (end)"])
    assert rest[0] == pytest.approx(-0.0155, abs=5e-4) and abs(rest[1]) < 1e-9
    for heading, u in (("+x", (1, 0)), ("+y", (0, 1)), ("-x", (-1, 0)), ("-y", (0, -1))):
        lead = by_motion[f"leaving along {heading} at 0.02 m/s"]
        assert float(np.dot(lead - rest, u)) > 2e-4  # friction and drag: the EPM pulls ahead
    for n in needs:
        np.testing.assert_allclose(n.epm_m, n.waypoint_m + n.lead_m)


@pytest.mark.parametrize(
    ("mu0", "message"),
    [
        (
            0.5,
            "needs the EPM 31.6 mm from its rest position over the capsule (friction mu = 0.284), "
            "beyond the coupling limit limits.max_lead_m = 25 mm: lower the speed",
        ),
        (5.0, "finds no steady lead (the magnet cannot pull the capsule against friction mu = 4.78): "),
    ],
)
def test_a_speed_the_magnet_cannot_pull_is_a_config_error(mu0, message):
    """More friction than the coupling limit allows (the MPC never leads that far), or more than any lead."""
    scenario = load_config(RECTANGLE)
    sticky = scenario.model_copy(update={"friction": scenario.friction.model_copy(update={"mu0": mu0})})
    path = ReferencePath(np.array([[0.0, 0.0], [0.0, 0.05]]), False, 0.02)
    with pytest.raises(ConfigError) as info:
        check_epm_workspace(sticky, path)
    text = str(info.value)
    assert text.startswith("path: segment 0 -> 1 along +y at 0.02 m/s: the nominal dipole model ")
    assert message in text and "\n" not in text
