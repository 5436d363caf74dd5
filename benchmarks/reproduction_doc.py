"""Render docs/reproduction.md from docs/results/reproduction.json (see reproduction.py).

Tables over plant draws are mean ± sd (worst): the sample standard deviation (ddof 1) and the
largest value; a change is paired (the same draw at v and at 0.8 v), in % of the value at v. The
page depends on the JSON only.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Iterable, Sequence
from typing import Any

from reproduction_text import page  # the prose, kept apart from the arithmetic

__all__ = ["render"]

CONTROLLERS = ("follow", "paper_0.8v")
#: The STD on the true positions, and its part within the legs of one heading.
STD_KEYS = ("paper_std_mm", "paper_std_within_legs_mm")
EXPERIMENT_TITLES = {
    "plate": ("plate, rectangle", "0.02"),
    "pipe_0.005": ("pipe", "0.005"),
    "pipe_0.02": ("pipe", "0.02"),
    "pipe_0.045": ("pipe", "0.045"),
}
PARAMETER_TITLES = {
    "friction.mu0": "μ0",
    "friction.rate_state.a": "a",
    "friction.rate_state.b": "b",
    "camera.noise_std_m": "camera noise (mm)",
}


def _msw(values: Sequence[float], fmt: str = "{:.2f}") -> str:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return "n/a"
    sd = statistics.stdev(vals) if len(vals) > 1 else 0.0
    sd_fmt = fmt.replace("+", "")
    return f"{fmt.format(statistics.fmean(vals))} ± {sd_fmt.format(sd)} ({fmt.format(max(vals))})"


def _pct(new: float, old: float) -> float:
    return 100.0 * (new - old) / old


def _runs(record: dict[str, Any], exp: str, plant: str, controller: str) -> dict[int, dict[str, Any]]:
    return {
        r["seed"]: r
        for r in record["protocol"]
        if r["experiment"] == exp and r["plant"] == plant and r["controller"] == controller
    }


def _pairs(record: dict[str, Any], exp: str, plant: str) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    v, slow = (_runs(record, exp, plant, c) for c in CONTROLLERS)
    return [(v[s], slow[s]) for s in sorted(v) if s in slow]


def _changes(pairs: Iterable[tuple[dict[str, Any], dict[str, Any]]], key: str) -> list[float]:
    return [_pct(b[key], a[key]) for a, b in pairs if a[key] and b[key] is not None]


def _lower(changes: Sequence[float]) -> str:
    return f"lower on {sum(c < 0 for c in changes)} of {len(changes)}"


def _paper_cell(record: dict[str, Any], exp: str, which: str) -> str:
    paper = record["paper"]
    key = {"v": f"{exp}_v" if exp == "plate" else exp, "0.8v": f"{exp}_0.8v", "change": f"{exp}_change_pct"}
    value = paper.get(key[which])
    if value is None:
        return "n/a"
    return f"{value:+.1f} %" if which == "change" else f"{value:.1f}"


def _row(cells: Sequence[str]) -> str:
    """One row of a Markdown table."""
    return "| " + " | ".join(cells) + " |"


def _head(names: Sequence[str]) -> list[str]:
    """A Markdown table's header row and its rule."""
    return [_row(names), "|" + "---|" * len(names)]


def _side_by_side(record: dict[str, Any], n_lab: int) -> list[str]:
    lines = _head(
        ["experiment", "v (m/s)", "arm", "paper (mm)", "nominal rig (mm)", f"`lab`, {n_lab} draws (mm)"]
    )
    for exp, (title, speed) in EXPERIMENT_TITLES.items():
        ideal, lab = _pairs(record, exp, "ideal"), _pairs(record, exp, "lab")
        for i, (arm, which) in enumerate((("v", "v"), ("0.8 v", "0.8v"))):
            nominal = f"{ideal[0][i]['paper_std_mm']:.2f}" if ideal else "n/a"
            draws = _msw([p[i]["paper_std_mm"] for p in lab])
            cells = [title, speed, arm, _paper_cell(record, exp, which), nominal, draws]
            lines.append(_row(cells))
        lab_change = _changes(lab, "paper_std_mm")
        nominal_change = f"{_changes(ideal, 'paper_std_mm')[0]:+.1f} %" if ideal else "n/a"
        draws_change = f"{_msw(lab_change, '{:+.1f}')} %, {_lower(lab_change)}"
        cells = [title, speed, "change", _paper_cell(record, exp, "change"), nominal_change, draws_change]
        lines.append(_row(cells))
    return lines


def _metric_ways(record: dict[str, Any]) -> list[str]:
    lines = _head(
        [
            "experiment",
            "v (m/s)",
            "true positions, arm moving",
            "camera, arm moving",
            "true positions, t = 0 to the motion's end",
        ]
    )
    for exp, (title, speed) in EXPERIMENT_TITLES.items():
        lab = _pairs(record, exp, "lab")
        cells = [title, speed]
        for key in ("paper_std_mm", "paper_std_camera_mm", "paper_std_window_mm"):
            ch = _changes(lab, key)
            cells.append(f"{_msw(ch, '{:+.1f}')} %, {_lower(ch)}")
        lines.append(_row(cells))
    return lines


def _hidden(record: dict[str, Any]) -> list[str]:
    lines = _head(
        [
            "experiment",
            "v (m/s)",
            "arm",
            "tracking RMS (mm)",
            "final error (mm)",
            "completed",
            "arrival / nominal",
        ]
    )
    for exp, (title, speed) in EXPERIMENT_TITLES.items():
        lab = _pairs(record, exp, "lab")
        for i, arm in enumerate(("v", "0.8 v")):
            runs = [p[i] for p in lab]
            done = f"{sum(bool(r['completed']) for r in runs)}/{len(runs)}"
            cells = [title, speed, arm, _msw([r["tracking_rms_mm"] for r in runs])]
            cells += [_msw([r["final_error_mm"] for r in runs]), done]
            cells += [_msw([r["arrival_ratio"] for r in runs])]
            lines.append(_row(cells))
    return lines


def _headings(record: dict[str, Any]) -> list[str]:
    legs = ["lead, legs along x (mm)", "lead, legs along y (mm)", "STD (mm)", "STD within the legs (mm)"]
    lines = _head(["experiment", "v (m/s)", "arm", *legs])
    for exp, (title, speed) in EXPERIMENT_TITLES.items():
        lab = _pairs(record, exp, "lab")
        for i, arm in enumerate(("v", "0.8 v")):
            runs = [p[i] for p in lab]
            keys = ("lead_x_legs_mm", "lead_y_legs_mm", "paper_std_mm", "paper_std_within_legs_mm")
            cells = [title, speed, arm] + [_msw([r[k] for r in runs]) for k in keys]
            lines.append(_row(cells))
    return lines


def _sensitivity_pair(record: dict[str, Any], parameter: str, value: float) -> list[dict[str, Any]]:
    """The sensitivity's runs of ``follow`` and ``paper_0.8v`` at one value."""
    pair = [r for r in record["sensitivity"] if r["parameter"] == parameter and r["value"] == value]
    return [next(r for r in pair if r["controller"] == c) for c in CONTROLLERS]


def _sensitivity_value(parameter: str, value: float) -> str:
    return f"{value * 1e3:g}" if parameter == "camera.noise_std_m" else f"{value:g}"


def _sensitivity(record: dict[str, Any], nominal: dict[str, float]) -> list[str]:
    stds = ["STD at v (mm)", "STD at 0.8 v (mm)", "change", "change, camera"]
    lines = _head(["constant", "value", *stds, "tracking RMS at v / 0.8 v (mm)"])
    for parameter, title in PARAMETER_TITLES.items():
        for value in record["sensitivity_axes"][parameter]:
            a, b = _sensitivity_pair(record, parameter, value)
            shown = _sensitivity_value(parameter, value)
            shown = f"**{shown}**" if math.isclose(value, nominal[parameter]) else shown
            cells = [title, shown, f"{a['paper_std_mm']:.2f}", f"{b['paper_std_mm']:.2f}"]
            cells += [f"{_pct(b['paper_std_mm'], a['paper_std_mm']):+.1f} %"]
            cells += [f"{_pct(b['paper_std_camera_mm'], a['paper_std_camera_mm']):+.1f} %"]
            cells += [f"{a['tracking_rms_mm']:.2f} / {b['tracking_rms_mm']:.2f}"]
            lines.append(_row(cells))
    return lines


def _not_helping(record: dict[str, Any]) -> list[str]:
    """The sensitivity's values at which 0.8 v does not lower the STD (true positions)."""
    out = []
    for parameter, title in PARAMETER_TITLES.items():
        for value in record["sensitivity_axes"][parameter]:
            a, b = _sensitivity_pair(record, parameter, value)
            if b["paper_std_mm"] >= a["paper_std_mm"]:
                out.append(f"{title} = {_sensitivity_value(parameter, value)}")
    return out


def _pipe_speeds(record: dict[str, Any]) -> list[str]:
    speeds = sorted({r["speed_mps"] for r in record["pipe_speeds"]})
    lines = _head(["friction of the rig", "a - b", *(f"STD at {v:g} m/s (mm)" for v in speeds)])
    paper = record["paper"]
    lines.append("| the paper's rig | | " + " | ".join(f"{paper[f'pipe_{v:g}']:.1f}" for v in speeds) + " |")
    nominal = record["nominal"]
    for law, updates in record["speed_laws"].items():
        a = updates.get("friction.rate_state.a", nominal["friction.rate_state.a"])
        b = updates.get("friction.rate_state.b", nominal["friction.rate_state.b"])
        law_rows = [r for r in record["pipe_speeds"] if r["law"] == law]
        stds = [next(r for r in law_rows if r["speed_mps"] == v) for v in speeds]
        title = "grows with speed (nominal)" if a > b else "weakens with speed"
        cells = [title, f"{a - b:+.3f}"] + [f"{r['paper_std_mm']:.2f}" for r in stds]
        lines.append(_row(cells))
    return lines


def _speed_shape(record: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per friction law: the pipe's STD by speed, whether it falls from the slowest speed to the
    middle one and rises again (the shape of the paper's 5.1 / 4.7 / 4.9 mm), and the STD within
    the legs by speed."""
    out = {}
    for law in record["speed_laws"]:
        rows = sorted((r for r in record["pipe_speeds"] if r["law"] == law), key=lambda r: r["speed_mps"])
        std = [r["paper_std_mm"] for r in rows]
        out[law] = {
            "std": std,
            "within": [r["paper_std_within_legs_mm"] for r in rows],
            "paper_shape": std[0] > std[1] < std[2],
            "grows": all(x < y for x, y in itertools.pairwise(std)),
        }
    return out


def render(record: dict[str, Any]) -> str:
    """The page (module docstring) from the JSON record of ``benchmarks/reproduction.py``."""
    n_lab = len(record["lab_seeds"])
    tables = {
        "side_by_side": "\n".join(_side_by_side(record, n_lab)),
        "metric_ways": "\n".join(_metric_ways(record)),
        "hidden": "\n".join(_hidden(record)),
        "headings": "\n".join(_headings(record)),
        "pipe_speeds": "\n".join(_pipe_speeds(record)),
        "sensitivity": "\n".join(_sensitivity(record, record["nominal"])),
    }
    return page(record, tables, _facts(record))


def _by_slope(record: dict[str, Any]) -> str:
    """The change (%) at each a - b the a and b rows of the sensitivity reach, e.g. ``+0.030: -2.6 %``."""
    nominal = record["nominal"]
    by: dict[float, list[float]] = {}
    for parameter in ("friction.rate_state.a", "friction.rate_state.b"):
        for value in record["sensitivity_axes"][parameter]:
            a = value if parameter.endswith(".a") else nominal["friction.rate_state.a"]
            b = value if parameter.endswith(".b") else nominal["friction.rate_state.b"]
            slow = _sensitivity_pair(record, parameter, value)
            change = _pct(slow[1]["paper_std_mm"], slow[0]["paper_std_mm"])
            by.setdefault(round(a - b, 6), []).append(change)
    parts = []
    for slope in sorted(by, reverse=True):
        changes = " and ".join(f"{c:+.1f} %" for c in sorted(set(by[slope])))
        parts.append(f"{slope:+.3f}: {changes}")
    return "; ".join(parts)


def _between_share(pairs: Sequence[tuple[dict[str, Any], dict[str, Any]]]) -> float:
    """The part (%) of the STD's variance at v that lies between the headings, mean over the draws."""
    shares = [100.0 * (1.0 - (a["paper_std_within_legs_mm"] / a["paper_std_mm"]) ** 2) for a, _ in pairs]
    return _mean(shares)


def _mean(values: Iterable[float]) -> float:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.fmean(vals) if vals else math.nan


def _facts(record: dict[str, Any]) -> dict[str, Any]:
    """Numbers the prose quotes."""
    ideal, lab = _pairs(record, "plate", "ideal"), _pairs(record, "plate", "lab")
    plate_lab = _changes(lab, "paper_std_mm")
    window = {exp: _changes(_pairs(record, exp, "lab"), "paper_std_window_mm") for exp in EXPERIMENT_TITLES}
    gains = [a["paper_std_mm"] - b["paper_std_mm"] for p in (ideal, lab) for a, b in p]
    sens = [_sensitivity_pair(record, k, v) for k in PARAMETER_TITLES for v in record["sensitivity_axes"][k]]
    return {
        "n_lab": len(plate_lab),
        "plate_nominal_change": _changes(ideal, "paper_std_mm")[0] if ideal else math.nan,
        "plate_lab_change": _mean(plate_lab),
        "plate_lab_lower": sum(c < 0 for c in plate_lab),
        "plate_gain_mm": _mean(a["paper_std_mm"] - b["paper_std_mm"] for a, b in lab),
        "plate_camera_change": _mean(_changes(lab, "paper_std_camera_mm")),
        "plate_legs": [_mean(p[0][k] for p in lab) for k in ("lead_x_legs_mm", "lead_y_legs_mm")],
        "plate_std_within": [_mean(p[0][k] for p in lab) for k in STD_KEYS],
        "window_means": {exp: _mean(ch) for exp, ch in window.items()},
        "window_mixed": [e for e, ch in window.items() if any(c < 0 for c in ch) and any(c >= 0 for c in ch)],
        "gain_range_mm": (min(gains), max(gains)) if gains else (math.nan, math.nan),
        "plate_track": [_mean(p[i]["tracking_rms_mm"] for p in lab) for i in (0, 1)],
        "plate_final": [_mean(p[i]["final_error_mm"] for p in lab) for i in (0, 1)],
        "plate_done": [sum(bool(p[i]["completed"]) for p in lab) for i in (0, 1)],
        "plate_arrival": [_mean(p[i]["arrival_ratio"] for p in lab) for i in (0, 1)],
        "not_helping": _not_helping(record),
        "sensitivity_gain_mm": (
            min(a["paper_std_mm"] - b["paper_std_mm"] for a, b in sens),
            max(a["paper_std_mm"] - b["paper_std_mm"] for a, b in sens),
        ),
        "speed_shape": _speed_shape(record),
        "by_slope": _by_slope(record),
        "between_share_pct": {exp: _between_share(_pairs(record, exp, "lab")) for exp in EXPERIMENT_TITLES},
    }
