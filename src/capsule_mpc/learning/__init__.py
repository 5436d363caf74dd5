"""Learning the friction relation c(v) from demonstrations (paper §IV-C).

Run logs (or per-sample CSVs) -> per-sample mu and c -> least-squares polynomial
c(v) -> a :class:`~capsule_mpc.config.LearnedFrictionModel` YAML that a scenario
loads as ``friction.learned``.

Static friction and its healing from breakaway experiments: :mod:`.breakaway`
(:func:`learn_static_friction`, :func:`fit_healing`); :func:`learn_from_logs` uses the
breakaway logs among its inputs for them.

Main entry points: :func:`learn_from_logs`, :func:`learn_from_samples_csv`,
:func:`learn_friction`, :func:`write_model`, :func:`steady_lead`. Every fit carries a
verdict (:class:`FitQuality`: weak or not, and why) and, from logs, a check that each log
is an open-loop demonstration (:class:`LoopCheck`). Demonstrations in the
simulator are in :mod:`capsule_mpc.learning.demonstrations` (not imported here: the fit
itself does not depend on the simulator).
"""

from .breakaway import (
    BreakawayEvent,
    HealingFit,
    StaticFrictionResult,
    detect_breakaway,
    fit_healing,
    learn_static_friction,
)
from .core import (
    LearningResult,
    learn_friction,
    learn_from_logs,
    learn_from_samples_csv,
    model_yaml,
    write_model,
)
from .data import (
    EXCLUSION_REASONS,
    MIN_LOG_RATIO,
    SAMPLE_COLUMNS,
    SPEED_FLOOR_MPS,
    CSamples,
    FrictionConstants,
    FrictionSamples,
    LearningDataError,
    per_sample_c,
    read_samples_csv,
    write_samples_csv,
)
from .fit import PolynomialFit, fit_c_polynomial, synthetic_samples
from .heldout import SteadyLead, measured_steady_lead, predicted_steady_lead
from .logs import (
    LogOptions,
    RunLog,
    find_run_logs,
    log_samples,
    read_run_log,
    samples_from_logs,
    samples_from_run_logs,
)
from .openloop import LoopCheck, check_open_loop
from .predict import law_mu, plant_mu, steady_lead
from .quality import FitQuality, assess_fit

__all__ = [
    "EXCLUSION_REASONS",
    "MIN_LOG_RATIO",
    "SAMPLE_COLUMNS",
    "SPEED_FLOOR_MPS",
    "BreakawayEvent",
    "CSamples",
    "FitQuality",
    "FrictionConstants",
    "FrictionSamples",
    "HealingFit",
    "LearningDataError",
    "LearningResult",
    "LogOptions",
    "LoopCheck",
    "PolynomialFit",
    "RunLog",
    "StaticFrictionResult",
    "SteadyLead",
    "assess_fit",
    "check_open_loop",
    "detect_breakaway",
    "find_run_logs",
    "fit_c_polynomial",
    "fit_healing",
    "law_mu",
    "learn_friction",
    "learn_from_logs",
    "learn_from_samples_csv",
    "learn_static_friction",
    "log_samples",
    "measured_steady_lead",
    "model_yaml",
    "per_sample_c",
    "plant_mu",
    "predicted_steady_lead",
    "read_run_log",
    "read_samples_csv",
    "samples_from_logs",
    "samples_from_run_logs",
    "steady_lead",
    "synthetic_samples",
    "write_model",
    "write_samples_csv",
]
