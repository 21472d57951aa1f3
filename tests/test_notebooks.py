"""The notebooks in notebooks/ run from top to bottom (DESIGN 7: thin layers over tested library code).

Each notebook has one cell tagged ``parameters``; the test appends small values to it (fewer sampled orderings,
an output folder under tmp_path) and executes every cell in a fresh kernel of this interpreter.
"""

from __future__ import annotations

import re
from pathlib import Path

import nbclient  # the dev extra installs nbformat, nbclient and ipykernel
import nbformat
import pytest
from test_analysis import write_evaluated_run

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
SMALL = {"agent_contributions.ipynb": "N_PERMUTATIONS = 4\nRUN = None"}
"""Small settings per notebook, appended to its parameters cell."""


def test_there_are_notebooks_and_each_has_small_settings():
    assert NOTEBOOKS, "notebooks/ holds no notebook"
    assert {p.name for p in NOTEBOOKS} == set(SMALL)


def execute(path: Path, overrides: str) -> nbformat.NotebookNode:
    """Execute a notebook with ``overrides`` appended to its parameters cell; raises on any cell's error."""
    nb = nbformat.read(path, as_version=4)
    params = [c for c in nb.cells if "parameters" in c.get("metadata", {}).get("tags", [])]
    assert len(params) == 1, "expected one cell tagged 'parameters'"
    params[0].source += f"\n# test overrides\n{overrides}\n"
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})  # fmt: skip
    client.execute()  # raises CellExecutionError naming the cell on any error
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    return nb


def _stdout(nb: nbformat.NotebookNode) -> str:
    return "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_executes(path, tmp_path):
    out = tmp_path / "out"
    nb = execute(path, f"{SMALL[path.name]}\nOUT = {str(out)!r}")
    assert "analysing the twin's hidden perturbation" in _stdout(nb)
    written = {p.name for p in (out / "twin_truth").iterdir()}  # a run's analysis goes beside it, never over it
    assert {"contributions.csv", "contributions.md", "contributions.png", "cells.png"} <= written
    head = (out / "twin_truth" / "contributions.md").read_text().split("\n## ")[0]  # what, and with which settings
    assert head.startswith("# Contributions: the twin's hidden perturbation") and "4 orderings" in head, head


def test_agent_contributions_notebook_analyses_a_run(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    write_evaluated_run(run)
    path = next(p for p in NOTEBOOKS if p.name == "agent_contributions.ipynb")
    nb = execute(path, f"N_PERMUTATIONS = 4\nRUN = {str(run)!r}\nOUT = {str(tmp_path / 'out')!r}")
    text = _stdout(nb)
    assert f"analysing the calibration of {run} (its iterate 1)" in text and "largest per-step move" in text
    assert (tmp_path / "out" / f"{tmp_path.name}_run" / "contributions.csv").is_file()
    shown = "".join(o.get("data", {}).get("text/markdown", "") for c in nb.cells if c.cell_type == "code"
                    for o in c.get("outputs", []))  # fmt: skip
    # the run's one step goes from the initial parameters to the truth: straight at it, and there after it
    table = (
        "| step | size | cos previous | cos net | cos truth | distance truth |\n|---|---|---|---|---|---|\n"
        "| 1 | 0.0000 | +nan | +1.00 | +1.00 | 0.000 |"
    )
    assert re.search(re.escape(table).replace("0\\.0000", r"0\.\d{4}") + "$", shown), shown


def test_a_picture_that_cannot_be_written_does_not_lose_the_tables(tmp_path):
    """The contributions' tables are written as soon as they are computed: they were written by the last cell, after
    both pictures, so a picture that could not be written (here: a folder where contributions.png goes) stopped the
    notebook with the minutes of simulations done and no table on disk."""
    out = tmp_path / "out"
    (out / "twin_truth" / "contributions.png").mkdir(parents=True)
    path = next(p for p in NOTEBOOKS if p.name == "agent_contributions.ipynb")
    with pytest.raises(nbclient.exceptions.CellExecutionError, match=r"contributions\.png is a folder"):
        execute(path, f"{SMALL[path.name]}\nOUT = {str(out)!r}")
    written = {p.name for p in (out / "twin_truth").iterdir()}
    assert {"contributions.csv", "contributions.md"} <= written


def test_re_evaluations_of_two_runs_go_to_two_folders(tmp_path):
    """A re-evaluation folder (``<run>/eval/<checkpoint>/``, which the analysis reads with its run's config) is
    analysed into ``OUT/<algorithm>_<run>_eval_<checkpoint>/``: its folder was named by its last two parts only
    (``eval_<checkpoint>``), the same for every run's re-evaluation of that name, so analysing a second run's
    replaced the first one's pictures and tables without a word."""
    run = tmp_path / "mappo" / "run"
    run.mkdir(parents=True)
    write_evaluated_run(run)
    again = run / "eval" / "checkpoint_steps2"
    again.mkdir(parents=True)
    (again / "calibrated.npz").write_bytes((run / "calibrated.npz").read_bytes())
    path = next(p for p in NOTEBOOKS if p.name == "agent_contributions.ipynb")
    execute(path, f"N_PERMUTATIONS = 4\nRUN = {str(again)!r}\nOUT = {str(tmp_path / 'out')!r}")
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["mappo_run_eval_checkpoint_steps2"]


def test_a_runs_changes_are_read_against_its_own_initial_parameters(tmp_path):
    """The table of what the calibration did to each agent's cells read a run's parameters against the initial ones
    of today's problem, not the run's own (``calibrated.npz``'s ``initial``, which the contributions start from):
    with ``configs/`` changed since the run (warned about, and supported), it showed moves the calibration never made.
    Here a run that moved nothing, from initial parameters 5 % stiffer than today's: every change is 0."""
    import numpy as np
    from test_analysis import write_evaluated_run

    run = tmp_path / "run"
    run.mkdir()
    problem = write_evaluated_run(run)
    start = problem.init.clone()
    start[problem.layout.agent_of_cell >= 0, 0] *= 1.05  # E_x of every owned cell
    keep = dict(np.load(run / "calibrated.npz"))
    np.savez(run / "calibrated.npz", **{**keep, "initial": start.numpy(), "calibrated": start.numpy(),
                                         "per_iteration": np.stack([start.numpy()] * 2)})  # fmt: skip
    path = next(p for p in NOTEBOOKS if p.name == "agent_contributions.ipynb")
    nb = execute(path, f"N_PERMUTATIONS = 4\nRUN = {str(run)!r}\nOUT = {str(tmp_path / 'out')!r}")
    shown = [o.get("data", {}).get("text/markdown", "") for c in nb.cells if c.cell_type == "code"
             for o in c.get("outputs", [])]  # fmt: skip
    tables = [t for t in shown if t.startswith("| agent | E_x |")]
    assert len(tables) == 1
    rows = [r.split("|")[2:5] for r in tables[0].splitlines()[2:]]  # E_x, E_s, transmission of the run
    assert len(rows) == problem.n_agents
    assert all(float(x) == 0.0 for r in rows for x in r), tables[0]
