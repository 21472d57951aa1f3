"""The console script, run as a user would: a subprocess, JSON parsed back."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def run_cli(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "marlcrash.cli", *args], capture_output=True, text=True, timeout=600)
    if check and proc.returncode != 0:
        raise AssertionError(f"marlcrash {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr}")
    return proc


def test_inspect_lsopt_json(lsopt_deck):
    out = json.loads(run_cli("inspect", str(lsopt_deck), "--param", "tbumper=3", "--param", "thood=1", "--json").stdout)
    assert (out["n_nodes"], out["n_shells"], out["n_solids"], out["n_beams"], out["n_parts"]) == (1236, 1174, 0, 0, 6)
    assert set(out["parts"]) == {"1", "2", "3", "4", "5", "6"}
    assert out["total_mass_kg"] == pytest.approx(sum(out["parts"].values()))
    assert out["skipped_cards"]  # the deck has contacts, rigid walls, database cards


def test_inspect_undefined_parameter_is_a_clear_error(lsopt_deck):
    proc = run_cli("inspect", str(lsopt_deck), check=False)
    assert proc.returncode == 2
    assert "tbumper" in proc.stderr and "line" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_inspect_table_and_bad_param(lsopt_deck):
    proc = run_cli("inspect", str(lsopt_deck), "--param", "tbumper=3", "--param", "thood=1")
    assert "1174 shells" in proc.stdout and "skipped cards" in proc.stdout
    proc = run_cli("inspect", str(lsopt_deck), "--param", "tbumper", check=False)
    assert proc.returncode == 2 and "--param" in proc.stderr


def test_discretize_default_car_json(tmp_path):
    plot = tmp_path / "cells.png"
    out = json.loads(run_cli("discretize", "--json", "--plot", str(plot)).stdout)
    for key in (
        "roi_volume_mm3",
        "target_cell_volume_mm3",
        "n_cells_uniform",
        "n_cells_optimized",
        "n_null_cells",
        "roi_mass_kg",
        "cell_mass_kg",
        "n_subassemblies",
    ):
        assert key in out, key
    assert out["n_cells_optimized"] * 8 <= out["n_cells_uniform"]
    assert out["cell_mass_kg"] == pytest.approx(out["roi_mass_kg"], rel=5e-3)
    assert plot.stat().st_size > 10_000


def test_discretize_lsopt_with_axis_map(lsopt_deck):
    out = json.loads(
        run_cli(
            "discretize",
            str(lsopt_deck),
            "--param",
            "tbumper=3",
            "--param",
            "thood=1",
            "--axis-map",
            "x=+x,y=+z,z=+y",
            "--json",
        ).stdout
    )
    assert out["n_cells_optimized"] > 0 and out["n_subassemblies"] >= 5
    assert out["cell_mass_kg"] == pytest.approx(out["roi_mass_kg"], rel=5e-3)
