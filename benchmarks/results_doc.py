"""Render docs/results.md from the result files in docs/results/ and its templates.

Every number in docs/results.md comes from a file written by a benchmark or a ``capsule-mpc``
command, copied into ``docs/results/``. ``docs/results/sources.json`` lists, per section, the file
it is rendered from and the provenance the file itself may not record (the command that wrote
it, the date, the machine, its load); ``docs/results/sections.md`` holds the prose (each section's
title, renderer and text) and ``docs/results/tables.md.j2`` the tables, one Jinja macro per
renderer. A campaign's data (a sweep's ``summary.json``, a friction ablation's or fault campaign's
report) is read as a run table (:mod:`capsule_mpc.experiments.table`) and summarised by
:func:`capsule_mpc.experiments.aggregate.aggregate` (mean ± sd (worst): the sample standard
deviation, ddof 1, and the largest value) and :func:`~capsule_mpc.experiments.aggregate.paired`
before its macro formats it. The prose is a Jinja template too: its paired figures
(``{{ paired(base, new, metric) }}``) come from the sweeps' run tables by the same
:func:`~capsule_mpc.experiments.aggregate.paired`. The output depends on the files only.

    python benchmarks/results_doc.py            # write docs/results.md
    python benchmarks/results_doc.py --check    # exit 1 if docs/results.md is not up to date
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import shlex
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jinja2
import pandas as pd

from capsule_mpc.experiments.aggregate import aggregate, mean_sd_worst, paired
from capsule_mpc.experiments.compare import CONTROLLER_ORDER
from capsule_mpc.experiments.table import table_from_entries

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "results"
OUT = ROOT / "docs" / "results.md"
#: The manifest in the data folder: per section, its data file and provenance.
SOURCES = "sources.json"
#: The templates in the data folder: the prose and the sections in order; the tables.
TEMPLATE, TABLES = "sections.md", "tables.md.j2"
COMMAND = "python benchmarks/results_doc.py"
README = ROOT / "README.md"
#: The README's rendered tables, each between its opening marker and :data:`README_CLOSE`: the
#: placement campaigns' summaries, and the controllers on the rectangle's held-out draws.
README_OPEN = "<!-- placement table: rendered by benchmarks/results_doc.py -->"
README_CLOSE = "<!-- end of the rendered table -->"
README_DATA = ("placement_lab/summary.json", "placement_hard/summary.json")
README_CONTROLLERS_OPEN = "<!-- controllers table: rendered by benchmarks/results_doc.py -->"
README_CONTROLLERS_DATA = ("sweep_rectangle_lab/summary.json",)

#: The metrics of the ablation's table, in order.
ABLATION_METRICS = ("tracking_rms_mm", "cross_track_rms_mm", "start_tracking_rms_mm", "final_error_mm")
#: Final error counted as reached, mm (the benchmarks' default tolerance).
FINAL_TOL_MM = 0.5
#: The ablation's controller, and the baseline of its paired differences.
ABLATION_CONTROLLER, BASELINE = "mpc", "paper"
#: Targets of the placement, as the camera sees it (mm): ``lab`` and ``hard`` draws.
PLACED_SEEN_MM = {"lab": 0.2, "hard": 0.3}
#: The truth may miss the target by the camera's bias plus this, mm.
PLACED_TRUTH_MARGIN_MM = 0.2
#: First motion within this multiple of the draw's arm-limited bound counts as prompt.
START_BOUND_FACTOR = 1.3
#: A placement counts as quick within this time from the path's nominal end, s.
QUICK_PLACE_S = 2.0
#: A learned breakaway within this relative error of the plant's counts as right, %.
BREAKAWAY_TOL_PCT = 10.0


# ----------------------------------------------------------------------------- formatting helpers
def fmt(value: Any, spec: str = "") -> str:
    """``value`` formatted with ``spec``; ``n/a`` for a missing or non-finite number."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return format(value, spec)


def cell(stats: pd.Series, metric: str, total: int, digits: int = 2) -> str:
    """mean ± sd (worst) of a metric's finite values, with how many were finite when some were not."""
    n = int(stats[(metric, "n")]) if (metric, "n") in stats else 0
    if not n:
        return "n/a"
    text = mean_sd_worst(stats[(metric, "mean")], stats[(metric, "sd")], stats[(metric, "worst")], digits)
    return text if n == total else f"{text} [{n}/{total}]"


def count(stats: pd.Series, flag: str) -> int:
    """How many runs raised ``flag`` (0 when no run recorded it)."""
    return int(stats[(flag, "count")]) if (flag, "count") in stats and stats[(flag, "n")] else 0


def seeds(values: Sequence[int]) -> str:
    """``0-19`` (en dash) for a contiguous run of seeds, else the list."""
    s = sorted(values)
    if s and s == list(range(s[0], s[-1] + 1)):
        return f"{s[0]}\u2013{s[-1]}" if len(s) > 1 else str(s[0])
    return ", ".join(map(str, s))


def paired_cell(metric: str, stats: pd.Series, diff: pd.Series | None, total: int) -> str:
    """:func:`cell`, then the paired difference to the baseline: mean (better on k draws)."""
    text = cell(stats, metric, total)
    if diff is None:
        return text
    return f"{text}; {diff[(metric, 'mean')]:+.2f} ({int(diff[(metric, 'better')])})"


# --------------------------------------------------------------------- the prose's paired figures
@functools.cache
def _runs(path: Path) -> pd.DataFrame:
    """The run table of a sweep's ``summary.json`` (``path``, or the one in the folder ``path``)."""
    path = path / "summary.json" if path.is_dir() else path
    return table_from_entries(json.loads(path.read_text(encoding="utf-8"))["runs"])


def pairing(data_dir: Path) -> Callable[..., str]:
    """The prose's ``paired(base, new, metric, digits=2, part="diff")``: a metric's difference from
    the runs of ``base`` to those of ``new`` (sweeps in ``data_dir``) on the same seeds, by the one
    aggregation (:func:`~capsule_mpc.experiments.aggregate.paired`). ``part`` is ``diff`` (mean ±
    standard error, signed), ``lower`` (draws where ``new`` is lower) or ``n`` (draws paired)."""

    def figure(base: str, new: str, metric: str, digits: int = 2, part: str = "diff") -> str:
        table = pd.concat(
            [_runs(data_dir / base).assign(variant="base"), _runs(data_dir / new).assign(variant="new")]
        )
        row = paired(table, {"variant": "base"}, [metric], by=["variant"]).loc["new", metric]
        if part == "lower":
            return str(int(row["better"]))
        if part == "n":
            return str(int(row["n"]))
        se = row["sd"] / math.sqrt(row["n"])
        return f"{row['mean']:+.{digits}f} ± {se:.{digits}f}".replace("-", "\u2212")

    return figure


# ------------------------------------------------------------------------- campaigns' aggregation
def campaign_context(data: dict[str, Any]) -> dict[str, Any]:
    """A sweep's ``summary.json`` per controller over its runs: ``rows`` (name, statistics, runs) in
    :data:`~capsule_mpc.experiments.compare.CONTROLLER_ORDER`, others alphabetically, with the flags
    of a run that ended placed (as seen and in truth), gave up or first moved promptly; ``moves``,
    per controller the time to place by the moves a run took."""
    table = table_from_entries(data["runs"])
    preset = data.get("plant_preset", "?")
    seen_mm = PLACED_SEEN_MM.get(preset, 0.2)
    table["final_within_tol"] = table["final_error_mm"] <= FINAL_TOL_MM
    if "final_error_seen_mm" in table:
        table["seen_ok"] = table["final_error_seen_mm"] <= seen_mm
        table["truth_ok"] = table["final_error_mm"] <= table["camera_bias_mm"] + PLACED_TRUTH_MARGIN_MM
    if "end_phase" in table:
        table["gave_up"] = table["end_phase"].astype(str) == "failed"
    if "first_motion_ratio" in table:
        ratio = table["first_motion_ratio"]
        table["prompt"] = (ratio <= START_BOUND_FACTOR).astype("boolean").mask(ratio.isna())
    stats = aggregate(table, by=["controller"], quantiles={"p95": 0.95})
    present = list(stats.index)
    names = [n for n in CONTROLLER_ORDER if n in present] + sorted(set(present) - set(CONTROLLER_ORDER))
    totals = stats[("runs", "n")] + stats[("failed", "n")]
    moves = {}
    if "placement_moves" in table:
        by_moves = aggregate(table, by=["controller", "placement_moves"], metrics=["time_to_place_s"])
        placed = set(by_moves.index.get_level_values(0))  # a controller without moves has no rows
        moves = {n: list(by_moves.sort_index().loc[n].iterrows()) for n in names if n in placed}
    config = data.get("config")
    varied = "".join(
        f"; plant.{f} drawn from U({lo:g}, {hi:g})" for f, (lo, hi) in data.get("vary", {}).items()
    )
    return {
        **data,
        "rows": [(n, stats.loc[n], int(totals[n])) for n in names],
        "moves": moves,
        "seeds": [r["seed"] for r in data["runs"]],
        "preset": preset,
        "config": Path(config).name if isinstance(config, str) else "?",
        "varied": varied,
        "tol": FINAL_TOL_MM,
        "seen_mm": seen_mm,
        "margin_mm": PLACED_TRUTH_MARGIN_MM,
        "bound": START_BOUND_FACTOR,
    }


#: A sweep's table and its placement's are rendered from one aggregation.
sweep_context = placement_context = campaign_context


def _ablation_rows(data: dict[str, Any], metrics: Sequence[str]) -> dict[str, Any]:
    """The MPC's runs of an ablation per variant that every draw ran, in the report's order: (label,
    statistics, paired difference to the baseline or None)."""
    table = table_from_entries(data["runs"])
    table = table[table["controller"] == ABLATION_CONTROLLER].copy()
    table["final_within_tol"] = table["final_error_mm"] <= FINAL_TOL_MM
    if "time_to_place_s" in table:
        table["quick"] = table["time_to_place_s"] <= QUICK_PLACE_S
    n = int(table["seed"].nunique())
    stats = aggregate(table, by=["variant"])
    labels = data["variants"]
    variants = [v for v in labels if v in stats.index and stats.loc[v, ("runs", "n")] == n]
    diffs = paired(table, {"variant": BASELINE}, list(metrics), by=["variant"])
    compared = BASELINE in variants
    rows = [(labels[v], stats.loc[v], diffs.loc[v] if compared and v != BASELINE else None) for v in variants]
    runs = data["runs"]
    return {**data, **_breakaway(runs), "rows": rows, "n": n, "seeds": [r["seed"] for r in runs]}


def ablation_context(data: dict[str, Any]) -> dict[str, Any]:
    """The friction ablation per variant: mean ± sd (worst) and the paired difference to ``paper``."""
    out = _ablation_rows(data, ABLATION_METRICS)
    partial = sum(bool(d.get("learning", {}).get("demonstrations_failed")) for d in data["runs"])
    failed = [f["seed"] for f in data.get("draws_failed", [])]
    started = len(data.get("seeds", out["seeds"]))
    return {**out, "metrics": ABLATION_METRICS, "tol": FINAL_TOL_MM, "partial": partial, "failed": failed,
            "started": started}  # fmt: skip


def placement_ablation_context(data: dict[str, Any]) -> dict[str, Any]:
    """The ablation's placement per variant: moves (paired difference to ``paper``), time to place."""
    return {**_ablation_rows(data, ["placement_moves"]), "quick_s": QUICK_PLACE_S}


def _breakaway(draws: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The learned breakaway coefficient against the plant's at the path's start, after 2 s at rest
    and (where recorded) after the rest the draw's capsule had before its run: per check the
    statistics of the |relative error|, %, and the draws within :data:`BREAKAWAY_TOL_PCT`."""
    learning = pd.DataFrame([d["learning"] for d in draws if d.get("learning")])
    if "breakaway_mu_learned" not in learning or learning["breakaway_mu_learned"].isna().all():
        return {"breakaway": [], "unlearned": 0}
    learned = learning[learning["breakaway_mu_learned"].notna()]
    checks = {"after 2 s at rest": ("breakaway_mu_learned", "breakaway_mu_plant")}
    if "breakaway_mu_plant_start" in learned and learned["breakaway_mu_plant_start"].notna().all():
        checks["after the rest before the draw's run"] = (
            "breakaway_mu_learned_start",
            "breakaway_mu_plant_start",
        )
    rows = [
        pd.DataFrame({"check": when, "error_pct": 100 * (learned[mine] / learned[plant] - 1).abs()})
        for when, (mine, plant) in checks.items()
    ]
    errors = pd.concat(rows, ignore_index=True)
    errors["within"] = errors["error_pct"] <= BREAKAWAY_TOL_PCT
    stats = aggregate(errors, by=["check"])
    return {
        "breakaway": [(when, stats.loc[when], len(learned)) for when in checks],
        "unlearned": len(learning) - len(learned),
    }


def breakaway_context(data: dict[str, Any]) -> dict[str, Any]:
    """The learned breakaway on each draw (``friction_ablation.py --learn-only``)."""
    draws = data["runs"]
    return {**data, **_breakaway(draws), "n": len(draws), "seeds": [d["seed"] for d in draws]}


def faults_context(data: dict[str, Any]) -> dict[str, Any]:
    """A fault campaign's report: each seed with and without faults, aggregated."""
    rows = []
    for run in data["per_run"]:
        for variant, suffix in (("faults", ""), ("no faults", "_no_faults")):
            metrics = {m: run[m + suffix] for m in ("tracking_rms_mm", "final_error_mm")}
            rows.append({"seed": run["seed"], "variant": variant, "controller": "mpc", **metrics})
    return {**data, "stats": aggregate(pd.DataFrame(rows), by=["variant"]), "n": len(data["per_run"])}


def hpipm_context(data: dict[str, Any]) -> dict[str, Any]:
    """HPIPM's barrier parameters, once their totals are checked against the cases."""
    for i, first in enumerate(data["cases"][0]["results"]):
        total = data["totals"].get(str(first["mu0"]))
        if total is not None and total["not_solved"] != sum(
            c["results"][i]["not_solved"] for c in data["cases"]
        ):
            raise ValueError(f"hpipm_mu0: totals of mu0 {first['mu0']} disagree with its cases")
    return data


#: What a renderer's macro is given beside the data file: the aggregation of a campaign.
CONTEXTS: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
    name.removesuffix("_context"): fn for name, fn in globals().items() if name.endswith("_context")
}


# --------------------------------------------------------------------------------------- document
@functools.cache
def tables(data_dir: Path) -> Any:
    """The macros of the tables' template (one per renderer)."""
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(data_dir),
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
    )
    env.globals.update(fmt=fmt, cell=cell, count=count, seeds=seeds)
    env.filters.update(paired_cell=paired_cell, c_at=lambda key, values, spec=".4f": fmt(values[key], spec))
    return env.get_template(TABLES).module


def section_lines(renderer: str, data: dict[str, Any], data_dir: Path = DATA) -> list[str]:
    """The lines ``renderer``'s macro renders from ``data`` (after its campaign's aggregation)."""
    context = CONTEXTS.get(renderer, lambda d: d)(data)
    return str(getattr(tables(data_dir), renderer)(context)).strip("\n").split("\n")


def _provenance(entry: dict[str, Any], data: dict[str, Any], data_dir: Path) -> list[str]:
    """The command, date, machine and load of a section's data (the ``provenance`` macro).

    The command and date come from the ``manifest.json`` a ``capsule-mpc`` command left beside its
    output when ``entry`` names one (``manifest``), else from the data file when it records its
    command line, else from ``entry``; two sources that disagree are an error.
    """
    command = data.get("command") if isinstance(data.get("command"), str) and " " in data["command"] else None
    date = entry.get("date")
    if entry.get("manifest"):
        manifest = json.loads((data_dir / entry["manifest"]).read_text(encoding="utf-8"))
        if manifest.get("status") != "complete":
            raise ValueError(f"{entry['manifest']}: the command did not complete ({manifest.get('status')})")
        command = "capsule-mpc " + " ".join(shlex.quote(a) for a in manifest["argv"])
        date = f"{manifest['started']} to {manifest['finished']}"
    if entry.get("command"):
        if command and entry["command"] != command:
            raise ValueError(f"{entry['file']}: sources.json and the data disagree on the command")
        command = entry["command"]
    if not command or not date:
        raise ValueError(f"{entry['file']}: no command or no date recorded")
    return str(tables(data_dir).provenance(entry, command, date)).strip("\n").split("\n")


def read_template(data_dir: Path) -> tuple[str, list[tuple[str, str, str, str]]]:
    """The template's opening text and its sections: (key, renderer, title, text)."""
    text = (data_dir / TEMPLATE).read_text(encoding="utf-8")
    text = text[text.index("-->") + 3 :] if text.startswith("<!--") else text
    opening, *blocks = text.split("\n## ")
    macros = tables(data_dir)
    sections = []
    for block in blocks:
        heading, _, prose = block.partition("\n")
        key, renderer, title = (part.strip() for part in heading.split("|", 2))
        if not hasattr(macros, renderer):
            raise ValueError(f"{TEMPLATE}: section {key}: no macro {renderer!r} in {TABLES}")
        sections.append((key, renderer, title, prose.strip()))
    return opening.strip(), sections


def render(data_dir: Path) -> str:
    """docs/results.md from the files in ``data_dir`` (its ``sources.json``, templates and data)."""
    sources = json.loads((data_dir / SOURCES).read_text(encoding="utf-8"))["sections"]
    opening, sections = read_template(data_dir)
    unknown = set(sources) - {key for key, *_ in sections}
    if unknown:
        raise ValueError(f"{SOURCES}: sections without a renderer: {sorted(unknown)}")
    out = [
        "# Results (simulated rig)",
        "",
        f"<!-- Generated by `{COMMAND}` from docs/results/*.json; do not edit by hand. -->",
        "",
        opening,
        "",
    ]
    # The prose may quote paired figures of run tables: {{ paired(base, new, metric, ...) }}.
    prose_env = jinja2.Environment(undefined=jinja2.StrictUndefined, keep_trailing_newline=False)
    prose_env.globals["paired"] = pairing(data_dir)
    present = [s for s in sections if s[0] in sources]
    out += [f"- [{title}](#{_anchor(title)})" for _, _, title, _ in present]
    for key, renderer, title, what in present:
        entry = sources[key]
        data = json.loads((data_dir / entry["file"]).read_text(encoding="utf-8"))
        rendered = section_lines(renderer, data, data_dir)
        prose = prose_env.from_string(what).render()
        out += ["", f"## {title}", "", prose, "", *rendered, "", *_provenance(entry, data, data_dir)]
    return "\n".join(out) + "\n"


def render_readme(text: str, data_dir: Path) -> str:
    """``text`` (the README) with its placement table rendered from :data:`README_DATA` and its
    controllers table from :data:`README_CONTROLLERS_DATA`."""
    blocks = (
        (README_OPEN, "readme_placement", README_DATA),
        (README_CONTROLLERS_OPEN, "readme_controllers", README_CONTROLLERS_DATA),
    )
    macros = tables(data_dir)
    for opening, macro, files in blocks:
        head, found, rest = text.partition(opening)
        _, closed, tail = rest.partition(README_CLOSE)
        if not (found and closed):
            raise ValueError(f"README.md: no {opening!r} ... {README_CLOSE!r} block")
        contexts = [campaign_context(json.loads((data_dir / f).read_text(encoding="utf-8"))) for f in files]
        table = str(getattr(macros, macro)(contexts)).strip("\n")
        text = f"{head}{opening}\n{table}\n{README_CLOSE}{tail}"
    return text


def _anchor(title: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    kept = "".join(c for c in title.lower() if c.isalnum() or c in " -_")
    return kept.replace(" ", "-")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the JSON and sources.json")
    parser.add_argument("--out", type=Path, default=OUT, help="the Markdown file to write")
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if --out is stale")
    parser.add_argument("--readme", type=Path, default=README, help="the README whose table to render")
    args = parser.parse_args(argv)
    readme = args.readme.read_text(encoding="utf-8")
    outputs = {args.out: render(args.data), args.readme: render_readme(readme, args.data)}
    if args.check:
        stale = [p for p, text in outputs.items() if not p.exists() or p.read_text(encoding="utf-8") != text]
        for path in stale:
            print(f"{path} is not up to date: run `{COMMAND}`", file=sys.stderr)
        return 1 if stale else 0
    for path, text in outputs.items():
        path.write_text(text, encoding="utf-8")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
