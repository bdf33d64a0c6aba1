"""pkmcal: kinematic calibration of (redundantly actuated) parallel mechanisms.

A mechanism (the built-in reference, or a TOML description), commands and
measured positions as NumPy arrays in, identified parameters with their
uncertainties, identifiability, before/after accuracy, figures and corrected
commands out. Arrays are in mm, rad, N and N·m; pose numbers in results and
exceptions are row indices (from 0) of the arrays given.

>>> import pkmcal
>>> mech = pkmcal.Mechanism()                      # the built-in reference
>>> targets = pkmcal.plan(mech, 35).targets         # where to measure
>>> commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002)
>>> cal = pkmcal.calibrate(mech, commands, measured)
>>> round(cal.parameters["l11"], 1)
280.3

Functions: predict, nominal_commands, simulate, calibrate, analyze,
compensate, plan, montecarlo, trilaterate. Classes: Mechanism, Calibration,
Identifiability, ErrorStats, Warning, Figure, Prediction, Compensation, Plan.
Errors: PkmcalError (a ValueError) with the message and ``.pose``. A
calibration's warnings are also emitted with ``warnings.warn``, once per call,
as PkmcalWarning (a UserWarning) subclasses: ConvergenceWarning,
IdentifiabilityWarning, OutlierWarning. Arrays with named columns (a pandas
DataFrame, a NumPy structured array) are read by name.
"""

from ._pkmcal import (
    Calibration,
    Compensation,
    ConvergenceWarning,
    ErrorStats,
    Figure,
    Identifiability,
    IdentifiabilityWarning,
    Mechanism,
    OutlierWarning,
    PkmcalError,
    PkmcalWarning,
    Plan,
    Prediction,
    SavedCalibration,
    Warning,
    __version__,
    analyze,
    calibrate,
    compensate,
    load_calibration,
    montecarlo,
    nominal_commands,
    plan,
    predict,
    set_threads,
    simulate,
    trilaterate,
)

# `Warning` stays out of `__all__`: `from pkmcal import *` must not shadow
# Python's builtin `Warning` (it is `pkmcal.Warning`).
__all__ = [
    "Calibration",
    "Compensation",
    "ConvergenceWarning",
    "ErrorStats",
    "Figure",
    "Identifiability",
    "IdentifiabilityWarning",
    "Mechanism",
    "OutlierWarning",
    "PkmcalError",
    "PkmcalWarning",
    "Plan",
    "Prediction",
    "SavedCalibration",
    "__version__",
    "analyze",
    "calibrate",
    "compensate",
    "load_calibration",
    "montecarlo",
    "nominal_commands",
    "plan",
    "predict",
    "set_threads",
    "simulate",
    "trilaterate",
]
