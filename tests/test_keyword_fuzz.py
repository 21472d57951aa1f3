"""Fuzzing the reader: random and mutated decks either load or raise DeckError, nothing else."""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from marlcrash.errors import DeckError
from marlcrash.vehicle.keyword import read_deck
from marlcrash.vehicle.model import VehicleModel

FUZZ_EXAMPLES = int(os.environ.get("MARLCRASH_FUZZ_EXAMPLES", "250"))  # raise for a deeper search
BASE = """*KEYWORD
*PARAMETER
R tpar         1.5
*PART
plate
         1         1         1
*SECTION_SHELL_TITLE
sec
         1         2
     &tpar       2.0
*PART
solid
         2         2         2
*SECTION_SOLID
         2         1
*PART
beam
         3         3         1
*SECTION_BEAM
         3         1       1.0       2.0       1.0
      20.0      20.0      10.0      10.0
*MAT_PIECEWISE_LINEAR_PLASTICITY
         1  7.85e-09  210000.0       0.3     250.0       0.0      0.25
       0.0       0.0         0
       0.0       0.1
     250.0     350.0
*MAT_RIGID
         2  7.85e-09  210000.0       0.3
*SET_PART_LIST
        10
         1         2
*NODE
       1
       2            10.0
       3            10.0            10.0
       4                            10.0
5,0,0,10
6,10,0,10
7,10,10,10
8,0,10,10
*ELEMENT_SHELL_THICKNESS
       1       1       1       2       3       4
             1.0             1.0             1.0             1.0
*ELEMENT_SOLID
       2       2       1       2       3       4       5       6       7       8
*ELEMENT_BEAM
       3       3       1       7
*CONTROL_TERMINATION
      0.05
*END
"""
BASE_LINES = BASE.splitlines()
TOKENS = [
    "99999999999999999999",
    "*NODE",
    "*ELEMENT_SHELL",
    "*PART",
    "*MAT_ELASTIC",
    "*INCLUDE",
    "*PARAMETER",
    "&tpar",
    "-&nope",
    "nan",
    "inf",
    "1e999",
    ",",
    "$",
    "*",
    "+",
    "%",
    "       0",
    "99999999",
    "-1",
    "1.5D+02",
    "\t",
    "\x00",
    "é",
    "*END",
    "*KEYWORD LONG=Y",
    "*SECTION_BEAM",
    "*ELEMENT_SOLID",
    "*ELEMENT_BEAM_THICKNESS",
]

line_text = st.one_of(
    st.text(alphabet=st.characters(min_codepoint=9, max_codepoint=255), max_size=90),
    st.lists(st.sampled_from(TOKENS), max_size=6).map("".join),
    st.lists(st.sampled_from(TOKENS) | st.integers(-5, 10**9).map(str), max_size=10).map(" ".join),
)


@st.composite
def mutated_deck(draw) -> str:
    lines = list(BASE_LINES)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["replace", "insert", "delete", "char", "truncate", "swap"]))
        i = draw(st.integers(0, len(lines) - 1)) if lines else 0
        if not lines:
            lines.append(draw(line_text))
        elif op == "replace":
            lines[i] = draw(line_text)
        elif op == "insert":
            lines.insert(i, draw(line_text))
        elif op == "delete":
            del lines[i]
        elif op == "char" and lines[i]:
            j = draw(st.integers(0, len(lines[i]) - 1))
            c = draw(st.characters(min_codepoint=9, max_codepoint=255))
            lines[i] = lines[i][:j] + c + lines[i][j + 1 :]
        elif op == "truncate":
            lines[i] = lines[i][: draw(st.integers(0, max(0, len(lines[i]))))]
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
    return "\n".join(lines) + draw(st.sampled_from(["\n", "", "\r\n"]))


def _check(text: str, **kw) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "fuzz.k"
        p.write_bytes(text.encode("latin-1", errors="replace"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                m = read_deck(p, **kw)
            except DeckError as e:
                assert "fuzz.k" in str(e)  # every deck error names the file
                return
        assert isinstance(m, VehicleModel)
        m.validate()


def test_base_deck_loads(tmp_path):
    p = tmp_path / "base.k"
    p.write_text(BASE)
    with pytest.warns(UserWarning, match=r"skipped 1 card\(s\).*CONTROL_TERMINATION"):
        m = read_deck(p)
    assert (m.n_nodes, m.n_shells, m.n_solids, m.n_beams) == (8, 1, 1, 1)


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_deck())
def test_mutated_decks_only_raise_deck_error(text):
    _check(text)


@settings(max_examples=FUZZ_EXAMPLES // 2, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(line_text, max_size=30).map("\n".join))
def test_random_decks_only_raise_deck_error(text):
    _check("*KEYWORD\n" + text, units="mm-t-s")
