"""What a sweep keeps in its folder: its definition (to resume it), and its summary and figures."""

from __future__ import annotations

import functools
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ...atomic import json_ready
from ...config import ConfigError, Scenario
from ...paths import ReferencePath
from ...plots import plot_metrics
from ..aggregate import succeeded
from ..compare import RUNS_FOLDER, SUMMARY_COLUMNS
from ..table import run_label, table_from_entries
from .tasks import Variant
from .vary import VaryRange

__all__ = [
    "SPEC_FILE",
    "WORST_COUNT",
    "check_resume",
    "code_fingerprint",
    "finished_runs",
    "spec_difference",
    "sweep_spec",
    "worst_runs",
    "worst_table",
    "write_figures",
]

#: Where the sweep's definition is kept in its folder (checked when it is resumed).
SPEC_FILE = "sweep.json"
#: Worst runs listed per controller and metric.
WORST_COUNT = 3
#: The flags of the table (true/false per run): their seeds are listed, not ranked.
_FLAGS = ("decoupled", "dropped", "stalled")
#: The metrics of the table that get a distribution figure and a worst-runs ranking.
_RANKED = tuple((key, header) for key, header, _ in SUMMARY_COLUMNS if key not in _FLAGS)


@functools.cache
def code_fingerprint() -> dict[str, str]:
    """The ``capsule_mpc`` code this process runs: a SHA-256 (16 hex digits) of its Python sources
    and packaged configs, so that a sweep resumed by other code is refused (its first
    runs and the rest would not be one experiment)."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".yaml") and p.is_file()):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
    return {"sha256": digest.hexdigest()[:16]}


def sweep_spec(
    scenario: Scenario,
    path: ReferencePath,
    seed: int,
    runs: int,
    controllers: Sequence[str],
    vary: Sequence[VaryRange],
    variants: Sequence[Variant] = (),
) -> dict[str, Any]:
    """What a sweep is, as kept in ``sweep.json`` (JSON-ready): a resumed sweep must match it."""
    spec = {
        "command": "sweep",
        "code": code_fingerprint(),
        "config": scenario.model_dump(mode="json"),
        "path": {
            "waypoints_m": path.waypoints_m.tolist(),
            "closed": path.closed,
            "speed_mps": path.speed_mps,
        },
        "seed": seed,
        "runs": runs,
        "controllers": list(controllers),
        "vary": {v.field: [v.lo, v.hi] for v in vary},
    }
    if variants:
        spec["variants"] = {
            v.name: {"overrides": dict(v.overrides), "controllers": v.controllers} for v in variants
        }
    return dict(json.loads(json.dumps(json_ready(spec))))


#: The parts of :func:`sweep_spec` checked on resume, and the argument each comes from.
_SPEC_ARGUMENTS = (
    ("command", "the command"),
    ("code", "the capsule_mpc code"),
    ("seed", "--seed"),
    ("runs", "--runs"),
    ("controllers", "--controllers"),
    ("vary", "--vary"),
    ("variants", "the variants"),
    ("path", "the path (--waypoints, --speed or the config's path)"),
    ("config", "config"),
)


def _first_difference(held: Any, now: Any, where: str = "") -> tuple[str, Any, Any]:
    """The first dotted key where two JSON values differ, with both values there."""
    if isinstance(held, dict) and isinstance(now, dict):
        for key in [*held, *(k for k in now if k not in held)]:
            if held.get(key) != now.get(key):
                return _first_difference(held.get(key), now.get(key), f"{where}.{key}" if where else key)
    return where, held, now


def spec_difference(held: Mapping[str, Any], now: Mapping[str, Any]) -> str | None:
    """How the sweep in a folder (``held``) differs from the one asked for (``now``); None if alike."""
    for key, label in _SPEC_ARGUMENTS:
        a, b = held.get(key), now.get(key)
        if a != b:
            if key == "config" and isinstance(a, dict):
                where, a, b = _first_difference(a, b)
                label = f"config {where}"
            a, b = (json.dumps(v) for v in (a, b))
            a, b = (v if len(v) <= 80 else v[:77] + "..." for v in (a, b))
            return f"{label}: {a} in the folder, {b} now"
    return None


def check_resume(out: str | Path, spec: Mapping[str, Any]) -> bool:
    """Whether ``out`` holds this sweep (to resume); False if it holds none. A ConfigError when it
    holds a sweep with other arguments (naming the first difference) or an unreadable ``sweep.json``."""
    held_file = Path(out) / SPEC_FILE
    try:
        if not held_file.is_file():
            return False
    except OSError:  # e.g. a name too long: no sweep there (the output folder says why)
        return False
    try:
        held = json.loads(held_file.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(
            f"--out: {held_file} cannot be read ({exc}); delete it or use another folder"
        ) from None
    difference = spec_difference(held if isinstance(held, dict) else {}, spec)
    if difference is not None:
        hint = (
            "its runs cannot be resumed by this code; use another folder"
            if isinstance(held, dict) and held.get("code") != spec.get("code")
            else "re-run it with the same arguments to resume it, or use another folder"
        )
        raise ConfigError(f"--out: {out} holds a sweep with other arguments ({difference}); {hint}")
    return True


def finished_runs(out: Path, seeds: Sequence[int]) -> dict[int, dict[str, Any]]:
    """The runs whose files are in ``out/runs/`` (a crashed or unreadable one is run again)."""
    done: dict[int, dict[str, Any]] = {}
    for seed in seeds:
        try:
            entry = json.loads((out / RUNS_FOLDER / f"seed_{seed}.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if (
            isinstance(entry, dict)
            and entry.get("seed") == seed
            and isinstance(entry.get("controllers"), dict)
            and "crashed" not in entry
        ):
            done[seed] = entry
    return done


def worst_runs(per_seed: Sequence[Mapping[str, Any]], count: int = WORST_COUNT) -> dict[str, dict[str, Any]]:
    """The worst runs per run label, ``summary.json``'s ``worst``: ``metrics``, for each metric of
    the table, the ``count`` runs with the largest finite values, ``[{"seed", "value"}]`` from the
    worst, ties by seed; ``flags``, the seeds where each flag was raised; ``failed``, the seeds whose
    run did not finish."""
    table = table_from_entries(per_seed)
    out: dict[str, dict[str, Any]] = {}
    for (variant, controller), runs in table.groupby(["variant", "controller"], sort=False):
        ok = succeeded(runs)
        ranked = {}
        for m, _ in _RANKED:  # a metric no run recorded: no seeds
            values = ok.reindex(columns=["seed", m]).replace([math.inf, -math.inf], math.nan).dropna()
            top = values.sort_values([m, "seed"], ascending=[False, True]).head(count)
            ranked[m] = [{"seed": int(s), "value": float(v)} for s, v in zip(top["seed"], top[m])]
        out[run_label(variant, controller)] = {
            "metrics": ranked,
            "flags": {
                f: [int(s) for s in ok["seed"][ok.reindex(columns=[f])[f].eq(True).fillna(False)]]
                for f in _FLAGS
            },
            "failed": [int(s) for s in runs.loc[~runs.index.isin(ok.index), "seed"]],
        }
    return out


def worst_table(worst: Mapping[str, Mapping[str, Any]]) -> str:
    """A markdown table of :func:`worst_runs` (metrics whose worst value is 0 and empty lists left out)."""
    headers = dict(_RANKED)
    lines = ["| controller | metric | worst runs: seed (value) |", "|---|---|---|"]
    for name, entry in worst.items():
        for key, ranked in entry["metrics"].items():
            if ranked and ranked[0]["value"] != 0:
                cells = ", ".join(f"{r['seed']} ({r['value']:.4g})" for r in ranked)
                lines.append(f"| {name} | {headers[key]} | {cells} |")
        for flag, seeds in entry["flags"].items():
            if seeds:
                lines.append(f"| {name} | {flag} | {', '.join(map(str, seeds))} |")
        if entry["failed"]:
            lines.append(f"| {name} | failed | {', '.join(map(str, entry['failed']))} |")
    return "\n".join(lines) + "\n"


def write_figures(out: Path, per_seed: Sequence[Mapping[str, Any]], distributions: bool = True) -> list[str]:
    """metrics.png and, with ``distributions``, one distribution_<metric>.png per metric of the
    table; the file names."""
    done: dict[str, list[Mapping[str, Any]]] = {}
    for seed in per_seed:
        for name, entry in seed["controllers"].items():
            if "error" not in entry:
                done.setdefault(name, []).append(entry)
    if not done:  # no controller finished a run: nothing to draw
        return []
    draw: dict[str, Sequence[tuple[str, str]] | None] = {"metrics.png": None}
    if distributions:
        draw.update({f"distribution_{key}.png": [(key, header)] for key, header in _RANKED})
    for name, keys in draw.items():  # each figure complete or absent (written atomically)
        plot_metrics(done, out / name, keys)
    return list(draw)
