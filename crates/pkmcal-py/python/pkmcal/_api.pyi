"""Type stubs of the package's functions and option groups (``pkmcal/_api.py``)."""

import dataclasses
from typing import Any, Literal, Mapping, Optional, Sequence, Tuple, Union

from ._pkmcal import (
    Budget,
    Calibration,
    Compensation,
    Drift,
    Identifiability,
    MonteCarlo,
    Plan,
    Prediction,
    SavedCalibration,
    _Array,
    _ArrayLike,
    _Ballbar,
    _Frame,
    _Int,
    _MechanismLike,
    _ModelName,
    _Names,
    _Params,
    _Path,
    _Points,
    _Seed,
    _Tolerances,
    _Vector,
)

@dataclasses.dataclass(frozen=True)
class Solver:
    loss: str = "squared"
    loss_scale: Optional[float] = None
    max_nfev: Optional[_Int] = None
    ftol: Optional[float] = None
    xtol: Optional[float] = None
    gtol: Optional[float] = None
    bounds: Optional[Mapping[str, Tuple[float, float]]] = None

@dataclasses.dataclass(frozen=True)
class Instrument:
    axes: _Names = None
    points: _Points = None
    ballbar: _Ballbar = None
    frame: str = "auto"
    stated_noise: Optional[float] = None
    stated_angle_noise: Optional[float] = None
    stated_readings: float = 10.0
    stated_distance_noise: Optional[float] = None
    stated_relative: bool = False

@dataclasses.dataclass(frozen=True)
class Validation:
    data: Optional[Tuple[Any, ...]] = None
    holdout: Optional[float] = None
    kfold: Optional[_Int] = None
    seed: _Seed = 1

def load_calibration(path: _Path) -> SavedCalibration: ...
def set_threads(n: _Int) -> None: ...
def predict(
    mechanism: _MechanismLike,
    commands: _ArrayLike,
    params: _Params = None,
    *,
    model: Optional[_ModelName] = None,
    load: Optional[_Vector] = None,
    force: Optional[_Vector] = None,
    uncertainty: bool = False,
    skip_unreachable: bool = False,
    outputs: _Names = "all",
) -> Prediction: ...
def nominal_commands(mechanism: _MechanismLike, targets: _ArrayLike) -> _Array: ...
def simulate(
    mechanism: _MechanismLike,
    targets: _ArrayLike,
    truth: _Params = None,
    *,
    noise: float = 0.0,
    angle_noise: Optional[float] = None,
    seed: _Seed = None,
    axes: _Names = None,
    points: _Points = None,
    ballbar: _Ballbar = None,
) -> Tuple[_Array, _Array]: ...
def calibrate(
    mechanism: _MechanismLike,
    commands: _ArrayLike,
    measured: _ArrayLike,
    *,
    sigma: Union[None, float, _ArrayLike] = None,
    targets: Optional[_ArrayLike] = None,
    model: _ModelName = "exact",
    free: _Names = None,
    fix: _Names = None,
    start: _Params = None,
    loss: Literal["squared", "huber", "cauchy"] = "squared",
    loss_scale: Optional[float] = None,
    outlier_threshold: float = 4.0,
    drop_outliers: bool = False,
    load: Optional[_Vector] = None,
    force: Optional[_Vector] = None,
    axes: _Names = None,
    points: _Points = None,
    ballbar: _Ballbar = None,
    frame: _Frame = "auto",
    validation: Union[None, Validation, Sequence[Any]] = None,
    holdout: Optional[float] = None,
    kfold: Optional[_Int] = None,
    seed: _Seed = 1,
    distances: Optional[Tuple[Any, ...]] = None,
    max_nfev: Optional[_Int] = None,
    ftol: Optional[float] = None,
    xtol: Optional[float] = None,
    gtol: Optional[float] = None,
    bounds: Optional[Mapping[str, Tuple[float, float]]] = None,
    x0: Union[None, Mapping[str, float], _ArrayLike] = None,
    tolerances: _Tolerances = None,
    stated_noise: Optional[float] = None,
    stated_angle_noise: Optional[float] = None,
    stated_readings: float = 10.0,
    stated_distance_noise: Optional[float] = None,
    stated_relative: bool = False,
    instrument: Optional[Instrument] = None,
    solver: Optional[Solver] = None,
) -> Calibration: ...
def analyze(
    mechanism: _MechanismLike,
    commands: _ArrayLike,
    measured: _ArrayLike,
    *,
    params: _Params = None,
    sigma: Union[None, float, _ArrayLike] = None,
    model: _ModelName = "exact",
    free: _Names = None,
    fix: _Names = None,
    load: Optional[_Vector] = None,
    force: Optional[_Vector] = None,
    axes: _Names = None,
    points: _Points = None,
    ballbar: _Ballbar = None,
    frame: _Frame = "auto",
    tolerances: _Tolerances = None,
    stated_noise: float = 0.002,
    stated_angle_noise: Optional[float] = None,
    noise: Optional[float] = None,
    angle_noise: Optional[float] = None,
    instrument: Optional[Instrument] = None,
) -> Identifiability: ...
def compensate(
    mechanism: _MechanismLike,
    targets: _ArrayLike,
    params: _Params = None,
    *,
    model: Literal["exact", "rigid"] = "exact",
    load: Optional[_Vector] = None,
    force: Optional[_Vector] = None,
    preload: Optional[_Vector] = None,
    skip_unreachable: bool = False,
) -> Compensation: ...
def plan(
    mechanism: _MechanismLike,
    count: _Int,
    params: _Params = None,
    *,
    criterion: Literal["O1", "O3", "O5"] = "O5",
    model: _ModelName = "exact",
    free: _Names = None,
    fix: _Names = None,
    spacing: float = 6.0,
    max_candidates: _Int = 4000,
    tolerances: _Tolerances = None,
    stated_noise: float = 0.002,
    stated_angle_noise: Optional[float] = None,
    noise: Optional[float] = None,
    angle_noise: Optional[float] = None,
) -> Plan: ...
def montecarlo(
    mechanism: _MechanismLike,
    targets: _ArrayLike,
    *,
    runs: _Int = 200,
    noise: float = 0.002,
    angle_noise: Optional[float] = None,
    seed: _Seed = 1,
    model: _ModelName = "exact",
    free: _Names = None,
    fix: _Names = None,
    length_error: float = 0.3,
    angle_error: float = 0.001,
    validation: _Int = 50,
    tolerances: _Tolerances = None,
) -> MonteCarlo: ...
def budget(
    mechanism: _MechanismLike,
    tolerances: Optional[Mapping[str, Union[float, str]]] = None,
    *,
    grid: _Int = 200,
    samples: _Int = 3000,
    seed: _Seed = 1,
    model: _ModelName = "exact",
    poses: Optional[_ArrayLike] = None,
    stated_noise: float = 0.002,
    stated_angle_noise: Optional[float] = None,
    noise: Optional[float] = None,
    angle_noise: Optional[float] = None,
) -> Budget: ...
def drift(
    new: Union[Calibration, SavedCalibration, _Path],
    old: Union[None, Calibration, SavedCalibration, _Path] = None,
    *,
    mechanism: Optional[_MechanismLike] = None,
    alpha: float = 0.05,
    grid: _Int = 100,
) -> Drift: ...
def trilaterate(
    sockets: _ArrayLike,
    readings: _ArrayLike,
    *,
    bar_offset: float = 0.0,
    sigma: float = 0.002,
) -> Tuple[_Array, _Array]: ...
