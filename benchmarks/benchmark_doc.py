"""The benchmark's reference scores: run ``capsule-mpc benchmark`` for the package's controllers and
a random policy, and render the table in docs/benchmark.md from its leaderboard.json.

    python benchmarks/benchmark_doc.py --draws 3     # run (into docs/results/benchmark/), render
    python benchmarks/benchmark_doc.py               # render the table from the JSON only
    python benchmarks/benchmark_doc.py --check       # exit 1 if docs/benchmark.md is not up to date

The table replaces what stands between the two marker lines of docs/benchmark.md; the rest of the
page is prose kept by hand. It depends on the JSON only.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from _args import int_at_least

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "results" / "benchmark"
DOC = ROOT / "docs" / "benchmark.md"
START, END = "<!-- reference-scores:start -->", "<!-- reference-scores:end -->"
#: The reference entrants, in column order: (option, value, column title).
ENTRANTS = (
    ("--controller", "follow", "`follow`"),
    ("--controller", "paper_0.8v", "`paper_0.8v`"),
    ("--controller", "plan", "`plan`"),
    ("--controller", "mpc", "`mpc`"),
    ("--policy", "capsule_mpc.envs.policies:random_policy", "random policy"),
)


def run(draws: int) -> None:
    """Run the benchmark for :data:`ENTRANTS` into :data:`DATA`."""
    argv = [w for opt, value, _ in ENTRANTS for w in (opt, value)]
    code = "import sys; from capsule_mpc.cli import main; sys.exit(main(sys.argv[1:]))"
    cmd = [sys.executable, "-c", code, "benchmark", *argv, "--draws", str(draws), "--out", str(DATA)]
    subprocess.run(cmd, check=False)  # exit 1 when an entrant raised on a run: its rows say so


def _cell(row: dict[str, Any] | None) -> str:
    if row is None:
        return "n/a"
    n, ok = row["n_runs"], round(row["success_rate"] * row["n_runs"])
    mean, sd, worst = (row.get(k) for k in ("score_mean", "score_sd", "score_worst"))
    if mean is None or not math.isfinite(mean):
        return f"n/a, {ok}/{n}"
    return f"{mean:.2f} ± {sd:.2f} ({worst:.2f}), {ok}/{n}"


def measured_on() -> str:
    """When the reference scores were measured: the benchmark command's manifest, UTC."""
    manifest = json.loads((DATA / "manifest.json").read_text(encoding="utf-8"))
    return f"{manifest['started'][:16].replace('T', ' ')} to {manifest['finished'][11:16]} UTC"


def render_table(record: dict[str, Any]) -> str:
    """The reference-score table: a row per task and preset, a column per entrant."""
    meta = record["meta"]
    by_key = {(r["entrant"], r["task"], r["preset"]): r for r in record["leaderboard"]}
    names = [value for _, value, _ in ENTRANTS]
    cases = list(dict.fromkeys((r["task"], r["preset"]) for r in record["leaderboard"]))
    seeds = meta["seeds"]
    lines = [
        f"Score (mm; `place`: final error, else tracking RMS) mean ± sd (worst), and successful runs, over "
        f"{meta['draws']} draws per task and preset (seeds {seeds[0]} to {seeds[-1]}), measured "
        f"{measured_on()} by `{meta['command']}`.",
        "",
        "| task | preset | " + " | ".join(title for _, _, title in ENTRANTS) + " |",
        "|---|---|" + "---|" * len(ENTRANTS),
    ]
    for task, preset in cases:
        cells = [_cell(by_key.get((name, task, preset))) for name in names]
        lines.append(f"| `{task}` | `{preset}` | " + " | ".join(cells) + " |")
    cpu = {name: sum(r["cpu_s"] for r in record["runs"] if r["entrant"] == name) for name in names}
    spent = ", ".join(f"{title} {cpu[name]:.0f} s" for (_, name, title) in ENTRANTS)
    lines += ["", f"CPU time of the whole suite per entrant: {spent}. The first run on a machine also"]
    lines += ["builds the plant's shared magnet table and the MPC's compiled solver (then cached)."]
    return "\n".join(lines) + "\n"


def render(doc: str, record: dict[str, Any]) -> str:
    """``doc`` with the table between the markers replaced."""
    head, rest = doc.split(START, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{START}\n{render_table(record)}{END}{tail}"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int_at_least(1, 1000), default=None, help="run with N draws first")
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/benchmark.md is stale")
    args = parser.parse_args(argv)
    if args.draws is not None:
        run(args.draws)
    record = json.loads((DATA / "leaderboard.json").read_text(encoding="utf-8"))
    doc = DOC.read_text(encoding="utf-8")
    text = render(doc, record)
    if args.check:
        print("docs/benchmark.md is " + ("stale" if text != doc else "up to date"))
        return int(text != doc)
    DOC.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
