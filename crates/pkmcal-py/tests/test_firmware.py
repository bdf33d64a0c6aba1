"""The firmware calibrations (klipper, reprap, marlin, with and without
physical=True) return the numbers the command line prints, write the same
files where asked and nothing else, refuse misuse naming the keyword, and
say whether the probe's noise was stated or assumed."""

import re

import pytest

import pkmcal
from conftest import EXAMPLES

KLIPPER = EXAMPLES / "klipper-delta" / "printer.cfg"
ROTARY = EXAMPLES / "klipper-rotary-delta" / "printer.cfg"
RRF = (EXAMPLES / "reprap-delta" / "config.g", EXAMPLES / "reprap-delta" / "probes.csv")
MARLIN = (EXAMPLES / "marlin-delta" / "M503.txt", EXAMPLES / "marlin-delta" / "G30.log")


def sigma_text(v):
    if v.sigma is not None and v.sigma > 0:
        return f"{v.sigma:.4f} {v.unit}"
    if v.sigma is not None and v.sigma != v.sigma:
        return "unknown"
    return "fixed"


def assert_values_as_cli(result, stdout):
    """Each value's row of the table the command line prints."""
    assert result.values
    lines = stdout.splitlines()
    for v in result.values:
        row = f"  {v.name:<28} {v.before:>14.6f} {v.after:>14.6f} {sigma_text(v):>14}"
        assert row in lines, f"{row!r} not in:\n{stdout}"


def assert_heights_as_cli(result, stdout):
    e = result.height_errors
    said = (
        f"before max {e['before'].max:.4f} mm, RMS {e['before'].rms:.4f} mm; "
        f"after max {e['after'].max:.4f} mm, RMS {e['after'].rms:.4f} mm"
    )
    assert said in stdout, f"{said!r} not in:\n{stdout}"


@pytest.mark.parametrize("firmware", ["klipper", "reprap", "marlin"])
def test_firmware_values_and_file_equal_cli(cli, tmp_path, firmware):
    if firmware == "klipper":
        files, call = ["--config", KLIPPER], lambda **k: pkmcal.klipper(KLIPPER, **k)
    elif firmware == "reprap":
        files = ["--config", RRF[0], "--probes", RRF[1]]
        call = lambda **k: pkmcal.reprap(*RRF, **k)  # noqa: E731
    else:
        files = ["--config", MARLIN[0], "--probes", MARLIN[1]]
        call = lambda **k: pkmcal.marlin(*MARLIN, **k)  # noqa: E731
    out = cli(firmware, *files, "--out", tmp_path / "cli.out").stdout
    r = call(out=tmp_path / "py.out")
    assert r.physical is None
    assert r.termination in out
    assert " ".join(r.free) in out
    assert_heights_as_cli(r, out)
    assert_values_as_cli(r, out)
    assert (tmp_path / "py.out").read_bytes() == (tmp_path / "cli.out").read_bytes()
    assert r.out == str(tmp_path / "py.out")
    # Nothing is written unless asked.
    before = sorted(p.name for p in tmp_path.iterdir())
    call()
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_klipper_physical_equals_cli(cli, tmp_path):
    out = cli(
        "klipper", "--config", KLIPPER, "--physical",
        "--out", tmp_path / "cli.cfg", "--height-map", tmp_path / "cli-map.cfg",
    ).stdout
    r = pkmcal.klipper(KLIPPER, physical=True, out=tmp_path / "py.cfg", height_map=tmp_path / "py-map.cfg")
    p = r.physical
    assert p is not None
    assert (tmp_path / "py.cfg").read_bytes() == (tmp_path / "cli.cfg").read_bytes()
    # The map's comment names where the readings came from: the same file.
    assert (tmp_path / "py-map.cfg").read_bytes() == (tmp_path / "cli-map.cfg").read_bytes()
    assert p.height_map is not None and p.height_map.nodes > 0
    assert f"from {p.height_map.min:+.4f} to {p.height_map.max:+.4f} mm" in out
    assert_heights_as_cli(r, out)
    assert_values_as_cli(r, out)
    for what, e in [("the current values", p.nozzle_errors["current"]), ("Klipper's own fit of the probe", p.nozzle_errors["own"])]:
        said = f"XY RMS {e.xy_rms:.4f} mm, max {e.xy_max:.4f} mm; Z RMS {e.z_rms:.4f} mm, max {e.z_max:.4f} mm"
        line = next(l for l in out.splitlines() if l.strip().startswith(what))
        assert said in line, f"{said!r} not in {line!r}"
    for cube in p.cubes:
        said = (
            f"X size {cube.size[0]:+.3f} ± {cube.size_sd[0]:.3f} mm, "
            f"Y size {cube.size[1]:+.3f} ± {cube.size_sd[1]:.3f} mm, "
            f"top flatness {cube.flatness:.3f} ± {cube.flatness_sd:.3f} mm"
        )
        assert said in out, said
    assert p.next_measurements
    assert f"1. {p.next_measurements[0].what}:" in out
    written = "the values for the nozzle are written" in out
    assert p.projection_written == written
    # The probe's σ is assumed: a typical probe's, the residuals' smaller
    # scatter news, not a warning.
    assert not p.probe_noise_stated and p.probe_noise == 0.01
    assert p.noise_note is not None and not p.noise_note.more and not p.noise_note.stated
    assert p.noise_note.hint == ""
    assert "a typical probe's" in p.noise_note.message and "assumed" in p.noise_note.message
    assert all(w.kind != "noise" for w in r.warnings)


@pytest.mark.parametrize("firmware", ["reprap", "marlin"])
def test_physical_writes_the_clis_lines(cli, tmp_path, firmware):
    files = RRF if firmware == "reprap" else MARLIN
    cli(firmware, "--config", files[0], "--probes", files[1], "--physical",
        "--out", tmp_path / "cli.g", "--height-map", tmp_path / "cli-map")
    fn = pkmcal.reprap if firmware == "reprap" else pkmcal.marlin
    r = fn(*files, physical=True, out=tmp_path / "py.g", height_map=tmp_path / "py-map")
    assert (tmp_path / "py.g").read_bytes() == (tmp_path / "cli.g").read_bytes()
    assert (tmp_path / "py-map").read_bytes() == (tmp_path / "cli-map").read_bytes()
    assert r.physical is not None and r.physical.cubes


def test_stated_probe_noise_is_said_stated(cli):
    # Stated far above what the heights show: the residuals scatter less,
    # and the hint is about the value stated.
    r = pkmcal.klipper(KLIPPER, physical=True, probe_noise=0.2)
    p = r.physical
    assert p is not None and p.probe_noise_stated and p.probe_noise == 0.2
    n = p.noise_note
    assert n is not None and n.stated and not n.more
    assert "stated" in n.message and "assumed" not in n.message
    assert "probe_noise=0.2" in n.hint
    assert any(w.kind == "noise" for w in r.warnings)
    out = cli("klipper", "--config", KLIPPER, "--physical", "--probe-noise", "0.2").stdout
    assert "probe σ 0.2 mm as stated" in out
    assert "check --probe-noise 0.2" in out
    # Stated below what the heights show: they scatter more; the hint asks
    # to check the value stated, not to state one.
    r = pkmcal.klipper(KLIPPER, physical=True, probe_noise=0.0002)
    n = r.physical.noise_note if r.physical else None
    assert n is not None and n.stated and n.more
    assert "the σ 0.0002 mm stated" in n.message
    assert n.hint.startswith("check probe_noise=0.0002")
    out = cli("klipper", "--config", KLIPPER, "--physical", "--probe-noise", "0.0002").stdout
    # One message, the library's: the front ends word only the hint.
    assert f"warning: {n.message}" in out
    assert "hint: check --probe-noise 0.0002" in out


@pytest.mark.parametrize(
    "kwargs,says",
    [
        ({"probe_noise": 0.01}, "probe_noise= weighs the physical fit's probe heights: add physical=True"),
        ({"tolerances": {"rod_a1": 0.05}}, "tolerances= belongs to the physical model: add physical=True"),
        ({"height_map": "x.cfg"}, "height_map= maps what the physical model's values leave: add physical=True"),
        ({"physical": True, "mesh_points": 7}, "mesh_points= sets the height map's mesh: add height_map="),
        ({"physical": True, "probe_noise": 0.0}, "probe_noise: 0 mm: a probe's σ is above 0"),
        ({"physical": True, "probe_noise": 5.0}, "probe_noise: 5 mm"),
        ({"physical": True, "probe_noise": float("nan")}, "probe_noise: NaN mm"),
        ({"max_sigma": 0.0}, "max_sigma: 0 must be above 0"),
        ({"previous": KLIPPER}, "previous= compares physical calibrations: add physical=True"),
        ({"weighting": "often"}, "weighting: "),
        ({"heights": EXAMPLES / "klipper-delta" / "heights.csv"}, "heights= are read by the physical model: add physical=True"),
    ],
)
def test_misuse_is_refused_by_keyword(tmp_path, kwargs, says):
    with pytest.raises(pkmcal.PkmcalError) as e:
        pkmcal.klipper(KLIPPER, **kwargs)
    assert says in str(e.value)
    assert not list(tmp_path.iterdir())


def test_probe_noise_bounds_on_the_command_line(cli):
    for bad in ["0", "-1", "2", "nan"]:
        r = cli("klipper", "--config", KLIPPER, "--physical", f"--probe-noise={bad}", check=False)
        assert r.returncode == 2, r.stderr
        assert "--probe-noise" in r.stderr
    r = cli("klipper", "--config", KLIPPER, "--probe-noise", "0.01", check=False)
    assert r.returncode == 2
    assert "--probe-noise weighs the physical fit's probe heights: add --physical" in r.stderr


def test_rotary_delta_refuses_physical():
    r = pkmcal.klipper(ROTARY)
    assert r.values and r.physical is None
    with pytest.raises(pkmcal.PkmcalError, match="physical=True models linear deltas"):
        pkmcal.klipper(ROTARY, physical=True)


def test_results_compare_by_value():
    import pickle

    a = pkmcal.reprap(*RRF)
    assert pickle.loads(pickle.dumps(a)) == a
    assert isinstance(a, pkmcal.FirmwareCalibration)


def test_rectangular_klipper_mesh_as_cli(cli, tmp_path):
    # Klipper's rectangular [bed_mesh]: the profile keeps its layout, the
    # same file from both front ends.
    cfg = tmp_path / "printer.cfg"
    cfg.write_text(
        "[bed_mesh]\nmesh_min: -120, -120\nmesh_max: 120, 120\nprobe_count: 5, 7\n\n" + KLIPPER.read_text()
    )
    out = cli("klipper", "--config", cfg, "--physical", "--height-map", tmp_path / "cli.cfg").stdout
    r = pkmcal.klipper(cfg, physical=True, height_map=tmp_path / "py.cfg")
    text = (tmp_path / "py.cfg").read_text()
    assert text == (tmp_path / "cli.cfg").read_text()
    assert "x_count = 5\ny_count = 7\n" in text
    assert "min_x = -120.0\nmax_x = 120.0\nmin_y = -120.0\nmax_y = 120.0" in text
    m = r.physical.height_map if r.physical else None
    assert m is not None and m.rectangular and m.counts == (5, 7) and m.spacings == (60.0, 40.0)
    assert "5 x 7 nodes 60.00 by 40.00 mm apart from (-120, -120) to (120, 120)" in out


def test_heights_measured_by_hand_as_cli(cli, tmp_path):
    """``heights=`` reads the touches as ``--heights`` does: the same values
    written, the probe's heights counted without the touches."""
    heights = EXAMPLES / "klipper-delta" / "heights.csv"
    out = cli(
        "klipper", "--config", KLIPPER, "--physical", "--heights", heights,
        "--out", tmp_path / "cli.cfg",
    ).stdout
    r = pkmcal.klipper(KLIPPER, physical=True, heights=heights, out=tmp_path / "py.cfg")
    assert (tmp_path / "py.cfg").read_bytes() == (tmp_path / "cli.cfg").read_bytes()
    assert f"Physical model: {r.heights} probe heights" in out
    assert "touches" in out
    assert_values_as_cli(r, out)
    without = pkmcal.klipper(KLIPPER, physical=True)
    assert without.heights == r.heights


def test_physical_outputs_all_or_nothing(tmp_path):
    """One output that cannot be written: none is (the height map is not
    left behind when ``out=`` fails)."""
    with pytest.raises(pkmcal.PkmcalError):
        pkmcal.klipper(
            KLIPPER, physical=True,
            out=tmp_path / "missing" / "new.cfg", height_map=tmp_path / "map.cfg",
        )
    assert not list(tmp_path.iterdir())


REPORT_FILES = [
    "report.html",
    "nozzle-z.svg", "nozzle-z.png",
    "nozzle-xy.svg", "nozzle-xy.png",
    "nozzle-sigma.svg", "nozzle-sigma.png",
]


def assert_same_files(a, b, names):
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert sorted(p.name for p in a.iterdir()) == sorted(p.name for p in b.iterdir())


@pytest.mark.parametrize("firmware", ["klipper", "reprap", "marlin"])
def test_report_dir_equals_cli(cli, tmp_path, firmware):
    """``report_dir=`` writes the report ``--report-dir`` writes: the figures
    byte for byte, the page but for the names of the inputs its advice says
    to give (the height map's path is on the page: both write it to the
    same path, one after the other)."""
    if firmware == "klipper":
        # With the drift since a previous configuration on the page.
        files = ["--config", KLIPPER, "--previous", KLIPPER]
        call = lambda **k: pkmcal.klipper(KLIPPER, previous=KLIPPER, **k)  # noqa: E731
    elif firmware == "reprap":
        files = ["--config", RRF[0], "--probes", RRF[1]]
        call = lambda **k: pkmcal.reprap(*RRF, **k)  # noqa: E731
    else:
        files = ["--config", MARLIN[0], "--probes", MARLIN[1]]
        call = lambda **k: pkmcal.marlin(*MARLIN, **k)  # noqa: E731
    height_map = tmp_path / "map"
    out = cli(firmware, *files, "--physical", "--report-dir", tmp_path / "cli",
              "--height-map", height_map).stdout
    assert f"report -> {tmp_path / 'cli'}" in out
    cli_map = height_map.read_bytes()
    r = call(physical=True, report_dir=tmp_path / "py", height_map=height_map)
    assert height_map.read_bytes() == cli_map
    assert r.report_dir == str(tmp_path / "py")
    assert_same_files(tmp_path / "py", tmp_path / "cli",
                      [f for f in REPORT_FILES if f != "report.html"])
    # The page is the command line's but for how it names the inputs its
    # advice says to give: Python's keywords, not the command line's options.
    html = (tmp_path / "py" / "report.html").read_text()
    cli_html = (tmp_path / "cli" / "report.html").read_text()
    for option, keyword in [("--heights", "heights="), ("--probes", "probes="),
                            ("--height-map", "height_map=")]:
        cli_html = cli_html.replace(option, keyword)
    assert html == cli_html
    assert str(height_map) in html
    # The next measurements the call returns head the page's.
    assert r.physical is not None and r.physical.next_measurements
    assert r.physical.next_measurements[0].what.split(" ")[0] in html
    assert (r.physical.drift is not None) == (firmware == "klipper")
    assert ("<h2>Since " in html) == (firmware == "klipper")


def test_report_dir_needs_physical_and_is_all_or_nothing(tmp_path):
    with pytest.raises(pkmcal.PkmcalError, match="report_dir= writes the physical model's report: add physical=True"):
        pkmcal.reprap(*RRF, report_dir=tmp_path / "r")
    # An output that cannot be written: the report's directory is not left
    # behind, nor its files.
    with pytest.raises(pkmcal.PkmcalError):
        pkmcal.reprap(*RRF, physical=True, report_dir=tmp_path / "r",
                      out=tmp_path / "missing" / "new.g")
    assert not list(tmp_path.iterdir())
    # A file where the directory would be is refused, naming it.
    (tmp_path / "f").write_text("x")
    with pytest.raises(pkmcal.PkmcalError, match="not a directory|directory"):
        pkmcal.reprap(*RRF, physical=True, report_dir=tmp_path / "f")
    assert (tmp_path / "f").read_text() == "x"


def klipper_with_distances(tmp_path):
    """The Klipper example with DELTA_ANALYZE distances added to its saved
    block: pairs of its probe points, each distance the one its configured
    geometry predicts plus a few hundredths (the arms it does not know)."""
    import numpy as np

    from conftest import columns, read_csv

    pkmcal.klipper(KLIPPER, out_dir=tmp_path / "nominal")
    mech = pkmcal.Mechanism(tmp_path / "nominal" / "mechanism.toml")
    commands = columns(read_csv(tmp_path / "nominal" / "probes.csv"), ["a", "b", "c"])
    steps = [l.split("=")[1].strip() for l in KLIPPER.read_text().splitlines()
             if re.match(r"#\*# height\d+_pos", l)]
    assert len(steps) == len(commands)
    x = pkmcal.predict(mech, commands).x[:, :3]
    lines = []
    for n, (i, j) in enumerate([(0, 1), (0, 2), (0, 3), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6)]):
        d = float(np.linalg.norm(x[i] - x[j])) + 0.01 * ((n % 3) - 1)
        lines.append(f"#*# distance{n} = {d:.6f}\n#*# distance{n}_pos1 = {steps[i]}\n#*# distance{n}_pos2 = {steps[j]}\n")
    cfg = tmp_path / "printer.cfg"
    cfg.write_text(KLIPPER.read_text().rstrip("\n") + "\n" + "".join(lines))
    return cfg


def test_out_dir_equals_cli(cli, tmp_path):
    """``out_dir=`` writes what ``--out-dir`` writes, byte for byte: the
    mechanism, the probe heights, the distances (with DELTA_ANALYZE ones)
    and the identified parameters; with ``out=`` all or nothing."""
    cfg = klipper_with_distances(tmp_path)
    out = cli("klipper", "--config", cfg, "--out-dir", tmp_path / "cli", "--out", tmp_path / "cli.cfg").stdout
    assert "8 distances measured on the calibration object" in out
    r = pkmcal.klipper(cfg, out_dir=tmp_path / "py", out=tmp_path / "py.cfg")
    assert r.distances == 8 and r.out_dir == str(tmp_path / "py")
    names = ["mechanism.toml", "probes.csv", "calibration.toml", "distances.csv"]
    assert_same_files(tmp_path / "py", tmp_path / "cli", names)
    assert (tmp_path / "py.cfg").read_bytes() == (tmp_path / "cli.cfg").read_bytes()
    # Without distances, no distances.csv (as the command line).
    cli("klipper", "--config", KLIPPER, "--out-dir", tmp_path / "cli2")
    r = pkmcal.klipper(KLIPPER, out_dir=tmp_path / "py2")
    assert_same_files(tmp_path / "py2", tmp_path / "cli2", names[:3])
    # What it wrote is read by the other functions: with the parameters
    # identified, the probed points (all at height 0) lie flatter than with
    # the configuration's.
    from conftest import columns, read_csv

    mech = pkmcal.Mechanism(tmp_path / "py2" / "mechanism.toml")
    commands = columns(read_csv(tmp_path / "py2" / "probes.csv"), ["a", "b", "c"])
    z_before = pkmcal.predict(mech, commands).x[:, 2]
    z_after = pkmcal.predict(mech, commands, tmp_path / "py2" / "calibration.toml").x[:, 2]
    assert z_after.std() < 0.5 * z_before.std(), (z_before.std(), z_after.std())


def test_out_dir_refusals_and_all_or_nothing(tmp_path):
    with pytest.raises(pkmcal.PkmcalError, match="out_dir="):
        pkmcal.klipper(KLIPPER, physical=True, out_dir=tmp_path / "d")
    with pytest.raises(TypeError):
        pkmcal.reprap(*RRF, out_dir=tmp_path / "d")  # type: ignore[call-arg]
    with pytest.raises(pkmcal.PkmcalError):
        pkmcal.klipper(KLIPPER, out_dir=tmp_path / "d", out=tmp_path / "missing" / "new.cfg")
    assert not list(tmp_path.iterdir())


def g33_lines(stdout):
    lines = stdout.splitlines()
    i = next(k for k, l in enumerate(lines) if l.startswith("G33 P"))
    return lines[i:i + 5]


@pytest.mark.parametrize("extra,kwargs", [
    ([], {}),
    (["--g33-points", "3", "--g33-fixed-angles", "--g33-radius", "80"],
     {"g33_points": 3, "g33_fixed_angles": True, "g33_radius": 80.0}),
])
def test_marlin_g33_comparison_equals_cli(cli, extra, kwargs):
    """The comparison with Marlin's own G33 that ``pkmcal marlin`` prints,
    as data: the same run, the settings it would set, the height errors
    with its values and with pkmcal's."""
    out = cli("marlin", "--config", MARLIN[0], "--probes", MARLIN[1], *extra).stdout
    r = pkmcal.marlin(*MARLIN, **kwargs)
    g = r.g33
    assert g is not None and g.run is not None and g.not_run is None
    head, runs, m665, m666, errors = g33_lines(out)
    assert head.startswith(f"G33 P{g.points}{'' if g.towers else ' T'} ({g.factors} factors: {g.adjusts})")
    assert f"at radius {g.radius:.2f} mm" in head
    assert g.radius_from == ("given" if kwargs else "farthest probed point")
    run = g.run
    sd = " → ".join(f"{s:.3f}" for s in run.std_devs)
    assert runs.startswith(f"  {len(run.std_devs)} iteration{'' if len(run.std_devs) == 1 else 's'} of {run.probes} points, std dev {sd} mm")
    assert ("rolled back to the best" in runs) == run.rolled_back
    assert run.settings.splitlines() == [m665.strip(), m666.strip()]
    said = (f"with G33's values: max {run.with_g33.max:.4f} mm, RMS {run.with_g33.rms:.4f} mm; "
            f"with pkmcal's: max {run.with_pkmcal.max:.4f} mm, RMS {run.with_pkmcal.rms:.4f} mm")
    assert said in errors, f"{said!r} not in {errors!r}"
    # A real comparison: G33 changes the settings it calibrates.
    assert run.settings != "\n".join(MARLIN[0].read_text().splitlines()[:2])
    assert len(run.std_devs) >= 1 and run.probes > 0


def test_g33_only_for_marlin_without_physical():
    assert pkmcal.klipper(KLIPPER).g33 is None
    assert pkmcal.reprap(*RRF).g33 is None
    r = pkmcal.marlin(*MARLIN, physical=True)
    assert r.g33 is None and r.physical is not None


@pytest.mark.parametrize("kwargs,says", [
    ({"g33_points": 0}, "g33_points=0: G33's probe points (its P) are 1 to 10"),
    ({"g33_points": 11}, "g33_points=11"),
    ({"g33_points": -1}, "g33_points"),
    ({"g33_radius": 0.0}, "g33_radius: 0 mm"),
    ({"g33_radius": float("nan")}, "g33_radius: NaN mm"),
])
def test_g33_choices_bounded(kwargs, says):
    with pytest.raises(pkmcal.PkmcalError, match=re.escape(says)):
        pkmcal.marlin(*MARLIN, **kwargs)


@pytest.mark.parametrize("firmware", ["marlin", "marlin-physical", "klipper-physical", "rotary"])
def test_fixed_values_have_no_sigma(cli, firmware):
    """A value no free parameter moves has ``sigma`` None (the command line
    says "fixed"), never 0.0; the others a σ above 0."""
    if firmware.startswith("marlin"):
        physical = firmware.endswith("physical")
        out = cli("marlin", "--config", MARLIN[0], "--probes", MARLIN[1],
                  *(["--physical"] if physical else [])).stdout
        r = pkmcal.marlin(*MARLIN, physical=physical)
    elif firmware == "klipper-physical":
        out = cli("klipper", "--config", KLIPPER, "--physical").stdout
        r = pkmcal.klipper(KLIPPER, physical=True)
    else:
        out = cli("klipper", "--config", ROTARY).stdout
        r = pkmcal.klipper(ROTARY)
    fixed = [l.split()[0:3] for l in out.splitlines() if l.rstrip().endswith(" fixed")]
    assert fixed, out
    for v in r.values:
        row = next(l for l in out.splitlines() if l.startswith(f"  {v.name:<28} "))
        assert row.rstrip().endswith(" fixed") == (v.sigma is None) == v.fixed, row
        assert v.sigma is None or v.sigma > 0 or v.sigma != v.sigma
    assert_values_as_cli(r, out)


def test_outputs_never_over_inputs_or_each_other(tmp_path):
    """As the command line refuses them, before any work: ``out=`` over
    the configuration (or any input), two outputs on one file."""
    cfg = tmp_path / "printer.cfg"
    cfg.write_bytes(KLIPPER.read_bytes())
    with pytest.raises(pkmcal.PkmcalError, match="also an input"):
        pkmcal.klipper(cfg, out=cfg)
    assert cfg.read_bytes() == KLIPPER.read_bytes()
    with pytest.raises(pkmcal.PkmcalError, match="also an input"):
        pkmcal.reprap(*RRF, out=RRF[1])
    with pytest.raises(pkmcal.PkmcalError):
        pkmcal.klipper(cfg, out_dir=tmp_path / "d", out=tmp_path / "d" / "mechanism.toml")
    with pytest.raises(pkmcal.PkmcalError):
        pkmcal.marlin(*MARLIN, physical=True, out=tmp_path / "m.g", height_map=tmp_path / "m.g")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["printer.cfg"]


def test_g33_not_run_says_why_as_cli(cli):
    """Where G33 cannot run (its circle out of the printer's reach), the
    comparison says why, in the command line's words, and the values are
    returned all the same."""
    out = cli("marlin", "--config", MARLIN[0], "--probes", MARLIN[1], "--g33-radius", "1000").stdout
    r = pkmcal.marlin(*MARLIN, g33_radius=1000.0)
    g = r.g33
    assert g is not None and g.run is None and g.not_run is not None
    assert "out of reach" in g.not_run
    assert f"  not run: {g.not_run}" in out.splitlines()
    assert r.values


def test_next_measurements_name_pythons_keywords():
    """The advice says how to give each measurement back in Python's words
    (``heights=``, ``probes=``), never the command line's options."""
    for r in [pkmcal.klipper(KLIPPER, physical=True),
              pkmcal.reprap(*RRF, physical=True),
              pkmcal.marlin(*MARLIN, physical=True)]:
        assert r.physical is not None
        words = [n.what for n in r.physical.next_measurements]
        assert words and not any("--" in w for w in words), words
        assert any("heights=" in w for w in words), words
    touches = [n.what for n in pkmcal.klipper(KLIPPER, physical=True).physical.next_measurements
               if "nozzle touches" in n.what]
    assert touches and "read back from heights= as `nozzle` rows" in touches[0]


def test_an_even_mesh_count_on_a_round_mesh_is_refused_by_its_keyword(tmp_path):
    """A round mesh has a centre node: an even ``mesh_points`` is refused,
    naming the keyword, before any file is written."""
    with pytest.raises(pkmcal.PkmcalError, match=r"mesh_points: 6 nodes across: a round bed's mesh has an odd count"):
        pkmcal.klipper(KLIPPER, physical=True, height_map=tmp_path / "m.cfg", mesh_points=6)
    assert not (tmp_path / "m.cfg").exists()


def test_g33_options_are_refused_with_physical():
    with pytest.raises(pkmcal.PkmcalError, match="g33_points= sets the run of Marlin's own G33"):
        pkmcal.marlin(*MARLIN, physical=True, g33_points=7)
