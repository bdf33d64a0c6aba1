"""The firmware calibrations of delta printers: :func:`klipper`,
:func:`reprap` and :func:`marlin` (the command line's ``pkmcal klipper``,
``reprap`` and ``marlin``), their options as keywords with the same
meanings, what the command line prints returned as data. Files are written
only where asked (``out=``, ``height_map=``, ``report_dir=``, ``out_dir=``),
all or nothing, byte for byte as the command line writes them."""

import dataclasses as _dataclasses
import os
from typing import Any, Dict, List, Literal, Mapping, Optional, Sequence, Tuple, Union

from . import _pkmcal as _ext

_Path = Union[str, "os.PathLike[str]"]
_Names = Union[None, str, Sequence[str]]
_Tolerances = Optional[Mapping[str, Union[float, str]]]

_MAX_SIGMA: float = _ext.DEFAULTS["max_sigma"]


@_dataclasses.dataclass(frozen=True)
class Errors:
    """The largest and the RMS error of a set of readings (mm)."""

    max: float
    rms: float


@_dataclasses.dataclass(frozen=True)
class FirmwareValue:
    """A value the firmware keeps: ``before`` (the configuration's) and
    ``after`` (the one written), its ``sigma`` in its ``unit``: ``None``
    where the value is fixed (no free parameter moves it; the command line
    says "fixed"), NaN where it is unknown; ``fixed`` says the same."""

    name: str
    before: float
    after: float
    sigma: Optional[float]
    unit: str

    @property
    def fixed(self) -> bool:
        """No free parameter moves this value (``sigma`` is ``None``)."""
        return self.sigma is None


@_dataclasses.dataclass(frozen=True)
class FirmwareNote:
    """A warning of the calibration: ``kind`` (``"correlated"``,
    ``"uncertain"``, ``"tilt_absorbed"``, ``"noise"``, or a fit's warning
    kind such as ``"outliers"``), what was found (``message``) and what to
    do (``hint``, naming this package's keywords)."""

    kind: str
    message: str
    hint: str


@_dataclasses.dataclass(frozen=True)
class NoiseNote:
    """What the physical fit's residuals say of the readings' noise: of
    the probe ``heights`` (else the distances), weighed with ``noise`` mm,
    ``stated`` (``probe_noise=``) or assumed (a typical probe's); the σ the
    residuals show (``found``), the χ² test's ``p``, whether they scatter
    ``more`` than ``noise`` (else less), and the parameters left out that
    would explain it (``suspects``: name and share of the misfit). With
    ``hint`` empty it is news, not a warning."""

    message: str
    hint: str
    heights: bool
    stated: bool
    noise: float
    found: float
    p: float
    more: bool
    suspects: List[Tuple[str, float]]


@_dataclasses.dataclass(frozen=True)
class NozzleErrors:
    """The nozzle's error over the build volume in the bed's frame (mm):
    XY (less the shift and turn no part shows) and Z (over the bed)."""

    xy_rms: float
    xy_max: float
    z_rms: float
    z_max: float


@_dataclasses.dataclass(frozen=True)
class Cube:
    """A predicted calibration cube printed with the values written:
    where (``centre``, mm), its X and Y size errors with their standard
    deviations, and its top's flatness."""

    centre: Tuple[float, float]
    size: Tuple[float, float]
    size_sd: Tuple[float, float]
    flatness: float
    flatness_sd: float


@_dataclasses.dataclass(frozen=True)
class NextMeasurement:
    """An extra measurement, in the firmware's commands (``what``), and the
    cube's largest σ before and after it (mm)."""

    what: str
    largest_before: float
    largest_after: float
    variance_removed: float


@_dataclasses.dataclass(frozen=True)
class Unseen:
    """A part the probe pattern cannot see: ``blind`` of its ``of`` free
    parameters, and what that means."""

    part: str
    blind: int
    of: int
    meaning: str


@_dataclasses.dataclass(frozen=True)
class HeightMap:
    """The height map written (``height_map=``): where, its mesh (nodes in
    x and y, their spacing, ``rectangular`` or round within ``radius``), the
    range of its values and their largest σ (mm); ``uncertain``: its
    uncertainty exceeds its values (measure more before loading it)."""

    path: str
    counts: Tuple[int, int]
    spacings: Tuple[float, float]
    rectangular: bool
    radius: float
    nodes: int
    min: float
    max: float
    largest_sd: Optional[float]
    uncertain: bool


@_dataclasses.dataclass(frozen=True)
class PrinterDrift:
    """Whether the printer changed since ``previous`` beyond both
    calibrations' uncertainty: the joint test (``chi2`` over ``dof``
    directions, ``p``) and the parameters seen alone."""

    previous: str
    changed: bool
    chi2: float
    dof: int
    p: float
    parameters: List[Dict[str, Any]]
    untested: List[str]


@_dataclasses.dataclass(frozen=True)
class Physical:
    """The verdict of ``physical=True``: the probe's σ (``probe_noise``,
    ``probe_noise_stated``) and what the residuals say of it
    (``noise_note``); whether the values for the nozzle are written
    (``projection_written``, else the firmware's own fit is) with the mean
    square error they gain (mm², mean and σ; ``z_gain`` Z alone); the
    nozzle's errors over the build volume (``nozzle_errors``: ``current``,
    ``own`` the firmware's own fit, ``projected`` the values for the
    nozzle); the predicted ``cubes``; what the probe pattern cannot see
    (``unseen``); the extra measurements best first
    (``next_measurements``); the ``drift`` since ``previous=``; the
    ``height_map`` written."""

    probe_noise: float
    probe_noise_stated: bool
    noise_note: Optional[NoiseNote]
    projection_written: bool
    gain: Tuple[float, float]
    z_gain: Tuple[float, float]
    z_weight: float
    grid_points: int
    print_radius: float
    nozzle_errors: Dict[str, NozzleErrors]
    cubes: List[Cube]
    unseen: List[Unseen]
    next_measurements: List[NextMeasurement]
    drift: Optional[PrinterDrift]
    height_map: Optional[HeightMap]


@_dataclasses.dataclass(frozen=True)
class G33Run:
    """Marlin's G33 run on the printer the fit found: the standard
    deviation of each iteration's heights (mm, as G33 prints them), whether
    it ``rolled_back`` to its best iteration, the points it probed per
    iteration (``probes``), the M665/M666 lines it would set
    (``settings``), and the height errors at the probed points with G33's
    values (``with_g33``) and with pkmcal's (``with_pkmcal``): the fit's
    residuals plus the change the fitted printer predicts."""

    std_devs: List[float]
    rolled_back: bool
    probes: int
    settings: str
    with_g33: Errors
    with_pkmcal: Errors


@_dataclasses.dataclass(frozen=True)
class G33Comparison:
    """Marlin's own calibration, G33, as its G33.cpp runs it on the printer
    the fit found (``pkmcal marlin`` prints it after the values): its ``P``
    (``points``), whether it calibrates the tower angles (``towers``: no
    ``T``), the ``factors`` it adjusts and what they are (``adjusts``), the
    ``radius`` it probes at (mm) and where that came from
    (``radius_from``: ``"given"`` by ``g33_radius=``, ``"log"`` the G33 log
    printed it, ``"M665 B"``, or ``"farthest probed point"``); what it did
    (``run``), or why it could not run (``not_run``)."""

    points: int
    towers: bool
    factors: int
    adjusts: str
    radius: float
    radius_from: Literal["given", "log", "M665 B", "farthest probed point"]
    run: Optional[G33Run]
    not_run: Optional[str]


@_dataclasses.dataclass(frozen=True)
class FirmwareCalibration:
    """A firmware calibration: the ``firmware``, where its readings came
    from (``source``), the parameters ``free``, how the fit ended
    (``termination``), the readings (``heights``, ``distances``) and their
    errors before and after (``height_errors``, ``distance_errors``:
    ``{"before": Errors, "after": Errors}``), the ``values`` written with
    their σ, the ``warnings``, the firmware's lines with the new values
    (``updated``), the files written (``out``, ``out_dir``,
    ``report_dir``), with ``physical=True`` the verdict (``physical``) and,
    for Marlin without it, the comparison with its own G33 (``g33``)."""

    firmware: str
    source: str
    free: List[str]
    termination: str
    heights: int
    distances: int
    height_errors: Dict[str, Errors]
    distance_errors: Optional[Dict[str, Errors]]
    values: List[FirmwareValue]
    warnings: List[FirmwareNote]
    physical: Optional[Physical]
    updated: str
    out: Optional[str]
    out_dir: Optional[str]
    report_dir: Optional[str]
    g33: Optional[G33Comparison]


def _errors(d: Optional[Mapping[str, Any]]) -> Optional[Dict[str, Errors]]:
    return None if d is None else {k: Errors(**v) for k, v in d.items()}


def _noise(d: Optional[Mapping[str, Any]]) -> Optional[NoiseNote]:
    if d is None:
        return None
    d = {k: v for k, v in d.items() if k != "kind"}
    d["suspects"] = [tuple(s) for s in d["suspects"]]
    return NoiseNote(**d)


def _physical(d: Optional[Mapping[str, Any]]) -> Optional[Physical]:
    if d is None:
        return None
    drift = d["drift"]
    height_map = d["height_map"]
    return Physical(
        probe_noise=d["probe_noise"],
        probe_noise_stated=d["probe_noise_stated"],
        noise_note=_noise(d["noise_note"]),
        projection_written=d["projection_written"],
        gain=tuple(d["gain"]),
        z_gain=tuple(d["z_gain"]),
        z_weight=d["z_weight"],
        grid_points=d["grid_points"],
        print_radius=d["print_radius"],
        nozzle_errors={k: NozzleErrors(**v) for k, v in d["nozzle_errors"].items()},
        cubes=[
            Cube(
                centre=tuple(c["centre"]),
                size=tuple(c["size"]),
                size_sd=tuple(c["size_sd"]),
                flatness=c["flatness"],
                flatness_sd=c["flatness_sd"],
            )
            for c in d["cubes"]
        ],
        unseen=[Unseen(**u) for u in d["unseen"]],
        next_measurements=[NextMeasurement(**m) for m in d["next_measurements"]],
        drift=None if drift is None else PrinterDrift(**drift),
        height_map=None
        if height_map is None
        else HeightMap(
            **{
                **height_map,
                "counts": tuple(height_map["counts"]),
                "spacings": tuple(height_map["spacings"]),
            }
        ),
    )


def _g33(d: Optional[Mapping[str, Any]]) -> Optional[G33Comparison]:
    if d is None:
        return None
    run = d["run"]
    return G33Comparison(
        **{
            **d,
            "run": None
            if run is None
            else G33Run(
                **{
                    **run,
                    "with_g33": Errors(**run["with_g33"]),
                    "with_pkmcal": Errors(**run["with_pkmcal"]),
                }
            ),
        }
    )


def _result(d: Mapping[str, Any]) -> FirmwareCalibration:
    return FirmwareCalibration(
        firmware=d["firmware"],
        source=d["source"],
        free=list(d["free"]),
        termination=d["termination"],
        heights=d["heights"],
        distances=d["distances"],
        height_errors=_errors(d["height_errors"]) or {},
        distance_errors=_errors(d["distance_errors"]),
        values=[FirmwareValue(**v) for v in d["values"]],
        warnings=[FirmwareNote(w["kind"], w["message"], w["hint"]) for w in d["warnings"]],
        physical=_physical(d["physical"]),
        updated=d["updated"],
        out=d["out"],
        out_dir=d["out_dir"],
        report_dir=d["report_dir"],
        g33=_g33(d["g33"]),
    )


def klipper(
    config: _Path,
    *,
    free: _Names = None,
    fix: _Names = None,
    weighting: str = "klipper",
    max_sigma: float = _MAX_SIGMA,
    physical: bool = False,
    tolerances: _Tolerances = None,
    probe_noise: Optional[float] = None,
    heights: Optional[_Path] = None,
    previous: Optional[_Path] = None,
    out: Optional[_Path] = None,
    out_dir: Optional[_Path] = None,
    height_map: Optional[_Path] = None,
    mesh_points: Optional[int] = None,
    report_dir: Optional[_Path] = None,
) -> FirmwareCalibration:
    """Calibrate a Klipper delta printer (``kinematics: delta`` or
    ``rotary_delta``) from its configuration ``config`` with the probe
    results DELTA_CALIBRATE saved, as ``pkmcal klipper`` does. ``free``,
    ``fix``: the parameters to identify (Klipper's by default);
    ``weighting``: ``"klipper"``, ``"estimated"`` or ``"shrunk[:N]"``;
    ``max_sigma``: warn of a written value whose σ exceeds it.
    ``physical=True``: fit the printer as built within its parts'
    ``tolerances`` (a dict name → σ replacing the defaults) with the probe's
    σ ``probe_noise`` (mm, above 0 and at most 1; a typical probe's 0.01 mm
    assumed by default), with the heights measured by hand in ``heights``
    (a CSV ``x, y, z, tool, surface[, sigma]``: where the nozzle or the
    probe touched a surface of known height, as ``--heights`` reads it),
    and write the values for the nozzle over the build volume; ``previous``: an earlier configuration, whether the printer
    changed since; ``height_map``: write what the values leave as a Klipper
    ``[bed_mesh]`` profile (``mesh_points`` nodes across);
    ``report_dir``: write the report for the printer's owner there
    (report.html with its figures, as ``--report-dir``). ``out``: write
    the configuration with the new values (never over ``config``);
    ``out_dir`` (not with ``physical=True``): write the printer as a pkmcal
    mechanism (mechanism.toml), its probe data (probes.csv, and
    distances.csv with DELTA_ANALYZE distances) and the identified
    parameters (calibration.toml) there, for the other functions. Every
    file asked for is written, or none.
    """
    return _result(_ext.klipper(locals()))


def reprap(
    config: _Path,
    probes: _Path,
    *,
    free: _Names = None,
    fix: _Names = None,
    max_sigma: float = _MAX_SIGMA,
    physical: bool = False,
    tolerances: _Tolerances = None,
    probe_noise: Optional[float] = None,
    heights: Optional[_Path] = None,
    out: Optional[_Path] = None,
    height_map: Optional[_Path] = None,
    mesh_points: Optional[int] = None,
    report_dir: Optional[_Path] = None,
) -> FirmwareCalibration:
    """Calibrate a RepRapFirmware delta printer from the M665/M666 lines of
    ``config`` (config.g or config-override.g) and the probe results
    ``probes`` (CSV x, y, z), as ``pkmcal reprap`` does; the options as
    :func:`klipper`'s (``height_map``: a heightmap.csv). ``out``: write the
    new M665 and M666 lines.
    """
    return _result(_ext.reprap(locals()))


def marlin(
    config: _Path,
    probes: _Path,
    *,
    free: _Names = None,
    fix: _Names = None,
    max_sigma: float = _MAX_SIGMA,
    m665_b: Optional[str] = None,
    probe_offset: Optional[Tuple[float, float]] = None,
    g33_radius: Optional[float] = None,
    g33_points: int = 4,
    g33_fixed_angles: bool = False,
    physical: bool = False,
    tolerances: _Tolerances = None,
    probe_noise: Optional[float] = None,
    heights: Optional[_Path] = None,
    out: Optional[_Path] = None,
    height_map: Optional[_Path] = None,
    mesh_points: Optional[int] = None,
    report_dir: Optional[_Path] = None,
) -> FirmwareCalibration:
    """Calibrate a Marlin delta printer from its M503 settings ``config``
    and a console log of probes ``probes``, as ``pkmcal marlin`` does;
    ``m665_b`` (``"calibration-radius"`` or ``"rod-trim"``) and
    ``probe_offset`` (x, y mm) where the files do not say; the other options
    as :func:`klipper`'s (``height_map``: M421 lines). Without
    ``physical=True`` the result holds the comparison with Marlin's own G33
    (``g33``), run with ``g33_points`` probe points (its ``P``, 1 to 10),
    without the tower angles if ``g33_fixed_angles`` (its ``T``), at
    ``g33_radius`` (mm; by default the G33 log's, else M665 B, else the
    farthest probed point; also where a G33 log's heights lie when it does
    not say). ``out``: write the new M665 and M666 lines.
    """
    return _result(_ext.marlin(locals()))
