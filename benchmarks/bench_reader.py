"""Keyword reader speed: marlcrash's read_deck against dynakw on one synthetic deck.

Writes a torus-shaped grid deck of N nodes and N 4-node shells (``*NODE``,
``*ELEMENT_SHELL``, one part, section and ``*MAT_ELASTIC``, mm-t-s) into a temporary
folder, times ``read_deck`` and, if importable, ``dynakw`` (the ``dyna`` extra) on it
in the same run, and prints both times and their ratio. Exits 1 if read_deck takes
longer than the limit (15 s by default).

    python benchmarks/bench_reader.py                 # 1,000,000 nodes and shells
    python benchmarks/bench_reader.py --nodes 10000   # quick check
    python benchmarks/bench_reader.py --velocities    # plus a *SET_NODE_LIST and an *INITIAL_VELOCITY_NODE
                                                      # line for every node, as a crash deck's initial state
    python benchmarks/bench_reader.py --masses        # plus an *ELEMENT_MASS of 1 g on every node (checked in
                                                      # the total mass)
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing


def write_grid_deck(path: Path, n_nodes: int, velocities: bool = False, masses: bool = False) -> tuple[int, int]:
    """Write a torus grid deck with about ``n_nodes`` nodes and as many quads; returns the counts.

    ``velocities``: also a node set of every node and an initial velocity (56 km/h along -x) per node.
    ``masses``: also an ``*ELEMENT_MASS`` of 1 g (1e-6 t) on every node.
    """
    nu = max(3, round(math.sqrt(n_nodes)))
    nv = max(3, n_nodes // nu)
    u = np.arange(nu) * (2 * math.pi / nu)
    v = np.arange(nv) * (2 * math.pi / nv)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    big, small = 1500.0, 400.0  # torus radii [mm]
    x = (big + small * np.cos(vv)) * np.cos(uu)
    y = (big + small * np.cos(vv)) * np.sin(uu)
    z = small * np.sin(vv)
    ids = np.arange(1, nu * nv + 1).reshape(nu, nv)
    n1 = ids
    n2 = np.roll(ids, -1, axis=0)
    n3 = np.roll(n2, -1, axis=1)
    n4 = np.roll(ids, -1, axis=1)
    with open(path, "w") as f:
        f.write("*KEYWORD\n*TITLE\nsynthetic torus grid\n")
        f.write("*PART\ngrid\n         1         1         1\n")
        f.write("*SECTION_SHELL\n         1         2\n       1.5       1.5       1.5       1.5\n")
        f.write("*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n")
        f.write("*NODE\n")
        rows = zip(ids.ravel().tolist(), x.ravel().tolist(), y.ravel().tolist(), z.ravel().tolist(), strict=True)
        for chunk in _chunks(rows):
            f.write("".join(f"{i:8d}{a:16.6f}{b:16.6f}{c:16.6f}\n" for i, a, b, c in chunk))
        f.write("*ELEMENT_SHELL\n")
        cols = [c.ravel().tolist() for c in (n1, n2, n3, n4)]
        rows = zip(ids.ravel().tolist(), *cols, strict=True)
        for chunk in _chunks(rows):
            f.write("".join(f"{e:8d}       1{a:8d}{b:8d}{c:8d}{d:8d}\n" for e, a, b, c, d in chunk))
        if velocities:
            flat = ids.ravel().tolist()
            f.write("*SET_NODE_LIST\n         1\n")
            for k in range(0, len(flat), 100_000):
                part = flat[k : k + 100_000]
                f.write("".join("".join(f"{i:10d}" for i in part[j : j + 8]) + "\n" for j in range(0, len(part), 8)))
            f.write("*INITIAL_VELOCITY_NODE\n")
            for chunk in _chunks(iter(flat)):
                f.write("".join(f"{i:10d}  -15640.0\n" for i in chunk))
        if masses:
            f.write("*ELEMENT_MASS\n")
            for chunk in _chunks(iter(ids.ravel().tolist())):
                f.write("".join(f"{i:8d}{i:8d}{1e-6:16.6e}{1:8d}\n" for i in chunk))
        f.write("*END\n")
    return nu * nv, nu * nv


def _chunks(it, size: int = 100_000):
    buf = []
    for r in it:
        buf.append(r)
        if len(buf) == size:
            yield buf
            buf = []
    if buf:
        yield buf


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--nodes", type=int, default=1_000_000, help="number of nodes (and shells) in the deck")
    ap.add_argument("--limit", type=float, default=15.0, help="largest acceptable read_deck time [s]")
    ap.add_argument("--skip-dynakw", action="store_true", help="do not time dynakw")
    ap.add_argument("--velocities", action="store_true", help="add a node set and an initial velocity per node")
    ap.add_argument("--masses", action="store_true", help="add an *ELEMENT_MASS of 1 g on every node")
    args = ap.parse_args(argv)

    from marlcrash.vehicle.keyword import read_deck

    with tempfile.TemporaryDirectory() as tmp:
        deck = Path(tmp) / "grid.k"
        t0 = time.perf_counter()
        n_nodes, n_shells = write_grid_deck(deck, args.nodes, args.velocities, args.masses)
        t_write = time.perf_counter() - t0
        size = deck.stat().st_size / 1e6
        print(f"deck: {n_nodes} nodes, {n_shells} shells, {size:.1f} MB, written in {t_write:.2f} s")

        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = read_deck(deck)
        t_ours = time.perf_counter() - t0
        ok = model.n_nodes == n_nodes and model.n_shells == n_shells and not model.left_out
        ok &= model.point_mass.size == (n_nodes if args.masses else 0)
        ok &= abs(model.total_mass() - sum(model.part_masses().values()) - 1e-3 * model.point_mass.size) < 1e-6
        print(
            f"marlcrash read_deck: {t_ours:.2f} s ({model.n_nodes} nodes, {model.n_shells} shells, "
            f"{model.point_mass.size} point masses, mass {model.total_mass():.1f} kg)"
        )
        if not ok:
            print("ERROR: read_deck returned the wrong counts")
            return 1

        if args.skip_dynakw:
            print("dynakw: skipped (--skip-dynakw)")
        else:
            try:
                from dynakw import DynaKeywordReader
            except ImportError:
                print("dynakw: not importable (pip install marlcrash[dyna]); comparison skipped")
            else:
                t0 = time.perf_counter()
                reader = DynaKeywordReader(str(deck))
                kws = list(reader.keywords())
                t_dyna = time.perf_counter() - t0
                print(f"dynakw DynaKeywordReader: {t_dyna:.2f} s ({len(kws)} keywords)")
                print(f"speed-up of read_deck over dynakw: {t_dyna / t_ours:.1f}x")
        if t_ours > args.limit:
            print(f"FAIL: read_deck took {t_ours:.2f} s > {args.limit:.1f} s")
            return 1
        print(f"OK: read_deck within {args.limit:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
