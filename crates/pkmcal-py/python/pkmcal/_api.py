"""The package's functions and option groups: their signatures, defaults and
documentation. Each function hands the extension (``pkmcal._pkmcal``) its
arguments as one dict; the extension reads each by name and type, and the
library checks every rule (a refusal names the keyword)."""

import dataclasses as _dataclasses
from typing import Any, Mapping, Optional, Tuple

from . import _pkmcal as _ext

_D = _ext.DEFAULTS


@_dataclasses.dataclass(frozen=True)
class Solver:
    """The least-squares solver's settings, as scipy's ``least_squares``
    names them: ``loss`` (``"squared"``, ``"huber"`` or ``"cauchy"``) and
    ``loss_scale`` (its tuning constant in robust standard deviations,
    scipy's ``f_scale``; default 1.345 for huber, 2.385 for cauchy),
    ``max_nfev`` (the evaluation budget, default 200), ``ftol``, ``xtol``
    (default 1e-12), ``gtol`` (default 0) and ``bounds`` (a dict name →
    ``(lower, upper)``, ±inf for an open side). ``calibrate(...,
    solver=Solver(...))`` is the same as giving each as a keyword."""

    loss: str = "squared"
    loss_scale: Optional[float] = None
    max_nfev: Optional[int] = None
    ftol: Optional[float] = None
    xtol: Optional[float] = None
    gtol: Optional[float] = None
    bounds: Optional[Mapping[str, Tuple[float, float]]] = None


@_dataclasses.dataclass(frozen=True)
class Instrument:
    """What reads the tool, and what its maker states: the whole tool
    (default), some tool ``axes`` (``["probe"]``: heights probed on a bed
    plane), target ``points`` on the tool, or a ``ballbar``; its ``frame``
    (``"auto"``, ``"base"`` or ``"free"``); its stated noise
    (``stated_noise`` mm, ``stated_angle_noise`` rad, worth
    ``stated_readings`` readings; ``stated_distance_noise`` for distances
    between poses; ``stated_relative=True`` when only their ratios are
    known). ``calibrate(..., instrument=Instrument(...))`` is the same as
    giving each as a keyword; ``analyze`` takes it too."""

    axes: Any = None
    points: Any = None
    ballbar: Any = None
    frame: str = "auto"
    stated_noise: Optional[float] = None
    stated_angle_noise: Optional[float] = None
    stated_readings: float = _D["stated_readings"]
    stated_distance_noise: Optional[float] = None
    stated_relative: bool = False


@_dataclasses.dataclass(frozen=True)
class Validation:
    """How a calibration is judged on poses it did not fit: ``data``
    measured apart (``(commands, measured)`` or ``(commands, measured,
    sigma)``) or a ``holdout`` fraction of the poses, and/or ``kfold``
    cross-validation, the poses drawn with ``seed``.
    ``calibrate(..., validation=Validation(...))`` is the same as giving
    ``validation=data``, ``holdout``, ``kfold`` and ``seed``."""

    data: Optional[Tuple[Any, ...]] = None
    holdout: Optional[float] = None
    kfold: Optional[int] = None
    seed: Any = _D["seed"]


# Each group's keywords as the functions name them.
_GROUPS = {
    "instrument": (Instrument, {}),
    "solver": (Solver, {}),
    "validation": (Validation, {"data": "validation"}),
}


def _is_default(value: Any, default: Any) -> bool:
    """Whether `value` is `default` (scalars by value; arrays never are)."""
    if value is default:
        return True
    scalar = (bool, int, float, str, type(None))
    return isinstance(value, scalar) and isinstance(default, scalar) and value == default


def _flatten(function: Any, args: dict) -> dict:
    """`args` with each option group given (``instrument=``, ``solver=``,
    ``validation=Validation(...)``) spread into its keywords; a keyword
    given both ways is refused."""
    defaults = function.__kwdefaults__ or {}
    for group, (cls, renamed) in _GROUPS.items():
        if group not in args:
            continue
        value = args[group] if group == "validation" else args.pop(group)
        if value is None or (group == "validation" and not isinstance(value, Validation)):
            continue
        if not isinstance(value, cls):
            raise TypeError(f"{group}: expected a pkmcal.{cls.__name__}, got {type(value).__name__}")
        if group == "validation":
            args["validation"] = None
        for field in _dataclasses.fields(cls):
            name = renamed.get(field.name, field.name)
            given = getattr(value, field.name)
            if _is_default(given, field.default):
                continue
            if name not in args:
                raise TypeError(f"{group}: {function.__name__}() takes no {field.name}")
            if not _is_default(args[name], defaults.get(name)):
                raise TypeError(f"give {name} once: in {group}= or as {name}=, not both")
            args[name] = given
    return args


def _renamed(args: dict, old: str, new: str, default: Any) -> dict:
    """`args` with the keyword `old` (a DeprecationWarning) read as `new`."""
    value = args.pop(old)
    if value is None:
        return args
    if not _is_default(args[new], default):
        raise TypeError(f"give {new} once ({old}= is its old name here)")
    import warnings

    warnings.warn(
        f"{old}= is deprecated and will be removed in the next release; use {new}=",
        DeprecationWarning,
        stacklevel=3,
    )
    args[new] = value
    return args


def _stated(args: dict) -> dict:
    """``noise=`` and ``angle_noise=``, the old names of the instrument's
    stated noise where readings are weighed against tolerances."""
    _renamed(args, "noise", "stated_noise", _D["stated_noise"])
    return _renamed(args, "angle_noise", "stated_angle_noise", None)


def predict(
    mechanism,
    commands,
    params=None,
    *,
    model=None,
    load=None,
    force=None,
    uncertainty=False,
    skip_unreachable=False,
    outputs="all",
):
    """Predict the tool position reached at each row of ``commands``.

    ``commands``: (n, actuators), or one row; a pandas DataFrame is read by
    column name and a Series (a row of one) by label. ``params``: None
    (nominal), a dict name → value (others nominal), a :class:`Calibration`
    (or its ``to_pandas()`` table), a :class:`SavedCalibration` or a
    parameter file path. ``model``: ``"exact"``, ``"linear"`` or
    ``"rigid"``; by default the calibration's model when ``params`` is one,
    else ``"exact"``. ``load``: a constant wrench on the tool (N along
    lengths, N·m about angles; ``force=`` is its old name).
    ``uncertainty=True`` (with a calibration) adds the covariance of each
    position. ``outputs``: ``"all"`` (x, q, torque, deflection), ``"x"``
    (only the tool pose: the memory of the output alone) or a sequence of
    those names. A row whose commands do not assemble the mechanism on its
    branch raises, naming the row; with ``skip_unreachable=True`` its
    outputs are NaN and it is listed in ``skipped`` (as is a row with a
    NaN). ``Prediction.to_pandas()`` keeps the commands' index.
    """
    return _ext.predict(locals())


def nominal_commands(mechanism, targets):
    """Nominal commands (inverse kinematics with nominal parameters) of tool
    positions ``targets`` (n, tool axes), shape (n, actuators)."""
    return _ext.nominal_commands(locals())


def simulate(
    mechanism,
    targets,
    truth=None,
    *,
    noise=0.0,
    angle_noise=None,
    seed=None,
    axes=None,
    points=None,
    ballbar=None,
):
    """Simulate measurements at tool positions ``targets`` for a mechanism
    whose true parameters are ``truth`` (None: nominal; a dict; a
    Calibration).

    Returns ``(commands, measured)``: the nominal commands of each target
    and what the instrument reads when they are sent, with Gaussian noise
    (``noise`` mm on lengths, ``angle_noise`` rad on angles; default the
    length noise over a 200 mm lever arm), seeded by ``seed`` (None: fresh
    numbers each call). The instrument is the whole tool unless ``axes``,
    ``points`` or ``ballbar`` say otherwise (as in :func:`calibrate`); its
    readings are in the base frame.
    """
    return _ext.simulate(locals())


def calibrate(
    mechanism,
    commands,
    measured,
    *,
    sigma=None,
    targets=None,
    model="exact",
    free=None,
    fix=None,
    start=None,
    loss="squared",
    loss_scale=None,
    outlier_threshold=_D["outlier_threshold"],
    drop_outliers=False,
    load=None,
    force=None,
    axes=None,
    points=None,
    ballbar=None,
    frame="auto",
    validation=None,
    holdout=None,
    kfold=None,
    seed=_D["seed"],
    distances=None,
    max_nfev=None,
    ftol=None,
    xtol=None,
    gtol=None,
    bounds=None,
    x0=None,
    tolerances=None,
    stated_noise=None,
    stated_angle_noise=None,
    stated_readings=_D["stated_readings"],
    stated_distance_noise=None,
    stated_relative=False,
    instrument=None,
    solver=None,
):
    """Identify parameter errors and encoder offsets from measurements (the
    method of docs/model.md, eq. 12).

    Data: ``commands`` (n, actuators) and ``measured`` (n, readings): the
    tool coordinates (``mechanism.tool_axes``), or with ``axes=[...]`` only
    those (``axes=["probe"]``: heights probed on a bed plane whose height
    and tilts are the parameters ``bed.z``, ``bed.rx``, ``bed.ry``, fixed
    unless freed), with ``points=`` target points on the tool (``t1x, t1y,
    …``), with ``ballbar=`` bar lengths (``d1, d2, …``). pandas DataFrames
    are read by column name and must have the same index (rows in another
    order are aligned, with an ``AlignmentWarning``). ``sigma``: the
    standard deviation of the readings (a number when they share a unit,
    one per reading, or (n, readings) with NaN where it is to be estimated).
    ``targets``: (n, tool axes), the poses the commands were meant to reach
    (for the "before" statistics; optional). ``distances=(commands_1,
    commands_2, distance[, sigma])``: distances measured between pairs of
    poses (calipers on a printed object, mm), fitted with the readings
    (their noise estimated apart); their errors are in
    ``Calibration.distances``.

    The instrument (or ``instrument=Instrument(...)``): ``axes``, ``points``,
    ``ballbar`` (a dict ``{"sockets": (k, 2 or 3) mm, "bar_offset": mm}`` or
    ``"mechanism"`` for the description's ``[ballbar]``); ``frame``:
    ``"auto"`` (the default, as on the command line: an instrument frame
    identified with the rest for whole positions and target points, as a
    laser tracker reads them; the base frame for readings that fix no
    frame), ``"base"`` (readings in the base frame) or ``"free"``;
    ``stated_noise`` (mm) and ``stated_angle_noise`` (rad): the instrument's
    stated noise, a prior of the noise estimates worth ``stated_readings``
    readings, and what the model-adequacy test holds the residuals against
    (a ``ModelWarning`` names the parameters whose freeing would explain
    them); ``stated_distance_noise`` (mm): the same for ``distances``
    (another instrument); ``stated_relative=True``: only the stated noises'
    ratios are known, their scale is estimated and not tested.

    The model: ``model`` (``"exact"``, ``"linear"``, ``"rigid"``);
    ``free``/``fix``: parameter names, a string (comma-separated) or a
    sequence (``"all"``, ``"default"``); ``start``: starting parameters (as
    ``predict``'s ``params``); ``load``: the wrench on the tool during the
    measurements (N, N·m; ``force=`` is its old name; ``cal.load`` gives it
    back). ``tolerances``: priors (docs/model.md eq. 13), a dict name → σ or
    ``"20%"`` beside the mechanism's ``[tolerances]`` table (replacing its
    entries of the same names); ``False`` fits without priors. A parameter
    with a tolerance is identified (unless ``fix`` names it) and held by it
    where the data are weak: the fit is then the maximum a posteriori
    estimate; ``Calibration.priors`` lists the priors used,
    ``Calibration.from_data`` each prior parameter's share of information
    from the data, and ``Calibration.to_pandas()`` both with every value.

    The solver (or ``solver=Solver(...)``), as scipy's ``least_squares``
    names its settings: ``loss`` (``"squared"``, ``"huber"``, ``"cauchy"``)
    with ``loss_scale`` (robust standard deviations; default 1.345 for
    huber, 2.385 for cauchy), ``max_nfev`` (evaluation budget, default 200),
    ``ftol``, ``xtol`` (default 1e-12), ``gtol`` (default 0), ``bounds`` (a
    dict name → ``(lower, upper)``, ±inf for an open side; mechanism or
    instrument parameters) and ``x0`` (the start: a dict name → value like
    ``start``, or an array with one value per free mechanism parameter in
    the order :func:`analyze`'s ``free`` lists them).
    ``outlier_threshold`` (robust standard deviations) flags outliers and
    ``drop_outliers=True`` refits without them.

    Validation (or ``validation=Validation(...)``):
    ``validation=(commands, measured)`` (or with ``sigma``), or
    ``holdout=0.2`` (a fraction held out, drawn with ``seed``), and/or
    ``kfold=5`` (folds drawn with ``seed``).

    Returns a :class:`Calibration`; its warnings are also emitted with
    ``warnings.warn``. Ctrl-C stops it (``KeyboardInterrupt``).
    """
    return _ext.calibrate(_flatten(calibrate, locals()))


def analyze(
    mechanism,
    commands,
    measured,
    *,
    params=None,
    sigma=None,
    model="exact",
    free=None,
    fix=None,
    load=None,
    force=None,
    axes=None,
    points=None,
    ballbar=None,
    frame="auto",
    tolerances=None,
    stated_noise=_D["stated_noise"],
    stated_angle_noise=None,
    noise=None,
    angle_noise=None,
    instrument=None,
):
    """Identifiability of the free parameters from poses and readings at
    ``params`` (nominal by default), without fitting: rank, singular values
    and the combinations the data cannot see. Arguments as
    :func:`calibrate` (``instrument=Instrument(...)`` too). With tolerances
    (the mechanism's table, or ``tolerances``) their information counts,
    readings without a given σ weighed with the instrument's stated noise
    (``stated_noise`` mm and ``stated_angle_noise`` rad;
    ``noise=`` and ``angle_noise=`` are their old names here), and
    ``Identifiability.held`` lists what they hold.
    """
    return _ext.analyze(_stated(_flatten(analyze, locals())))


def compensate(
    mechanism,
    targets,
    params=None,
    *,
    model="exact",
    load=None,
    force=None,
    preload=None,
    skip_unreachable=False,
):
    """Commands that bring the tool to each row of ``targets`` under
    ``params`` (a Calibration, a dict or None), deflections included
    (``model="exact"``) or not (``"rigid"``); ``load``: a wrench on the
    tool; ``preload``: actuator loads whose internal part is held. An
    unreachable or singular target raises, naming its row; with
    ``skip_unreachable=True`` its row is NaN and listed in ``skipped`` (as
    is a target with a NaN). ``Compensation.to_pandas()`` keeps the
    targets' index.
    """
    return _ext.compensate(locals())


def plan(
    mechanism,
    count,
    params=None,
    *,
    criterion="O5",
    model="exact",
    free=None,
    fix=None,
    spacing=6.0,
    max_candidates=4000,
    tolerances=None,
    stated_noise=_D["stated_noise"],
    stated_angle_noise=None,
    noise=None,
    angle_noise=None,
):
    """Choose ``count`` poses that make the free parameters most observable
    (greedy selection then exchanges, over a lattice of the usable
    workspace). ``criterion``: ``"O1"`` (D-optimal), ``"O3"`` or ``"O5"``
    (default); ``spacing``: lattice spacing in mm; ``max_candidates``: most
    lattice points scored. ``tolerances`` (as :func:`calibrate` takes them;
    the mechanism's table by default, ``False`` for none): the plan is
    optimal given what they already tell, its poses measured with the
    instrument's stated noise (``stated_noise`` mm and ``stated_angle_noise``
    rad; ``noise=`` and ``angle_noise=`` are their
    old names here). Ctrl-C stops it.
    """
    return _ext.plan(_stated(locals()))


def montecarlo(
    mechanism,
    targets,
    *,
    runs=200,
    noise=0.002,
    angle_noise=None,
    seed=_D["seed"],
    model="exact",
    free=None,
    fix=None,
    length_error=0.3,
    angle_error=0.001,
    validation=50,
    tolerances=None,
):
    """Monte Carlo study of a measurement plan: ``runs`` simulated
    calibrations from the poses ``targets``, each with random parameter
    errors (``length_error`` mm, ``angle_error`` rad on the free
    parameters) and simulated measurement noise (``noise`` mm,
    ``angle_noise`` rad), judged on ``validation`` random unseen poses.
    ``tolerances`` (as :func:`calibrate` takes them; the mechanism's table
    by default, ``False`` for none): each run's parameters with a tolerance
    are drawn from it, and the fits use them as priors.

    Returns a :class:`MonteCarlo`: the medians and per-parameter RMS errors,
    and each run's figures (``to_pandas()``). Ctrl-C stops it.
    """
    return _ext.montecarlo(locals())


def budget(
    mechanism,
    tolerances=None,
    *,
    grid=200,
    samples=3000,
    seed=_D["seed"],
    model="exact",
    poses=None,
    stated_noise=_D["stated_noise"],
    stated_angle_noise=None,
    noise=None,
    angle_noise=None,
):
    """The tool error a mechanism's parameter tolerances give over its
    workspace, before any machine exists: to first order through the exact
    model's Jacobian at ``grid`` targets spread over the workspace, checked
    by ``samples`` machines drawn from the tolerances (0: none); each
    tolerance's share; and, with ``poses`` (targets a calibration would
    measure the tool at, with the instrument's stated noise
    ``stated_noise`` mm and ``stated_angle_noise`` rad;
    ``noise=`` and ``angle_noise=`` are their old names here), what that
    calibration would leave. ``tolerances``: a dict name → σ (in the
    parameter's unit) or ``"20%"`` (of its nominal value); by default the
    description's ``[tolerances]`` table (given ones replace its entries).
    Ctrl-C stops it.
    """
    return _ext.budget(_stated(locals()))


def drift(new, old=None, *, mechanism=None, alpha=_D["alpha"], grid=100):
    """Has the machine changed, or only the noise? Compare the calibration
    ``new`` with ``old`` (an earlier calibration of the same machine) or,
    without ``old``, with the mechanism's nominal values: each parameter
    identified in both, its change against ``√(σ_old² + σ_new²)``, sorted
    by significance; Holm–Bonferroni keeps the chance of any false alarm at
    ``alpha``; a joint χ² test includes the correlations. Each is a
    :class:`Calibration`, a :class:`SavedCalibration` or a record's path;
    ``mechanism`` is needed for the nominal values when ``new`` is not a
    :class:`Calibration`, and must be the mechanism the calibrations are of
    (their records' identity). With the mechanism at hand, the change at the
    tool over ``grid`` workspace targets too (``Drift.workspace``; 0: none).
    """
    return _ext.drift(locals())


def trilaterate(sockets, readings, *, bar_offset=0.0, sigma=0.002):
    """Positions from ball-bar readings: for each row of ``readings`` (bar
    lengths to each socket, mm), the point whose distances to ``sockets``
    (k, 2 or 3; base frame, mm) best match them, and its covariance for
    readings of standard deviation ``sigma`` (mm). Returns ``(positions (n,
    dim), covariances (n, dim, dim))``."""
    return _ext.trilaterate(locals())


def load_calibration(path):
    """Read a calibration record (:meth:`Calibration.save`, ``pkmcal
    calibrate --report``): a :class:`SavedCalibration`, to pass as
    ``params``."""
    return _ext.load_calibration(locals())


def set_threads(n):
    """The number of threads each call computes with: ``n`` (0 for one per
    core, the default). Calls from several Python threads each compute on
    threads of their own. In a pool of worker processes, 1 per worker keeps
    the cores from being oversubscribed. Takes effect at the next call."""
    _ext.set_threads(locals())
