"""pkmcal: kinematic calibration of (redundantly actuated) parallel mechanisms.

A mechanism (the built-in reference, or a TOML description), commands and
measured positions as NumPy arrays or pandas DataFrames in, identified
parameters with their uncertainties, identifiability, before/after accuracy,
figures and corrected commands out. Arrays are in mm, rad, N and N·m; pose
numbers in results and exceptions are row indices (from 0) of the arrays
given.

>>> import pkmcal
>>> mech = pkmcal.Mechanism()                      # the built-in reference
>>> targets = pkmcal.plan(mech, 35).targets         # where to measure
>>> commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=1)
>>> cal = pkmcal.calibrate(mech, commands, measured, frame="base")  # simulated in the base frame
>>> round(cal.parameters["l11"], 1)
280.3

Functions: predict, nominal_commands, simulate, calibrate, analyze,
compensate, plan, montecarlo, budget, drift, trilaterate, load_calibration,
set_threads; for delta printers' firmware: klipper, reprap, marlin
(returning a FirmwareCalibration). Option groups: Instrument, Solver, Validation. Classes:
Mechanism, Calibration, Identifiability, ErrorStats, Warning, Figure,
Prediction, Compensation, Plan, MonteCarlo, Budget, Drift, SavedCalibration.
Every result pickles and compares by value; those with a table show it in a
notebook and give it as a pandas DataFrame (``to_pandas()``; pandas is
optional). Errors: PkmcalError (a ValueError) with the message and
``.pose``; a file that cannot be read or written raises a subclass that is
also Python's OSError (FileNotFoundError, PermissionError, …). A
calibration's warnings are also emitted with ``warnings.warn``, once per
call, as PkmcalWarning (a UserWarning) subclasses: ConvergenceWarning,
IdentifiabilityWarning, OutlierWarning, ToleranceWarning, ModelWarning;
AlignmentWarning when pandas rows given together were in different orders.
Arrays with named columns (a pandas DataFrame, a NumPy structured array) are
read by name, a pandas Series by label. Long calls stop on Ctrl-C.
"""

from ._pkmcal import (
    AlignmentWarning,
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
    PkmcalFileExistsError,
    PkmcalFileNotFoundError,
    PkmcalIsADirectoryError,
    PkmcalNotADirectoryError,
    PkmcalOSError,
    PkmcalPermissionError,
    PkmcalWarning,
    Plan,
    Prediction,
    SavedCalibration,
    ToleranceWarning,
    Warning,
    __version__,
)
from ._firmware import (
    Cube,
    Errors,
    FirmwareCalibration,
    FirmwareNote,
    FirmwareValue,
    G33Comparison,
    G33Run,
    HeightMap,
    NextMeasurement,
    NoiseNote,
    NozzleErrors,
    Physical,
    PrinterDrift,
    Unseen,
    klipper,
    marlin,
    reprap,
)
from ._api import (
    Instrument,
    Solver,
    Validation,
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

# `Warning` stays out of `__all__`: `from pkmcal import *` must not shadow
# Python's builtin `Warning` (it is `pkmcal.Warning`).
__all__ = [
    "AlignmentWarning",
    "Budget",
    "Calibration",
    "Compensation",
    "ConvergenceWarning",
    "Cube",
    "Drift",
    "ErrorStats",
    "Errors",
    "Figure",
    "FirmwareCalibration",
    "FirmwareNote",
    "FirmwareValue",
    "G33Comparison",
    "G33Run",
    "HeightMap",
    "Identifiability",
    "IdentifiabilityWarning",
    "Instrument",
    "Mechanism",
    "ModelWarning",
    "MonteCarlo",
    "NextMeasurement",
    "NoiseNote",
    "NozzleErrors",
    "OutlierWarning",
    "Physical",
    "PkmcalError",
    "PkmcalFileExistsError",
    "PkmcalFileNotFoundError",
    "PkmcalIsADirectoryError",
    "PkmcalNotADirectoryError",
    "PkmcalOSError",
    "PkmcalPermissionError",
    "PkmcalWarning",
    "Plan",
    "Prediction",
    "PrinterDrift",
    "SavedCalibration",
    "Solver",
    "ToleranceWarning",
    "Unseen",
    "Validation",
    "__version__",
    "analyze",
    "budget",
    "calibrate",
    "compensate",
    "drift",
    "klipper",
    "load_calibration",
    "marlin",
    "montecarlo",
    "nominal_commands",
    "plan",
    "predict",
    "reprap",
    "set_threads",
    "simulate",
    "trilaterate",
]
