"""The one aggregation of run tables (:mod:`.table`): mean ± sd, worst and paired differences.

Every summary of a campaign -- ``compare``'s and ``sweep``'s ``summary.json`` and ``summary.md``,
the benchmarks' reports and the tables of ``docs/results.md`` -- is computed here with pandas
``groupby`` over the rows of the runs that finished (``error`` empty):

* a numeric metric: ``mean``, ``sd`` (sample standard deviation, ddof 1; 0 for one value),
  ``min``, ``median``, ``worst`` (the largest: every metric is worse when larger), ``n`` (finite values;
  NaN values are left out) and ``sum``;
* a true/false flag: ``count`` (runs where true) and ``n``;
* per group ``runs`` (rows that finished) and ``failed`` (rows whose controller raised).

:func:`paired` gives, per group, the difference to a baseline run on the same seed: ``mean``,
``sd``, ``worst``, ``n``, ``better`` (draws where it is below the baseline's) and ``relative``
(the mean difference over the baseline's mean on the same draws).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import pandas as pd
from pandas.api.types import is_bool_dtype, is_numeric_dtype

from .table import KEYS

__all__ = ["aggregate", "mean_sd_worst", "paired", "succeeded"]

#: The numeric statistics of a metric, as pandas names them, and their names here.
_STATS = {
    "mean": "mean",
    "std": "sd",
    "min": "min",
    "median": "median",
    "max": "worst",
    "count": "n",
    "sum": "sum",
}
#: Columns that describe a row rather than measure it.
_NOT_METRICS = frozenset({*KEYS, "error", "window_end_s"})


def succeeded(table: pd.DataFrame) -> pd.DataFrame:
    """The rows of runs that finished (``error`` empty or absent)."""
    return table if "error" not in table else table[table["error"].fillna("") == ""]


def aggregate(
    table: pd.DataFrame,
    by: Sequence[str] = ("variant", "controller"),
    metrics: Sequence[str] | None = None,
    quantiles: Mapping[str, float] | None = None,
) -> pd.DataFrame:
    """Per group of ``by`` (in order of first appearance): the statistics of every metric and flag.

    ``metrics`` default to every numeric column but the keys, flags and the draw's ``plant.*`` and
    ``varied.*`` values; flags are always counted; ``quantiles`` adds statistics by name (e.g.
    ``{"p95": 0.95}``). The columns are ``(metric, stat)``, ``(flag, "count" | "n")``, ``("runs",
    "n")`` and ``("failed", "n")``; a group none of whose runs finished has NaN statistics.
    """
    keys = list(by)
    ok = succeeded(table)
    measured = [c for c in table.columns if c not in _NOT_METRICS and is_numeric_dtype(table[c])]
    flags = [c for c in measured if is_bool_dtype(table[c])]
    if metrics is None:
        metrics = [c for c in measured if c not in flags and not c.startswith(("plant.", "varied."))]
    groups = table.groupby(keys, sort=False).size().index
    parts = []
    if metrics:
        stats = ok.groupby(keys, sort=False)[metrics].agg(list(_STATS)).rename(columns=_STATS, level=1)
        for m in metrics:  # one value: sd 0 (pandas gives NaN for ddof 1)
            stats[(m, "sd")] = stats[(m, "sd")].where(stats[(m, "n")] != 1, 0.0)
        parts.append(stats)
        for name, q in (quantiles or {}).items():
            part = ok.groupby(keys, sort=False)[metrics].quantile(q)
            parts.append(part.set_axis(pd.MultiIndex.from_product([metrics, [name]]), axis=1))
    if flags:
        counted = ok[[*keys, *flags]].astype({f: "float" for f in flags}).groupby(keys, sort=False)[flags]
        parts.append(counted.agg(["sum", "count"]).rename(columns={"sum": "count", "count": "n"}, level=1))
    done = ok.groupby(keys, sort=False).size().reindex(groups, fill_value=0)
    total = table.groupby(keys, sort=False).size().reindex(groups, fill_value=0)
    counts = pd.DataFrame({("runs", "n"): done, ("failed", "n"): total - done})
    return pd.concat([p.reindex(groups) for p in parts] + [counts], axis=1)


def paired(
    table: pd.DataFrame,
    baseline: Mapping[str, str],
    metrics: Sequence[str],
    by: Sequence[str] = ("variant", "controller"),
) -> pd.DataFrame:
    """Per group of ``by``, each metric's difference to the ``baseline``'s run on the same seed.

    ``baseline`` selects its rows (e.g. ``{"variant": "paper"}``); the baseline's own group is
    included, its differences 0. Columns ``(metric, stat)`` for ``mean``, ``sd``, ``worst``, ``n``,
    ``better`` and ``relative``, over the seeds where both finished.
    """
    keys = list(by)
    ok = succeeded(table)
    base = ok.loc[(ok[list(baseline)] == pd.Series(baseline)).all(axis=1), ["seed", *metrics]]
    merged = ok[[*keys, "seed", *metrics]].merge(base, on="seed", suffixes=("", "@base"))
    diffs = merged[keys].assign(**{m: merged[m] - merged[m + "@base"] for m in metrics})
    stats = aggregate(diffs, keys, metrics)
    out = {}
    for m in metrics:
        out.update({(m, stat): stats[(m, stat)] for stat in ("mean", "sd", "worst", "n")})
        out[(m, "better")] = diffs.groupby(keys, sort=False)[m].agg(lambda d: int((d < 0).sum()))
        out[(m, "relative")] = stats[(m, "mean")] / merged.groupby(keys, sort=False)[m + "@base"].mean()
    return pd.DataFrame(out)


def mean_sd_worst(mean: float, sd: float, worst: float, digits: int = 2) -> str:
    """``mean ± sd (worst)``, each with ``digits`` decimals; ``n/a`` when the mean is not finite."""
    if not isinstance(mean, (int, float)) or not math.isfinite(mean):
        return "n/a"
    return f"{mean:.{digits}f} ± {sd:.{digits}f} ({worst:.{digits}f})"
