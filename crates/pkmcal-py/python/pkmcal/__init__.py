"""pkmcal: kinematic calibration of (redundantly actuated) parallel mechanisms.

A mechanism (the built-in reference, or a TOML description), commands and
measured positions as NumPy arrays in, identified parameters with their
uncertainties, identifiability, before/after accuracy, figures and corrected
commands out. Arrays are in mm, rad, N and N·m; pose numbers in results and
exceptions are row indices (from 0) of the arrays given.

>>> import pkmcal
>>> mech = pkmcal.Mechanism()                      # the built-in reference
>>> targets = pkmcal.plan(mech, 35).targets         # where to measure
>>> commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=1)
>>> cal = pkmcal.calibrate(mech, commands, measured, frame="base")  # simulated in the base frame
>>> round(cal.parameters["l11"], 1)
280.3

Functions: predict, nominal_commands, simulate, calibrate, analyze,
compensate, plan, montecarlo, budget, drift, trilaterate. Classes: Mechanism, Calibration,
Identifiability, ErrorStats, Warning, Figure, Prediction, Compensation, Plan,
MonteCarlo, Budget, Drift, SavedCalibration. Every result pickles and compares by value.
Errors: PkmcalError (a ValueError) with the message and ``.pose``. A
calibration's warnings are also emitted with ``warnings.warn``, once per call,
as PkmcalWarning (a UserWarning) subclasses: ConvergenceWarning,
IdentifiabilityWarning, OutlierWarning, ToleranceWarning, ModelWarning. Arrays with named columns (a pandas
DataFrame, a NumPy structured array) are read by name.
"""

from ._pkmcal import (
    Budget,
    Calibration,
    Compensation,
    ConvergenceWarning,
    Drift,
    ErrorStats,
    Figure,
    Identifiability,
    IdentifiabilityWarning,
    Mechanism,
    ModelWarning,
    MonteCarlo,
    OutlierWarning,
    PkmcalError,
    PkmcalWarning,
    ToleranceWarning,
    Plan,
    Prediction,
    SavedCalibration,
    Warning,
    __version__,
    analyze,
    budget,
    calibrate,
    compensate,
    drift,
    load_calibration,
    montecarlo,
    nominal_commands,
    plan,
    predict,
    set_threads,
    simulate,
    trilaterate,
)

import functools as _functools
import re as _re

_NOTE = _re.compile(r"while processing '(\w+)'")


def _naming_arguments(f):  # type: ignore[no-untyped-def]
    """`f` whose argument conversion errors (a TypeError or OverflowError the
    binding raises with the note "while processing 'axes'") say the
    argument's name in their message, not only in the traceback's note."""

    @_functools.wraps(f, assigned=(*_functools.WRAPPER_ASSIGNMENTS, "__text_signature__"))
    def call(*args, **kwargs):  # type: ignore[no-untyped-def]
        try:
            return f(*args, **kwargs)
        except (TypeError, OverflowError) as e:
            for note in getattr(e, "__notes__", ()):
                m = _NOTE.fullmatch(note)
                if m and not str(e).startswith(m.group(1)):
                    raise type(e)(f"{m.group(1)}: {e}").with_traceback(e.__traceback__) from None
            raise

    return call


analyze = _naming_arguments(analyze)
budget = _naming_arguments(budget)
calibrate = _naming_arguments(calibrate)
compensate = _naming_arguments(compensate)
drift = _naming_arguments(drift)
load_calibration = _naming_arguments(load_calibration)
montecarlo = _naming_arguments(montecarlo)
nominal_commands = _naming_arguments(nominal_commands)
plan = _naming_arguments(plan)
predict = _naming_arguments(predict)
set_threads = _naming_arguments(set_threads)
simulate = _naming_arguments(simulate)
trilaterate = _naming_arguments(trilaterate)

# `Warning` stays out of `__all__`: `from pkmcal import *` must not shadow
# Python's builtin `Warning` (it is `pkmcal.Warning`).
__all__ = [
    "Budget",
    "Calibration",
    "Compensation",
    "ConvergenceWarning",
    "Drift",
    "ErrorStats",
    "Figure",
    "Identifiability",
    "IdentifiabilityWarning",
    "Mechanism",
    "ModelWarning",
    "MonteCarlo",
    "OutlierWarning",
    "PkmcalError",
    "PkmcalWarning",
    "ToleranceWarning",
    "Plan",
    "Prediction",
    "SavedCalibration",
    "__version__",
    "analyze",
    "budget",
    "calibrate",
    "compensate",
    "drift",
    "load_calibration",
    "montecarlo",
    "nominal_commands",
    "plan",
    "predict",
    "set_threads",
    "simulate",
    "trilaterate",
]
