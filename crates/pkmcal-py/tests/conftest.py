"""Shared fixtures: the repository, the command-line tool (built if needed)
and a CSV reader, so that Python results are compared with the CLI's."""

import os
import pathlib
import subprocess

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]
EXAMPLES = REPO / "examples"


def _cli() -> pathlib.Path:
    explicit = os.environ.get("PKMCAL_BIN")
    if explicit:
        return pathlib.Path(explicit)
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    # Built by `cargo test --workspace` (dev profile) before pytest runs in CI.
    subprocess.run(
        ["cargo", "build", "--quiet", "-p", "pkmcal-cli"],
        cwd=REPO,
        check=True,
    )
    return target / "debug" / "pkmcal"


@pytest.fixture(scope="session")
def cli():
    path = _cli()

    def run(*args, check=True):
        r = subprocess.run(
            [str(path), *map(str, args)], capture_output=True, text=True, cwd=REPO
        )
        if check and r.returncode != 0:
            raise AssertionError(f"pkmcal {' '.join(map(str, args))} failed:\n{r.stderr}")
        return r

    return run


def read_csv(path):
    """Columns of a CSV written by the CLI, by name (comment lines skipped)."""
    lines = [l for l in pathlib.Path(path).read_text().splitlines() if not l.startswith("#")]
    header = lines[0].split(",")
    rows = np.array([[float(v) for v in l.split(",")] for l in lines[1:]])
    return {h: rows[:, i] for i, h in enumerate(header)}


def columns(table, names):
    return np.column_stack([table[n] for n in names])


def read_params(path):
    import tomllib

    with open(path, "rb") as f:
        return tomllib.load(f)
