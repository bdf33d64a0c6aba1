"""Type stubs of pkmcal (the extension module ``pkmcal._pkmcal``)."""

import os
from typing import Any, Dict, Literal, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

ArrayLike = npt.ArrayLike
Array = npt.NDArray[np.float64]
ModelName = Literal["exact", "linear", "rigid"]
Params = Union[None, Mapping[str, float], "Calibration", "SavedCalibration", str]
Names = Union[None, str, Sequence[str]]
MechanismLike = Union["Mechanism", str, os.PathLike, Mapping[str, Any]]
Seed = Union[None, int, np.random.Generator, np.random.RandomState]
Vector = Union[Sequence[float], ArrayLike]

class PkmcalError(ValueError):
    """Bad input or an impossible request; ``pose`` is the row (from 0) where it happened."""

    pose: Optional[int]

class PkmcalWarning(UserWarning):
    """A calibration warning, emitted once per call with ``warnings.warn``."""

class ConvergenceWarning(PkmcalWarning):
    """The fit stopped before converging."""

class IdentifiabilityWarning(PkmcalWarning):
    """Parameters the data cannot separate were fixed, or the fit is rank deficient."""

class OutlierWarning(PkmcalWarning):
    """Readings far beyond the noise were reported or dropped."""

class ModelWarning(PkmcalWarning):
    """The residuals do not match the instrument's stated noise: above it (the model misses something, or the noise is understated) or well below it (the noise is overstated)."""

class ToleranceWarning(PkmcalWarning):
    """An identified value far outside its tolerance, tolerances the data push against, or parameters the data taught little."""

class Mechanism:
    """A parallel mechanism: the built-in reference, or one described in TOML
    (a path, TOML text or a dict)."""

    def __init__(self, source: Union[None, str, os.PathLike, Mapping[str, Any]] = None) -> None: ...
    @staticmethod
    def reference() -> Mechanism: ...
    @staticmethod
    def from_file(path: Union[str, os.PathLike]) -> Mechanism: ...
    @staticmethod
    def from_toml(text: str) -> Mechanism: ...
    @staticmethod
    def from_dict(d: Mapping[str, Any]) -> Mechanism: ...
    @property
    def name(self) -> str: ...
    @property
    def kind(self) -> Literal["jeong-kim-2dof", "planar", "gough-stewart", "spatial"]: ...
    @property
    def dof(self) -> int: ...
    @property
    def joints(self) -> list[str]: ...
    @property
    def actuators(self) -> list[str]: ...
    @property
    def command_units(self) -> list[str]: ...
    @property
    def tool_axes(self) -> list[str]: ...
    @property
    def tool_units(self) -> list[str]: ...
    @property
    def summary(self) -> dict[str, Any]: ...
    @property
    def parameter_names(self) -> list[str]: ...
    @property
    def parameters(self) -> list[str]:
        """Deprecated: ``parameter_names``."""
    @property
    def nominal(self) -> dict[str, float]: ...
    @property
    def parameter_units(self) -> dict[str, str]: ...
    @property
    def parameter_kinds(self) -> dict[str, str]: ...
    @property
    def default_free(self) -> list[str]: ...
    @property
    def workspace(self) -> Array: ...
    @property
    def target_points(self) -> Optional[Array]: ...
    @property
    def targets(self) -> Optional[Array]:
        """Deprecated: ``target_points``."""

class ErrorStats:
    """Error statistics of a set of poses (mm; angles in rad)."""

    count: int
    axis_units: list[str]
    axis_min: list[float]
    axis_max: list[float]
    axis_rms: list[float]
    distance_min: float
    distance_mean: float
    distance_rms: float
    distance_max: float
    angle_rms: Optional[float]
    angle_max: Optional[float]

class Warning:
    """A calibration warning: kind, message, hint (compares and hashes by value)."""

    kind: str
    message: str
    hint: str

class Identifiability:
    """Rank, singular values and unidentifiable combinations."""

    @property
    def free(self) -> list[str]: ...
    @property
    def rank(self) -> int: ...
    @property
    def singular_values(self) -> Array: ...
    @property
    def condition_number(self) -> float: ...
    @property
    def observability(self) -> dict[str, float]: ...
    @property
    def unidentifiable(self) -> list[dict[str, Any]]: ...
    @property
    def held(self) -> list[str]: ...
    @property
    def correlations(self) -> list[Tuple[str, str, float]]: ...

class Figure:
    """A rendered figure (SVG and PNG); shown inline in a notebook."""

    name: str
    title: str
    caption: str
    svg: str
    png: bytes
    def _repr_svg_(self) -> str: ...
    def save(self, path: Union[str, os.PathLike]) -> None: ...

class Calibration:
    """Result of :func:`calibrate`."""

    @property
    def parameters(self) -> dict[str, float]: ...
    @property
    def measurement_parameters(self) -> dict[str, float]: ...
    @property
    def free(self) -> list[str]: ...
    @property
    def std_dev(self) -> dict[str, float]: ...
    @property
    def change(self) -> dict[str, float]: ...
    @property
    def nominal(self) -> dict[str, float]: ...
    @property
    def units(self) -> dict[str, str]: ...
    @property
    def notes(self) -> dict[str, str]: ...
    @property
    def covariance(self) -> Array: ...
    @property
    def covariance_names(self) -> list[str]: ...
    @property
    def identifiability(self) -> Identifiability: ...
    @property
    def before(self) -> ErrorStats: ...
    @property
    def after(self) -> ErrorStats: ...
    @property
    def distances(self) -> Optional[Dict[str, Any]]: ...
    @property
    def improvement(self) -> Tuple[float, float]: ...
    @property
    def validation(self) -> Optional[Tuple[ErrorStats, ErrorStats]]: ...
    @property
    def cross_validation(self) -> Optional[dict[str, Any]]: ...
    @property
    def warnings(self) -> list[Warning]: ...
    @property
    def converged(self) -> bool: ...
    @property
    def termination(self) -> str: ...
    @property
    def iterations(self) -> int: ...
    @property
    def model(self) -> str: ...
    @property
    def sum_of_squares(self) -> float: ...
    @property
    def unit_weight_sigma(self) -> float: ...
    @property
    def axes(self) -> list[str]: ...
    @property
    def axis_units(self) -> list[str]: ...
    @property
    def residuals(self) -> Array: ...
    @property
    def poses(self) -> list[int]: ...
    @property
    def outliers(self) -> list[dict[str, Any]]: ...
    @property
    def dropped(self) -> list[int]: ...
    def to_toml(self) -> str: ...
    def save(self, path: Union[str, os.PathLike]) -> None: ...
    @staticmethod
    def load(path: Union[str, os.PathLike]) -> Calibration: ...
    @property
    def mechanism(self) -> Mechanism: ...
    @property
    def x(self) -> Array: ...
    @property
    def x_names(self) -> list[str]: ...
    @property
    def x_units(self) -> list[str]: ...
    @property
    def fun(self) -> Array: ...
    @property
    def jac(self) -> Array: ...
    @property
    def sigmas(self) -> Array: ...
    @property
    def priors(self) -> list[dict[str, Any]]: ...
    @property
    def from_data(self) -> dict[str, float]: ...
    @property
    def cost(self) -> float: ...
    @property
    def nfev(self) -> int: ...
    @property
    def njev(self) -> int: ...
    @property
    def status(self) -> int: ...
    @property
    def message(self) -> str: ...
    @property
    def success(self) -> bool: ...
    @property
    def correlation(self) -> Array: ...
    def summary(self) -> str: ...
    def _repr_html_(self) -> str: ...
    def figures(self) -> list[Figure]: ...
    def save_report(self, path: Union[str, os.PathLike]) -> None: ...

class Budget:
    """A tolerance budget: see :func:`budget`."""

    @property
    def first_order(self) -> dict[str, Any]: ...
    @property
    def monte_carlo(self) -> Optional[dict[str, Any]]: ...
    @property
    def after_calibration(self) -> Optional[dict[str, Any]]: ...
    @property
    def shares(self) -> dict[str, float]: ...
    @property
    def tolerances(self) -> dict[str, float]: ...
    @property
    def sigma_after(self) -> Optional[dict[str, float]]: ...
    @property
    def axes(self) -> list[str]: ...
    @property
    def targets(self) -> int: ...
    @property
    def samples(self) -> int: ...
    def summary(self) -> str: ...

class Drift:
    """A drift test: see :func:`drift`."""

    @property
    def drifted(self) -> list[str]: ...
    @property
    def parameters(self) -> list[dict[str, Any]]: ...
    @property
    def alpha(self) -> float: ...
    @property
    def chi2(self) -> Tuple[float, int, float]: ...
    @property
    def joint_drift(self) -> bool: ...
    @property
    def untested(self) -> list[str]: ...
    @property
    def workspace(self) -> Optional[dict[str, Any]]: ...
    def summary(self) -> str: ...

class MonteCarlo:
    runs: int
    converged: int
    validation_rms_median: float
    validation_rms_p95: float
    validation_max_median: float
    parameters: list[str]
    parameter_rms_error: Array
    run_converged: npt.NDArray[np.bool_]
    validation_rms: Array
    validation_max: Array
    parameter_errors: Array
    def __getitem__(self, key: str) -> Any:
        """Deprecated: the attributes."""

class Prediction:
    x: Array
    q: Array
    torque: Array
    deflection: Array
    covariance: Optional[Array]
    skipped: list[int]

class Compensation:
    commands: Array
    nominal: Array
    correction: Array
    torque: Array
    q: Array
    skipped: list[int]

class Plan:
    targets: Array
    commands: Array
    observability: dict[str, float]
    condition: float
    grid_targets: Array
    grid_observability: dict[str, float]
    grid_condition: float
    spacing: float
    candidates: int
    rank: int
    free: int

class SavedCalibration:
    """A calibration read back by :func:`load_calibration`; pass it as ``params``."""

    @property
    def mechanism(self) -> str: ...
    @property
    def mechanism_identity(self) -> str: ...
    @property
    def version(self) -> int: ...
    @property
    def model(self) -> ModelName: ...
    @property
    def parameters(self) -> dict[str, float]: ...
    @property
    def covariance(self) -> Array: ...
    @property
    def covariance_names(self) -> list[str]: ...

def load_calibration(path: Union[str, os.PathLike]) -> SavedCalibration: ...
def set_threads(n: int) -> None: ...
def predict(
    mechanism: MechanismLike,
    commands: ArrayLike,
    params: Params = None,
    *,
    model: Optional[ModelName] = None,
    load: Optional[Vector] = None,
    force: Optional[Vector] = None,
    uncertainty: bool = False,
    skip_unreachable: bool = False,
) -> Prediction: ...
def nominal_commands(mechanism: MechanismLike, targets: ArrayLike) -> Array: ...
def simulate(
    mechanism: MechanismLike,
    targets: ArrayLike,
    truth: Params = None,
    *,
    noise: float = 0.0,
    angle_noise: Optional[float] = None,
    seed: Seed = None,
    axes: Optional[Sequence[str]] = None,
    points: Union[None, ArrayLike, Literal["mechanism"]] = None,
    ballbar: Union[None, Mapping[str, Any], Literal["mechanism"]] = None,
) -> Tuple[Array, Array]: ...
def calibrate(
    mechanism: MechanismLike,
    commands: ArrayLike,
    measured: ArrayLike,
    *,
    sigma: Union[None, float, ArrayLike] = None,
    targets: Optional[ArrayLike] = None,
    model: ModelName = "exact",
    free: Names = None,
    fix: Names = None,
    start: Params = None,
    loss: Literal["squared", "huber", "cauchy"] = "squared",
    loss_scale: Optional[float] = None,
    outlier_threshold: float = 4.0,
    drop_outliers: bool = False,
    load: Optional[Vector] = None,
    force: Optional[Vector] = None,
    axes: Optional[Sequence[str]] = None,
    points: Union[None, ArrayLike, Literal["mechanism"]] = None,
    ballbar: Union[None, Mapping[str, Any], Literal["mechanism"]] = None,
    frame: Literal["auto", "base", "free"] = "auto",
    validation: Optional[Tuple[ArrayLike, ...]] = None,
    holdout: Optional[float] = None,
    kfold: Optional[int] = None,
    seed: Seed = 1,
    distances: Optional[Tuple[ArrayLike, ...]] = None,
    max_nfev: Optional[int] = None,
    ftol: Optional[float] = None,
    xtol: Optional[float] = None,
    gtol: Optional[float] = None,
    bounds: Optional[Mapping[str, Tuple[float, float]]] = None,
    x0: Union[None, Mapping[str, float], ArrayLike] = None,
    tolerances: Union[None, bool, Mapping[str, Union[float, str]]] = None,
    stated_noise: Optional[float] = None,
    stated_angle_noise: Optional[float] = None,
    stated_readings: float = 10.0,
    stated_distance_noise: Optional[float] = None,
    stated_relative: bool = False,
) -> Calibration: ...
def analyze(
    mechanism: MechanismLike,
    commands: ArrayLike,
    measured: ArrayLike,
    *,
    params: Params = None,
    sigma: Union[None, float, ArrayLike] = None,
    model: ModelName = "exact",
    free: Names = None,
    fix: Names = None,
    load: Optional[Vector] = None,
    force: Optional[Vector] = None,
    axes: Optional[Sequence[str]] = None,
    points: Union[None, ArrayLike, Literal["mechanism"]] = None,
    ballbar: Union[None, Mapping[str, Any], Literal["mechanism"]] = None,
    frame: Literal["auto", "base", "free"] = "auto",
    tolerances: Union[None, bool, Mapping[str, Union[float, str]]] = None,
    noise: float = 0.002,
    angle_noise: Optional[float] = None,
) -> Identifiability: ...
def compensate(
    mechanism: MechanismLike,
    targets: ArrayLike,
    params: Params = None,
    *,
    model: Literal["exact", "rigid"] = "exact",
    load: Optional[Vector] = None,
    force: Optional[Vector] = None,
    preload: Optional[Vector] = None,
    skip_unreachable: bool = False,
) -> Compensation: ...
def plan(
    mechanism: MechanismLike,
    count: int,
    params: Params = None,
    *,
    criterion: Literal["O1", "O3", "O5"] = "O5",
    model: ModelName = "exact",
    free: Names = None,
    fix: Names = None,
    spacing: float = 6.0,
    max_candidates: int = 4000,
    tolerances: Union[None, bool, Mapping[str, Union[float, str]]] = None,
    noise: float = 0.002,
    angle_noise: Optional[float] = None,
) -> Plan: ...
def montecarlo(
    mechanism: MechanismLike,
    targets: ArrayLike,
    *,
    runs: int = 200,
    noise: float = 0.002,
    angle_noise: Optional[float] = None,
    seed: Seed = 1,
    model: ModelName = "exact",
    free: Names = None,
    fix: Names = None,
    length_error: float = 0.3,
    angle_error: float = 0.001,
    validation: int = 50,
    tolerances: Union[None, bool, Mapping[str, Union[float, str]]] = None,
) -> MonteCarlo: ...
def budget(
    mechanism: MechanismLike,
    tolerances: Optional[Mapping[str, Union[float, str]]] = None,
    *,
    grid: int = 200,
    samples: int = 3000,
    seed: Seed = 1,
    model: ModelName = "exact",
    poses: Optional[ArrayLike] = None,
    noise: float = 0.002,
    angle_noise: Optional[float] = None,
) -> Budget: ...
def drift(
    new: Union[Calibration, SavedCalibration, str, os.PathLike],
    old: Union[None, Calibration, SavedCalibration, str, os.PathLike] = None,
    *,
    mechanism: Optional[MechanismLike] = None,
    alpha: float = 0.05,
    grid: int = 100,
) -> Drift: ...
def trilaterate(
    sockets: ArrayLike,
    readings: ArrayLike,
    *,
    bar_offset: float = 0.0,
    sigma: float = 0.002,
) -> Tuple[Array, Array]: ...
