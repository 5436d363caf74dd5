"""Bad-input catalogue, the disk cache: a truncated, empty, NaN-holding, modified or foreign entry
(a force map, read by ``capsule-mpc info``, or a compiled MPC library, loaded by ``MPCSolver``) is
said once on stderr naming the file, removed and built again, and the result equals a clean build's;
an unwritable cache folder is replaced by a temporary one with a one-line warning before any
force-map work; a build leaves no temporary folder, however it ends.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from capsule_mpc import cache
from capsule_mpc.cli import main
from capsule_mpc.dynamics import capsule_model
from capsule_mpc.magnetics import model_equilibrium_lead
from capsule_mpc.mpc.controller import model_scenario
from capsule_mpc.mpc.problem import build_ocp
from capsule_mpc.mpc.solver import MPCSolver, compiled_nlp_functions, nlp_cache_key

#: A coarse force map (7 x 7 x 3 points, a coarse IPM mesh): computed in well under a second.
SMALL_MAP = (
    "base: paper\nforce_map:\n  lead_step_m: 0.015\n  height_offsets_m: [-0.005, 0.0, 0.005]\n  meshing: 10\n"
)
#: A tiny horizon: gcc compiles the MPC's functions in about a second.
HORIZON = 3
#: Builds a horizon-3 problem in a child process, then kills it (SIGKILL) inside the C compile.
KILLED_IN_COMPILE = """
import os, signal, sys
from pathlib import Path
from capsule_mpc import load_config
from capsule_mpc.dynamics import capsule_model
from capsule_mpc.magnetics import model_equilibrium_lead
from capsule_mpc.mpc import solver
from capsule_mpc.mpc.controller import model_scenario
from capsule_mpc.mpc.problem import build_ocp

scn = load_config()
scn = scn.model_copy(update={"mpc": scn.mpc.model_copy(update={"horizon": int(sys.argv[2])})})
ocp = build_ocp(capsule_model(model_scenario(scn)), 1.0 / 30.0, model_equilibrium_lead(scn))
solver._gcc = lambda source, out: os.kill(os.getpid(), signal.SIGKILL)
solver.compiled_nlp_functions(ocp, Path(sys.argv[1]))
"""


def _warnings(err: str) -> list[str]:
    return [line for line in err.replace("\r", "\n").splitlines() if "warning:" in line]


def _checksum(path: Path) -> Path:
    return path.with_name(path.name + ".sha256")


def _matches_checksum(path: Path) -> bool:
    digest, name = _checksum(path).read_text().split()
    return name == path.name and hashlib.sha256(path.read_bytes()).hexdigest() == digest


def _rewrite(path: Path, data: bytes, *, checksum: bool = False) -> None:
    """Replace ``path`` by a new file holding ``data`` (a new inode: a library this process has
    loaded stays intact); ``checksum``: record its checksum as the cache would."""
    path.unlink()
    path.write_bytes(data)
    if checksum:
        _checksum(path).write_text(f"{hashlib.sha256(data).hexdigest()}  {path.name}\n")


# ------------------------------------------------------------------ force maps (capsule-mpc info)


def _npz(path: Path, change: Callable[[dict[str, np.ndarray]], None]) -> bytes:
    with np.load(path) as data:
        arrays = dict(data)
    change(arrays)
    tmp = path.with_name("changed.npz")
    np.savez_compressed(tmp, **arrays)
    data = tmp.read_bytes()
    tmp.unlink()
    return data


def _nan(arrays: dict[str, np.ndarray]) -> None:
    arrays["force_n"][3, 3, 1, 2] = np.nan


def _times_3(arrays: dict[str, np.ndarray]) -> None:
    arrays["force_n"] = arrays["force_n"] * 3


def _foreign(arrays: dict[str, np.ndarray]) -> None:
    arrays["key"] = np.array("0123456789abcdef")


def _map_truncated(p: Path) -> None:
    _rewrite(p, p.read_bytes()[: p.stat().st_size // 2])


def _map_empty(p: Path) -> None:
    _rewrite(p, b"")


def _map_nan(p: Path) -> None:
    _rewrite(p, _npz(p, _nan), checksum=True)


def _map_times_3(p: Path) -> None:
    _rewrite(p, _npz(p, _times_3))


def _map_foreign(p: Path) -> None:
    _rewrite(p, _npz(p, _foreign), checksum=True)


def _map_folder(p: Path) -> None:
    p.unlink()
    p.mkdir()
    (p / "file").write_text("a folder in the entry's place\n")


def _map_no_checksum(p: Path) -> None:
    _checksum(p).unlink()


def _map_checksum_of_another(p: Path) -> None:
    digest = hashlib.sha256(p.read_bytes()).hexdigest()
    _checksum(p).write_text(f"{digest}  force_map_0123456789abcdef.npz\n")


MAP_CASES = {
    "truncated": (_map_truncated, r"does not match its checksum"),
    "empty": (_map_empty, r"does not match its checksum"),
    "nan-with-its-checksum": (_map_nan, r"cannot be used \(force_n: not finite at 1 of \d+ values\)"),
    "scaled-x3": (_map_times_3, r"does not match its checksum"),
    "foreign-with-its-checksum": (
        _map_foreign,
        r"cannot be used \(it holds the table of key '0123456789abcdef'\)",
    ),
    "a-folder": (_map_folder, r"cannot be read \(\[Errno 21\] Is a directory"),
    "no-checksum": (_map_no_checksum, r"has no checksum \(force_map_\w+\.npz\.sha256 is missing\)"),
    "checksum-of-another-entry": (_map_checksum_of_another, r"has a checksum file that is not its own"),
}


@pytest.fixture(scope="module")
def small_map(tmp_path_factory) -> tuple[Path, Path]:
    """The small-map config and a clean cache holding its force map."""
    root = tmp_path_factory.mktemp("small_map")
    config = root / "small.yaml"
    config.write_text(SMALL_MAP)
    clean = root / "clean"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("CAPSULE_MPC_CACHE", str(clean))
        assert main(["info", "--json", "--config", str(config)]) == 0
    return config, clean


def _info(config: Path, capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:
    capsys.readouterr()
    assert main(["info", "--json", "--config", str(config)]) == 0
    captured = capsys.readouterr()
    return json.loads(captured.out), captured.err


@pytest.mark.parametrize(("corrupt", "says"), list(MAP_CASES.values()), ids=list(MAP_CASES))
def test_a_bad_force_map_is_said_once_removed_and_computed_again(
    small_map, tmp_path, capsys, monkeypatch, corrupt, says
):
    config, clean = small_map
    monkeypatch.setenv("CAPSULE_MPC_CACHE", str(clean))
    reference, err = _info(config, capsys)
    assert _warnings(err) == []  # the clean entry is used as it is
    case = tmp_path / "cache"
    shutil.copytree(clean, case)
    (entry,) = case.glob("force_map_*.npz")
    corrupt(entry)

    monkeypatch.setenv("CAPSULE_MPC_CACHE", str(case))
    figures, err = _info(config, capsys)
    (warning,) = _warnings(err)
    assert warning.startswith(f"capsule-mpc: warning: cache entry {entry} ")
    assert warning.endswith("; removed, building it again")
    assert re.search(says, warning)
    assert "Traceback" not in err
    assert figures == reference
    assert _matches_checksum(entry)
    with np.load(entry) as stored, np.load(clean / entry.name) as fresh:
        assert np.array_equal(stored["force_n"], fresh["force_n"])
    _figures, err = _info(config, capsys)
    assert _warnings(err) == []  # said once: the rebuilt entry is used from then on


# ------------------------------------------------------------------ unwritable cache folders


def _a_file(tmp: Path) -> Path:
    (tmp / "cache.txt").write_text("not a folder\n")
    return tmp / "cache.txt"


def _under_a_file(tmp: Path) -> Path:
    return _a_file(tmp) / "capsule_mpc"


UNWRITABLE = {
    "a-file": (_a_file, r"\(it is a file\)"),
    "under-a-file": (_under_a_file, r"\(Not a directory\)"),
    "proc": (lambda _tmp: Path("/proc"), r"\(No such file or directory\)"),
}


@pytest.mark.parametrize(("folder", "reason"), list(UNWRITABLE.values()), ids=list(UNWRITABLE))
def test_an_unwritable_cache_falls_back_to_a_temporary_one_before_the_force_map(
    small_map, tmp_path, capsys, monkeypatch, folder, reason
):
    fm = importlib.import_module("capsule_mpc.magnetics.force_map")  # the module, not the function
    config, _clean = small_map
    where = folder(tmp_path)
    monkeypatch.setenv("CAPSULE_MPC_CACHE", str(where))
    monkeypatch.setattr(cache, "_fallbacks", {})  # this process has not used the folder yet
    said_before: list[str] = []
    compute = fm.finite_force

    def finite_force(*args, **kwargs):
        said_before.append(capsys.readouterr().err)
        return compute(*args, **kwargs)

    monkeypatch.setattr(fm, "finite_force", finite_force)
    capsys.readouterr()
    assert main(["info", "--config", str(config)]) == 0
    err = "".join(said_before) + capsys.readouterr().err
    (warning,) = _warnings(err)
    assert warning.startswith(
        f"capsule-mpc: warning: cache folder {where} ($CAPSULE_MPC_CACHE) cannot be written"
    )
    assert re.search(reason, warning)
    assert re.search(r"; using \S+ for this run$", warning)
    assert said_before and _warnings(said_before[0]) == [warning]  # said before computing the map
    assert "Traceback" not in err
    if where.parent == tmp_path:
        assert where.read_text() == "not a folder\n"


# ------------------------------------------------------------------ compiled MPC libraries


def _ocp(scenario, horizon: int = HORIZON):
    scn = scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update={"horizon": horizon})})
    return build_ocp(capsule_model(model_scenario(scn)), 1.0 / 30.0, model_equilibrium_lead(scn))


@pytest.fixture(scope="module")
def compiled(scenario, tmp_path_factory) -> dict:
    """A clean cache holding the horizon-3 library, a foreign (horizon-4) library, and the clean
    solver's RTI step at a few points."""
    clean, other = tmp_path_factory.mktemp("clean_lib"), tmp_path_factory.mktemp("other_lib")
    ocp = _ocp(scenario)
    solver = MPCSolver(ocp, "rti", compile_dir=clean)
    assert solver.compiled and not solver.loaded_from_cache
    assert compiled_nlp_functions(_ocp(scenario, HORIZON + 1), other) is not None
    rng = np.random.default_rng(0)
    points = [(rng.normal(size=ocp.n_w), rng.normal(size=ocp.n_p) * 1e-2) for _ in range(3)]
    steps = [solver._rti(w, p) for w, p in points]
    (foreign,) = other.glob("*.so")
    return {"clean": clean, "foreign": foreign, "points": points, "steps": steps}


def _lib_truncated(p: Path, _c: dict) -> None:
    _rewrite(p, p.read_bytes()[: p.stat().st_size // 2])


def _lib_empty(p: Path, _c: dict) -> None:
    _rewrite(p, b"")


def _lib_one_byte_changed(p: Path, _c: dict) -> None:
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0xFF
    _rewrite(p, bytes(data))


def _lib_not_a_library(p: Path, _c: dict) -> None:
    _rewrite(p, b"not a shared library\n" * 100, checksum=True)


def _lib_foreign(p: Path, c: dict) -> None:
    _rewrite(p, c["foreign"].read_bytes(), checksum=True)


def _lib_no_checksum(p: Path, _c: dict) -> None:
    _checksum(p).unlink()


LIB_CASES = {
    "truncated": (_lib_truncated, r"does not match its checksum"),
    "empty": (_lib_empty, r"does not match its checksum"),
    "one-byte-changed": (_lib_one_byte_changed, r"does not match its checksum"),
    "not-a-library-with-its-checksum": (_lib_not_a_library, r"cannot be used \("),
    "other-problem-with-its-checksum": (_lib_foreign, r"cannot be used \(compiled for \d+ variables"),
    "no-checksum": (_lib_no_checksum, r"has no checksum"),
}


#: Corruptions the checksum catches as it catches one changed byte (the same refusal and rebuild,
#: each a gcc run): in the slow suite.
CHECKSUM_ALIKE = {"truncated", "empty"}


@pytest.mark.parametrize(
    ("corrupt", "says"),
    [
        pytest.param(*case, id=name, marks=[pytest.mark.slow] if name in CHECKSUM_ALIKE else [])
        for name, case in LIB_CASES.items()
    ],
)
def test_a_bad_compiled_library_is_never_loaded_but_compiled_again(
    scenario, compiled, tmp_path, capsys, corrupt, says
):
    case = tmp_path / "mpc"
    shutil.copytree(compiled["clean"], case)
    lib = case / f"mpc_nlp_{nlp_cache_key(_ocp(scenario))}.so"
    corrupt(lib, compiled)
    capsys.readouterr()

    solver = MPCSolver(_ocp(scenario), "rti", compile_dir=case)
    (warning,) = _warnings(capsys.readouterr().err)
    assert warning.startswith(f"capsule-mpc: warning: cache entry {lib} ")
    assert re.search(says, warning)
    assert solver.compiled and not solver.loaded_from_cache
    assert _matches_checksum(lib)
    assert lib.read_bytes() == (compiled["clean"] / lib.name).read_bytes()  # the build is reproducible
    for (w, p), step in zip(compiled["points"], compiled["steps"], strict=True):
        for a, b in zip(solver._rti(w, p), step, strict=True):
            assert np.array_equal(a, b)
    again = MPCSolver(_ocp(scenario), "rti", compile_dir=case)
    assert again.loaded_from_cache and _warnings(capsys.readouterr().err) == []


def _leftovers(folder: Path) -> list[str]:
    """What a build may leave in a cache folder besides its lock files."""
    return sorted(p.name for p in folder.iterdir() if not p.name.endswith(".lock"))


def _processes() -> dict[int, tuple[str, int]]:
    """State and parent of every process (from /proc)."""
    found = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            state, ppid = stat.read_text().rsplit(")", 1)[1].split()[:2]
        except (OSError, IndexError):
            continue
        found[int(stat.parent.name)] = (state, int(ppid))
    return found


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie does not)."""
    state = _processes().get(pid, ("X", 0))[0]
    return state not in ("Z", "X")


def _ctrl_c_in_gcc(monkeypatch, folder: Path, started: list[int]) -> type[BaseException]:
    """Ctrl-C half a second into gcc (the C code generated, the compilers running)."""
    communicate = subprocess.Popen.communicate

    def interrupted(self, *args, **kwargs):
        assert list(folder.glob(".build.*/mpc_nlp.c"))
        with pytest.raises(subprocess.TimeoutExpired):
            communicate(self, timeout=0.5)
        started.extend([self.pid, *(pid for pid, (_, ppid) in _processes().items() if ppid == self.pid)])
        assert len(started) > 1  # gcc runs a compiler (cc1)
        raise KeyboardInterrupt

    monkeypatch.setattr(subprocess.Popen, "communicate", interrupted)
    return KeyboardInterrupt


def _gcc_fails(monkeypatch, folder: Path, started: list[int]) -> type[BaseException]:
    """gcc refuses an option."""
    import capsule_mpc.mpc.solver as solver

    monkeypatch.setattr(solver, "_CFLAGS", [*solver._CFLAGS, "-no-such-option"])
    return RuntimeError


@pytest.mark.parametrize("end", [_ctrl_c_in_gcc, _gcc_fails], ids=["ctrl-c", "gcc-fails"])
def test_a_compile_that_ends_early_leaves_nothing(scenario, tmp_path, monkeypatch, end):
    started: list[int] = []
    raised = end(monkeypatch, tmp_path, started)
    with pytest.raises(raised):
        compiled_nlp_functions(_ocp(scenario), tmp_path)
    assert _leftovers(tmp_path) == []  # no build folder (nor the compilers' temporary files)
    # gcc and the compiler it ran: killed (SIGKILL to their group; on a loaded machine the kernel
    # may take a moment to end an orphaned compiler, so wait up to 5 s for it).
    deadline = time.monotonic() + 5.0
    while any(_running(pid) for pid in started) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_running(pid) for pid in started)


def test_the_build_folder_of_a_killed_process_is_removed_at_the_next_start(scenario, tmp_path):
    child = subprocess.run(
        [sys.executable, "-c", KILLED_IN_COMPILE, str(tmp_path), str(HORIZON)],
        capture_output=True,
        check=False,
    )
    assert child.returncode == -signal.SIGKILL, child.stderr.decode()[-2000:]
    (left,) = _leftovers(tmp_path)  # the killed build's folder, with its C code
    assert left.startswith(".build.") and (tmp_path / left / "mpc_nlp.c").exists()
    running = tmp_path / f".build.{socket.gethostname()}.{os.getpid()}.abcd"
    running.mkdir()  # a build of a process that still runs: kept

    functions = compiled_nlp_functions(_ocp(scenario), tmp_path)
    assert functions is not None and not functions[2]
    lib = f"mpc_nlp_{nlp_cache_key(_ocp(scenario))}.so"
    assert _leftovers(tmp_path) == sorted([running.name, lib, f"{lib}.sha256"])
