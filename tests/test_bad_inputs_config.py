"""Bad-input catalogue, configs, waypoints and run arguments: each refused with exit code 2, a
message naming the field, line or file, and no output.

Every case goes through ``capsule_mpc.cli.main`` as a user would; argparse errors exit through
``SystemExit(2)``, the others return 2. Each is refused before any simulation or force-map work.
"""

from __future__ import annotations

import os
import re
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from benchmark_scripts import load
from capsule_mpc.cli import main

REPO = Path(__file__).resolve().parents[1]
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00"
#: A waypoint file that stays well inside the paper plate and the EPM workspace.
SHORT_PATH = "x_m,y_m\n0,0\n0.03,0\n"


def _simulate(*extra: str) -> list[str]:
    return ["simulate", "--controller", "follow", "--no-progress", "--no-arm", "--out", "{out}", *extra]


def _compare(*extra: str) -> list[str]:
    return ["compare", "--controllers", "follow", "--no-progress", "--out", "{out}", *extra]


CFG = ("--config", "{tmp}/c.yaml")
WIDE_WORKSPACE = "limits:\n  workspace_max_m: [0.18, 0.13, 0.35]\n"
#: Test-folder file of each ``_case`` keyword: the scenario (after ``base: paper``), a waypoint
#: CSV and a learned friction model.
FILES = {"config": "c.yaml", "waypoints": "wp.csv", "model": "model.yaml"}


def _case(case_id: str, command: list[str], message: str, **files: str | bytes) -> object:
    """One bad input: the command ({tmp}, {out} filled in), the regex its message must match, files."""
    return pytest.param({FILES[k]: v for k, v in files.items()}, command, message, id=case_id)


CASES = [
    _case(
        "bool-as-number",
        _simulate(*CFG),
        r"c\.yaml:\n  capsule\.mass_kg: must be a number .*got True",
        config="capsule:\n  mass_kg: true\n",
    ),
    _case(
        "quoted-number",
        _simulate(*CFG),
        r"capsule\.mass_kg: must be a number .*got '0\.0209'",
        config='capsule:\n  mass_kg: "0.0209"\n',
    ),
    _case(
        "quoted-number-in-list",
        _simulate(*CFG),
        r"limits\.workspace_min_m\.1: must be a number",
        config="limits:\n  workspace_min_m: [-0.18, '-0.13', 0.085]\n",
    ),
    _case(
        "quoted-integer",
        _simulate(*CFG),
        r"sim\.seed: must be an integer .*got '3'",
        config="sim:\n  seed: '3'\n",
    ),
    _case(
        "bool-as-integer",
        _simulate(*CFG),
        r"camera\.latency_frames: must be an integer .*got True",
        config="camera:\n  latency_frames: true\n",
    ),
    _case(
        "quoted-flag",
        _simulate(*CFG),
        r"mpc\.compile_c: must be true or false, got 'no'",
        config="mpc:\n  compile_c: 'no'\n",
    ),
    _case(
        "duplicate-key",
        _simulate(*CFG),
        r"c\.yaml: line 5: duplicate key 'mass_kg' \(first given at line 3\)",
        config="capsule:\n  mass_kg: 0.0209\n  length_m: 0.036\n  mass_kg: 1.0\n",
    ),
    _case(
        "duplicate-top-level-key",
        _compare(*CFG),
        r"c\.yaml: line 5: duplicate key 'name' \(first given at line 2\)",
        config="name: a\nplate:\n  setup: on_plate\nname: b\n",
    ),
    _case(
        "duplicate-key-in-learned-model",
        ["info", *CFG],
        r"model\.yaml: line 3: duplicate key 'coefficients' \(first given at line 1\)",
        config="friction:\n  learned: model.yaml\n",
        model="coefficients: [0.5, 0.03]\nvalidity_mps: [0.005, 0.04]\ncoefficients: [1.0]\n",
    ),
    _case(
        "binary-config",
        _simulate(*CFG),
        r"c\.yaml: not a UTF-8 text file \(byte 0x89 at offset 0\)",
        config=PNG,
    ),
    _case(
        "epm-height-outside-workspace",
        ["info", *CFG],
        r"plate\.epm_height_m: must be within the EPM workspace heights \[0\.085, 0\.105\] m",
        config="plate:\n  epm_height_m: 0.3\n",
    ),
    _case(
        "epm-height-overlapping-magnets",
        _simulate(*CFG),
        r"plate\.epm_height_m: must be >= 0\.035 m \(half the EPM height",
        config="plate:\n  epm_height_m: 0.03\nlimits:\n  workspace_min_m: [-0.18, -0.13, 0.0]\n",
    ),
    _case(
        "epm-height-beyond-force-map",
        _simulate(*CFG),
        r"plate\.epm_height_m: cannot be 0\.3 m: the capsule's rest lead .* beyond the force map's "
        r"\|lead\| <= force_map\.lead_half_range_m = 45 mm; this rig allows heights in \[0\.035, 0\.116\] m",
        config="plate:\n  epm_height_m: 0.3\n" + WIDE_WORKSPACE,
    ),
    _case(
        "info-epm-height-beyond-force-map",
        ["info", *CFG],
        r"plate\.epm_height_m: cannot be 0\.3 m: .*heights in \[0\.035, 0\.116\] m",
        config="plate:\n  epm_height_m: 0.3\n" + WIDE_WORKSPACE,
    ),
    _case(
        "force-map-misses-the-height",
        _simulate(*CFG),
        r"force_map\.height_offsets_m: must span the EPM's true height offsets \[-0\.001, 0\.001\] m",
        config="force_map:\n  height_offsets_m: [0.0, 0.01]\n",
    ),
    _case(
        "plate-smaller-than-path",
        _simulate(*CFG),
        r"path\.rectangle_size_m / path\.origin_m: rectangle corner 1 of 4 \(-0\.05, -0\.03\) m is "
        r"outside the plate \(plate\.size_m\): x in \[-0\.04, 0\.04\]",
        config="plate:\n  size_m: [0.08, 0.3]\npath:\n  kind: rectangle\n",
    ),
    _case(
        "pipe-out-of-epm-reach",
        _compare(*CFG),
        r"path\.origin_m: pipe centreline point 20 of 29 \(0\.185, 0\.04\) m is outside the EPM workspace",
        config="path:\n  kind: pipe\n  origin_m: [0.15, 0.0]\n",
    ),
    _case(
        "waypoint-off-the-plate",
        _simulate(*CFG, "--waypoints", "{tmp}/wp.csv"),
        r"waypoints file .*wp\.csv: line 3: point \(0\.05, 0\.0\) m is outside the workspace "
        r"x in \[-0\.04, 0\.04\]",
        config="plate:\n  size_m: [0.08, 0.3]\n",
        waypoints="x_m,y_m\n0,0\n0.05,0\n",
    ),
    _case(
        "binary-waypoints",
        _simulate("--waypoints", "{tmp}/wp.csv"),
        r"waypoints file .*wp\.csv: not a UTF-8 text file \(byte 0x89 at offset 0\)",
        waypoints=PNG,
    ),
    _case(
        "binary-config-waypoints",
        _compare(*CFG),
        r"waypoints file .*wp\.csv: not a UTF-8 text file",
        config="path:\n  kind: waypoints\n  waypoints_file: wp.csv\n",
        waypoints=PNG,
    ),
    _case(
        "speed-over-epm-limit",
        _simulate("--speed", "0.09"),
        r"speed: must be in \(0, 0\.0721\] m/s on this path, got 0\.09: the EPM moves at most 0\.08 m/s",
    ),
    _case(
        "speed-at-epm-limit-compare",
        _compare("--speed", "0.08"),
        r"speed: must be in \(0, 0\.0721\] m/s on this path, got 0\.08",
    ),
    _case(
        "config-speed",
        _simulate(*CFG),
        r"path\.speed_mps: must be in \(0, 0\.0721\] m/s on this path, got 0\.09",
        config="path:\n  speed_mps: 0.09\n",
    ),
    _case(
        "speed-on-waypoints",
        _simulate("--waypoints", "{tmp}/wp.csv", "--speed", "0.1"),
        r"speed: must be in \(0, 0\.0721\] m/s on this path, got 0\.1",
        waypoints=SHORT_PATH,
    ),
    _case(
        "negative-seed-simulate",
        _simulate("--seed", "-1"),
        r"argument --seed: must be an integer in \[0, 2\*\*63 - 1\], got -1",
    ),
    _case(
        "negative-seed-compare",
        _compare("--seed", "-1"),
        r"argument --seed: must be an integer in \[0, 2\*\*63 - 1\], got -1",
    ),
    _case(
        "fractional-seed-compare",
        _compare("--seed", "1.5"),
        r"argument --seed: must be an integer in \[0, 2\*\*63 - 1\], got '1\.5'",
    ),
]


def _exit_code_and_message(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse refuses an argument this way
        code = exc.code if isinstance(exc.code, int) else 1
    captured = capsys.readouterr()
    return code, captured.err + captured.out


@pytest.mark.parametrize(("files", "command", "message"), CASES)
def test_bad_input_exits_2_naming_it_and_writes_nothing(tmp_path, capsys, files, command, message):
    for name, content in files.items():
        if isinstance(content, bytes):
            (tmp_path / name).write_bytes(content)
        else:
            (tmp_path / name).write_text(("base: paper\n" if name == FILES["config"] else "") + content)
    out = tmp_path / "out"
    argv = [a.format(tmp=tmp_path, out=out) for a in command]
    code, text = _exit_code_and_message(argv, capsys)
    assert code == 2, text
    assert re.search(message, text), text
    assert "Traceback" not in text
    assert not out.exists() or not any(out.iterdir())


def _laughs(levels: int) -> str:
    """A "billion laughs" scenario: each level a list of ten aliases of the one before."""
    rows = ["base: paper", 'lol0: &a0 "lol"']
    rows += [f"lol{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, levels + 1)]
    return "\n".join(rows) + "\n"


def _nested_by_aliases(levels: int) -> str:
    """Lists 5 deep, each alias level wrapping the one before: shallow text, deep data."""
    rows = ["base: paper", "d0: &d0 [[[[[1]]]]]"]
    rows += [f"d{i}: &d{i} [[[[*d{i - 1}]]]]" for i in range(1, levels + 1)]
    return "\n".join(rows) + "\n"


#: Each line of a refusal, and the whole message, at most this long (characters).
MAX_LINE, MAX_MESSAGE = 500, 4000
#: Memory a command refusing a hostile file may use in its own process (one without the bounds
#: grows past 1.5 GB), bytes, and the wall time it may take, s. The refusal itself is timed in CPU
#: seconds (a third of that), which a loaded machine does not stretch as it does the wall clock
#: (a child's interpreter start took 11 s of wall time on 2 cores shared by 4 test suites).
CHILD_MEMORY, CHILD_TIMEOUT_S = 1 << 30, 30.0
MAIN = "from capsule_mpc.cli import main; raise SystemExit(main())"


def _hostile(case_id: str, command: list[str], message: str, lines: int, child: bool = False, **files: str):
    """A hostile YAML input: the command, the regex its message matches, how many lines the message
    has, whether to run it in a child process (memory and time capped), and the files it reads
    (the config is written as given: no ``base: paper`` is added)."""
    return pytest.param({FILES[k]: v for k, v in files.items()}, command, message, lines, child, id=case_id)


FILES["base"] = "b.yaml"
HOSTILE = [
    _hostile(
        "billion-laughs",
        _simulate(*CFG),
        r"c\.yaml: line 6: holds more than 10000 values \(through aliases\)$",
        1,
        child=True,
        config=_laughs(9),
    ),
    _hostile(
        "five-alias-levels",
        _simulate(*CFG),
        r"c\.yaml: line 6: holds more than 10000 values \(through aliases\)$",
        1,
        config=_laughs(5),
    ),
    _hostile(
        "too-many-aliases",
        _simulate(*CFG),
        r"c\.yaml: line 3: more than 100 aliases$",
        1,
        config="base: paper\nx: &x 1\ny: [" + ", ".join(["*x"] * 101) + "]\n",
    ),
    _hostile(
        "recursive-alias",
        _simulate(*CFG),
        r"c\.yaml: line 2: alias \*a refers to a node that contains it$",
        1,
        config="base: paper\nx: &a [1, *a]\n",
    ),
    _hostile(
        "list-nested-5000-deep",
        _simulate(*CFG),
        r"c\.yaml: line 2: nested deeper than 20 levels$",
        1,
        config="base: paper\nx: " + "[" * 5000 + "]" * 5000 + "\n",
    ),
    _hostile(
        "mapping-nested-3000-deep",
        _compare(*CFG),
        r"c\.yaml: line 21: nested deeper than 20 levels$",
        1,
        config="base: paper\n" + "".join("  " * i + f"k{i}:\n" for i in range(3000)) + "  " * 3000 + "1\n",
    ),
    _hostile(
        "nested-deep-through-aliases",
        _simulate(*CFG),
        r"c\.yaml: line 6: nested deeper than 20 levels \(through aliases\)$",
        1,
        config=_nested_by_aliases(6),
    ),
    _hostile(
        "sexagesimal-integer",
        _simulate(*CFG),
        r"c\.yaml:\n  mpc\.horizon: must be an integer .*got '1:30'$",
        2,
        config="base: paper\nmpc:\n  horizon: 1:30\n",
    ),
    _hostile(
        "sexagesimal-float",
        _simulate(*CFG),
        r"c\.yaml:\n  capsule\.mass_kg: must be a number .*got '1:30\.5'$",
        2,
        config="base: paper\ncapsule:\n  mass_kg: 1:30.5\n",
    ),
    _hostile(
        "100k-character-value",
        _simulate(*CFG),
        r"capsule\.mass_kg: must be a number .*got 'x{30,}\.\.\.x{30,}'$",
        2,
        config="base: paper\ncapsule:\n  mass_kg: '" + "x" * 100_000 + "'\n",
    ),
    _hostile(
        "300-unknown-keys",
        _simulate(*CFG),
        r"c\.yaml:\n  key0: unknown key .*, got 0\n(  key\d+: .*\n){17}  \.\.\. and 282 more$",
        20,
        config="base: paper\n" + "".join(f"key{i}: {i}\n" for i in range(300)),
    ),
    _hostile(
        "not-yaml",
        _simulate(*CFG),
        r"c\.yaml: line 3, column 1: not valid YAML: expected ',' or '\]', but got '<stream end>'$",
        1,
        config="base: paper\ncapsule: [1, 2\n",
    ),
    _hostile(
        "base-not-a-file-name",
        _simulate(*CFG),
        r"c\.yaml: base: must be a file name or 'paper', got \{'a': 1\}$",
        1,
        config="base: {a: 1}\n",
    ),
    _hostile(
        "hostile-base-file",
        _simulate(*CFG),
        r"b\.yaml: line 2: nested deeper than 20 levels$",
        1,
        config="base: b.yaml\n",
        base="base: paper\nx: " + "[" * 5000 + "]" * 5000 + "\n",
    ),
    _hostile(
        "billion-laughs-learned-model",
        ["info", *CFG],
        r"model\.yaml: line 6: holds more than 10000 values \(through aliases\)$",
        1,
        child=True,
        config="base: paper\nfriction:\n  learned: model.yaml\n",
        model=_laughs(9).replace("base: paper\n", "coefficients: [0.5, 0.03]\n"),
    ),
]


def _cpu_s() -> float:
    """CPU seconds (user and system) of this process and of its children that have ended."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (CHILD_MEMORY, CHILD_MEMORY))


@pytest.mark.parametrize(("files", "command", "message", "lines", "child"), HOSTILE)
def test_hostile_yaml_is_refused_in_a_short_message_within_seconds(
    tmp_path, capsys, files, command, message, lines, child
):
    for name, content in files.items():
        (tmp_path / name).write_text(content)
    out = tmp_path / "out"
    argv = [a.format(tmp=tmp_path, out=out) for a in command]
    cpu0 = _cpu_s()
    if child:  # a regression would hang and eat memory: capped in its own process
        done = subprocess.run(
            [sys.executable, "-c", MAIN, *argv],
            capture_output=True,
            text=True,
            timeout=CHILD_TIMEOUT_S,
            preexec_fn=_limit_memory,
            env={**os.environ, "COLUMNS": "100"},
        )
        code, text = done.returncode, done.stderr + done.stdout
    else:
        code, text = _exit_code_and_message(argv, capsys)
    cpu_s = _cpu_s() - cpu0
    assert code == 2, text[:2000]
    assert len(text) <= MAX_MESSAGE, text[:2000]
    assert text.startswith("capsule-mpc: ") and text.endswith("\n")
    assert len(text.splitlines()) == lines, text
    assert all(len(line) <= MAX_LINE for line in text.splitlines()), text
    assert re.search(message, text.rstrip("\n")), text
    assert cpu_s < CHILD_TIMEOUT_S / 3  # this process's and its reaped child's
    assert not out.exists() or not any(out.iterdir())


def test_the_demo_reads_its_learned_model_with_the_same_loader(tmp_path):
    from capsule_mpc.experiments.demo import model_is_current

    log = tmp_path / "log.csv"
    log.write_text("t_s\n")
    os.utime(log, (0, 0))
    model = tmp_path / "learned_friction.yaml"
    fitted = f"force_model: lookup\nsources: [{log.resolve()}]\n"
    model.write_text(fitted)
    assert model_is_current(model, [log])
    model.write_text(fitted + "x: " + "[" * 5000 + "]" * 5000 + "\n")  # refused: fitted again
    assert not model_is_current(model, [log])


def _sim_speed_main(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))  # as ``python benchmarks/sim_speed.py`` has it
    return load("sim_speed").main


@pytest.mark.parametrize(
    ("out_kind", "message"),
    [
        (
            "folder",
            r"sim_speed: --out: .*given is a folder; give a file name, e\.g\. .*given/sim_speed\.json",
        ),
        ("under-a-file", r"sim_speed: --out: .*a_file\.txt is not a folder"),
    ],
)
def test_sim_speed_benchmark_refuses_a_bad_out_before_running(
    tmp_path, capsys, monkeypatch, out_kind, message
):
    folder = tmp_path / "given"
    folder.mkdir()
    (tmp_path / "a_file.txt").write_text("not a folder\n")
    out = folder if out_kind == "folder" else tmp_path / "a_file.txt" / "report.json"
    assert _sim_speed_main(monkeypatch)(["--out", str(out)]) == 2
    assert re.search(message, capsys.readouterr().err)
    assert not any(folder.iterdir())
    assert (tmp_path / "a_file.txt").read_text() == "not a folder\n"


@pytest.mark.parametrize("script", ["fault_campaign", "friction_ablation", "placement_moves"])
def test_a_campaign_script_refuses_a_report_that_is_not_json_before_running(tmp_path, script):
    # the campaign's folder is the report's name without .json: a report without it would be that folder
    out = tmp_path / "report"
    done = subprocess.run(
        [sys.executable, str(REPO / "benchmarks" / f"{script}.py"), "--out", str(out)],
        capture_output=True, text=True, timeout=CHILD_TIMEOUT_S,
    )  # fmt: skip
    assert done.returncode == 2
    assert re.search(r"--out: must name a \.json file .*report'", done.stderr), done.stderr
    assert not any(tmp_path.iterdir())
