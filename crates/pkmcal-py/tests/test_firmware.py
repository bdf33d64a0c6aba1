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
