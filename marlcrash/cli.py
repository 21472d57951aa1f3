"""The ``marlcrash`` command line.

Each sub-command is a thin layer over library calls: parse arguments, call the
library, print a table or one JSON object. User errors (bad deck, bad config)
print ``error: ...`` on stderr and exit with status 2, never a traceback. Ctrl-C prints
``interrupted`` and ends the process by SIGINT (``main(argv)`` called from Python raises
KeyboardInterrupt to its caller instead); outputs are written whole or not at all.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

from marlcrash import __version__
from marlcrash.errors import ConfigError, MarlcrashError, end_by_sigint, report_interrupt
from marlcrash.outputs import check_output_file
from marlcrash.units import UNIT_SYSTEM_NAMES

DECK_SUFFIXES = (".k", ".key", ".dyn", ".kw")  # as marlcrash.vehicle.registry's (not imported: startup time)
ACC_UNIT_CHOICES = ("g", "m/s2", "mm/s2", "mm/ms2")  # marlcrash.pulse.io.ACC_UNIT_NAMES (not imported: startup time)


# ----------------------------------------------------------------- helpers
def _parse_params(items: list[str] | None) -> dict[str, float]:
    out: dict[str, float] = {}
    typed: dict[str, str] = {}  # the item that gave each name, as the deck reads it (LS-DYNA's: case-insensitive)
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ConfigError(f"expected NAME=VALUE, got {item!r}", key="--param")
        try:
            number = float(value)
        except ValueError:
            raise ConfigError(f"value of {name.strip()!r} must be a number, got {value!r}", key="--param") from None
        if not math.isfinite(number):  # nan, inf, 1e400: refused here, not at whatever card uses it
            raise ConfigError(f"value of {name.strip()!r} must be a finite number, got {value!r}", key="--param")
        key = name.strip().lower()
        if key in typed and out[key] != number:  # the last one was taken without a word
            raise ConfigError(f"parameter {key!r} given twice, {typed[key]!r} and {item!r}; give it once",
                              key="--param")  # fmt: skip
        typed[key], out[key] = item, number
    return out


def _add_vehicle_args(p: argparse.ArgumentParser, deck_required: bool) -> None:
    p.add_argument(
        "deck",
        nargs=None if deck_required else "?",
        type=_path,
        help="LS-DYNA keyword deck (.k/.key/.dyn), a synthetic-vehicle YAML, or a registered vehicle name"
        + ("" if deck_required else " (default: the embedded synthetic B-segment car)"),
    )
    p.add_argument(
        "--param",
        action="append",
        metavar="NAME=VALUE",
        help="value for a *PARAMETER of the deck: one it uses but does not define, or one overriding its own "
        "(repeatable)",
    )
    p.add_argument("--units", help=f"deck unit system: one of {UNIT_SYSTEM_NAMES} (default: detected)")
    p.add_argument(
        "--axis-map",
        metavar="MAP",
        help="deck axes to marlcrash axes (x rearward, y left, z up), e.g. 'x=+x,y=+z,z=+y'",
    )
    p.add_argument(
        "--subassemblies", type=_input_file, metavar="MAP.yaml", help="YAML file mapping parts to named sub-assemblies"
    )
    p.add_argument(
        "--seed", type=_seed, default=None, help="variant seed of a synthetic vehicle, integer >= 0 (default: nominal)"
    )


def _seed(text: str) -> int:
    """argparse type of ``--seed``: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def _path(text: str) -> str:
    """argparse type of a file or folder argument: not empty. ``""`` (a shell variable left unset) is no path: taken
    as none it chose the default (the embedded car, configs/cells.yaml), taken as ``Path("")`` the working folder."""
    if not text:
        raise argparse.ArgumentTypeError("expected a path, got an empty one")
    return text


def _input_file(text: str) -> str:
    """argparse type of an input file that is no deck (a config, a sub-assembly map): a path (:func:`_path`) to a
    file, so a folder or a missing file is named with its option before any work (a folder said only "<name>: cannot
    read config file (Is a directory)")."""
    path = Path(_path(text))
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder; expected a YAML file")
    if not path.is_file():
        raise argparse.ArgumentTypeError(
            f"no such file {text!r}" if not path.exists() else f"{text} is no regular file"
        )
    return text


def _output_path(text: str) -> str:
    """argparse type of an output file or folder: a path (:func:`_path`), not ``-``: outputs go to the files named,
    never to standard output (it takes the summary), so '-' would be written as a file or folder named '-'."""
    if text == "-":
        raise argparse.ArgumentTypeError("expected a file or folder name, got '-' (outputs are not written to "
                                         "standard output, which takes the summary)")  # fmt: skip
    return _path(text)


def _positive_int(text: str) -> int:
    """argparse type of a count: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def _batch_size(text: str) -> int:
    """argparse type of a benchmark batch size: an integer in ``[1, MAX_BATCH]`` (one batch is simulated at once:
    10**9 ran on into torch's "can't allocate memory")."""
    from marlcrash.calibrate.baselines import require_batch_size

    value = _positive_int(text)
    try:
        require_batch_size(value, "batch_sizes")
    except ConfigError as e:
        raise argparse.ArgumentTypeError(e.reason) from None
    return value


def load_model_from_args(args: argparse.Namespace):
    """Load the vehicle named by CLI arguments (deck path, YAML, registered name or default)."""
    from marlcrash.vehicle.model import AxisMap

    target = args.deck
    is_deck = target is not None and Path(target).suffix.lower() in DECK_SUFFIXES
    if is_deck:
        from marlcrash.vehicle.keyword import read_deck

        if args.seed is not None:  # a deck is one vehicle: the seed would be ignored without a word
            raise ConfigError(
                f"{args.seed} given for the deck {Path(target).name}; only synthetic cars have variants", key="--seed"
            )

        if args.units is not None:  # before the deck is read, said as the option the user typed
            from marlcrash.units import get_unit_system

            try:
                get_unit_system(args.units)
            except ConfigError as e:
                raise ConfigError(e.reason, key="--units") from None
        try:
            axis_map = AxisMap.parse(args.axis_map) if args.axis_map is not None else None  # "" is refused
        except ConfigError as e:  # said as the option the user typed, not the library's argument
            axis = (e.key or "").removeprefix("axis_map").removeprefix(".")  # the marlcrash axis, where one is meant
            raise ConfigError(f"{axis}: {e.reason}" if axis else e.reason, key="--axis-map") from None
        return read_deck(
            target,
            params=_parse_params(args.param),
            units=args.units,
            axis_map=axis_map,
            subassemblies=args.subassemblies,
        )
    for flag in ("param", "units", "axis_map"):
        if getattr(args, flag) is not None:  # given, if empty: `--axis-map ""` too
            raise ConfigError(f"--{flag.replace('_', '-')} only applies to keyword decks ({', '.join(DECK_SUFFIXES)})")
    from marlcrash.vehicle.registry import VehicleOptions, load_configured_vehicle

    return load_configured_vehicle(target or "b_segment", args.seed, VehicleOptions(subassemblies=args.subassemblies))


def _input_files(args: argparse.Namespace) -> tuple[str, ...]:
    """The files a command reads (deck or vehicle YAML, configs, sub-assembly map): outputs must not replace them."""
    names = (getattr(args, k, None) for k in ("deck", "config", "subassemblies"))
    return tuple(str(n) for n in names if n is not None and Path(n).is_file())


def _print_json(obj: dict) -> None:
    """Print ``obj`` as standard JSON: non-finite floats become ``null``, as ``time_to_zero_velocity_ms`` of a car
    that never stops (:func:`marlcrash.outputs.json_text`)."""
    from marlcrash.outputs import json_text

    print(json_text(obj))


# ---------------------------------------------------------------- commands
def cmd_inspect(args: argparse.Namespace) -> int:
    from marlcrash.vehicle.summary import format_vehicle_summary, vehicle_summary

    summary = vehicle_summary(load_model_from_args(args))
    if args.json:
        _print_json(summary)
    else:
        print(format_vehicle_summary(summary))
    return 0


def cmd_discretize(args: argparse.Namespace) -> int:
    from marlcrash.cells import discretization_summary, format_discretization_summary, load_discretization_config
    from marlcrash.provenance import output_record

    inputs = _input_files(args)
    check_output_file(args.save, "--save", suffix=".npz", inputs=inputs)  # before the work
    check_output_file(args.plot, "--plot", suffix=".png", inputs=(*inputs, args.save))
    model = load_model_from_args(args)
    config = load_discretization_config(args.config)
    summary, cells = discretization_summary(model, config, method=args.method)
    origin = output_record(inputs, getattr(args, "argv", None))
    if args.save:
        cells.meta["provenance"] = origin  # CellModel.load gives it back
        cells.save(args.save)
    if args.plot:
        from marlcrash.cells.plot import plot_cells

        plot_cells(cells, args.plot)
    if args.json:  # with the files written, as simulate's
        files = {k: str(v) for k, v in (("save", args.save), ("plot", args.plot)) if v}
        _print_json({**summary, **files, "provenance": origin})
    else:
        print(format_discretization_summary(summary))
        if args.save:
            print(f"\ncell model written to {args.save}")
        if args.plot:
            print(f"plot written to {args.plot}")
    return 0


def scenario_from_args(args: argparse.Namespace):
    """The crash scenario named by ``--scenario`` with ``--speed/--overlap/--side`` overrides.

    ``--duration`` [ms] (where the command has it) lengthens or shortens the record and keeps the scenario's
    name: the load case is the same, e.g. a test record that goes on past the compared window.
    """
    from dataclasses import replace

    from marlcrash.sim.scenario import get_scenario, list_scenarios

    try:
        scenario = get_scenario("full_width_40" if args.scenario is None else args.scenario)
    except ConfigError as e:  # an unknown name said as the option the user typed, as --speed's are
        if e.key != "scenario" or args.scenario is None:  # not the default's: the user typed no --scenario
            raise
        raise ConfigError(e.reason, key="--scenario") from None
    ms = getattr(args, "duration", None)
    if ms is not None:
        try:
            scenario = replace(scenario, duration=ms * 1e-3)
            scenario.validate()
        except ConfigError as e:  # the scenario's key in seconds, said as the option the user typed
            raise ConfigError(f"{ms:g} ms: {e.reason}", key="--duration") from None
    overrides = {
        key: value
        for key, value in (("speed_kmh", args.speed), ("overlap", args.overlap), ("side", args.side))
        if value is not None
    }
    if not overrides:
        return scenario
    registered, scenario = scenario, replace(scenario, **overrides)
    try:
        scenario.validate()
    except ConfigError as e:  # said as the option the user typed, not the scenario file's key
        option = {"speed_kmh": "speed", "overlap": "overlap", "side": "side"}.get(e.key or "")
        if option is None or getattr(args, option) is None:
            raise
        raise ConfigError(e.reason, key=f"--{option}") from None
    if scenario != registered:  # overrides that repeat the scenario's values (--speed 56 on full_width_56) keep it
        # named after what it is, not after the registered scenario it started from (an offset is no "full_width_40")
        shape = "full_width" if scenario.overlap >= 1.0 else f"overlap{scenario.overlap:g}_{scenario.side}"
        scenario = replace(scenario, name=f"custom_{scenario.speed_kmh:g}kmh_{shape}",
                           description=f"command-line overrides of {scenario.name}")  # fmt: skip
    if args.side is not None and scenario.overlap >= 1.0:
        warnings.warn(f"--side {args.side} has no effect: the barrier covers the full width (overlap 1)", stacklevel=2)
    # the registered scenarios' speeds are those the default car's pulses are checked at (tests/test_sim_*)
    speeds = [get_scenario(name).speed_kmh for name in list_scenarios()]
    lo, hi = min(speeds), max(speeds)
    if not lo <= scenario.speed_kmh <= hi:
        warnings.warn(
            f"{scenario.speed_kmh:g} km/h lies outside the impact speeds the surrogate's plausibility is checked at "
            f"({lo:g}-{hi:g} km/h, the registered scenarios); read its pulse with care",
            stacklevel=2,
        )
    return scenario


def cmd_simulate(args: argparse.Namespace) -> int:
    import dataclasses

    import torch

    from marlcrash.cells import discretize, load_discretization_config
    from marlcrash.outputs import json_text, write_text
    from marlcrash.provenance import check_record_path, output_record, record_path
    from marlcrash.pulse.simulation import (
        bottoming_note,
        crash_summary,
        energy_budget,
        plot_crash,
        short_record,
        write_crash_csv,
    )
    from marlcrash.sim import Surrogate

    scenario = scenario_from_args(args)
    why = short_record(scenario.duration, 60)  # the figures are CFC 60's: before the work
    if why is not None and args.duration is not None:
        raise ConfigError(f"{args.duration:g} ms: {why}", key="--duration")
    inputs = _input_files(args)
    # before the work: a typo in an output path costs nothing; .csv, the name marlcrash pulse reads it back by
    check_output_file(args.csv, "--csv", suffix=".csv", inputs=inputs)
    csv_record = None if args.csv is None else record_path(args.csv)  # what made the CSV, beside it
    check_output_file(csv_record, "--csv", suffix=".json", inputs=inputs)
    if args.csv is not None:  # a file there must be such a record: the user did not name it
        check_record_path(args.csv, "--csv")
    check_output_file(args.plot, "--plot", suffix=".png", inputs=(*inputs, args.csv, csv_record))
    model = load_model_from_args(args)
    cells = discretize(model, load_discretization_config(args.config), method=args.method)
    sim = Surrogate(cells, output_dt=scenario.output_dt)
    params = torch.as_tensor(cells.params)[None]
    result = sim.run(params, scenario, record_cells="series" if args.plot else "final")
    summary = crash_summary(result, cells, scenario)
    summary.update(energy_budget(cells, scenario))
    origin = output_record(inputs, getattr(args, "argv", None))
    if csv_record is not None:  # exactly when --csv is given
        write_crash_csv(result, args.csv)
        summary["csv"] = str(args.csv)
        what = {"csv": str(args.csv), "vehicle": cells.name, "n_cells": cells.n_cells, "method": cells.method,
                "scenario": dataclasses.asdict(scenario), "params": "the cell model's own"}  # fmt: skip
        write_text(csv_record, json_text({**what, "provenance": origin}))
        summary["provenance_file"] = str(csv_record)
    if args.plot:
        plot_crash(result, cells, args.plot, title=f"{cells.name}: {scenario.name}")
        summary["plot"] = str(args.plot)
    if args.json:
        _print_json({**summary, "provenance": origin})
        return 0
    t0v = summary["time_to_zero_velocity_ms"]
    print(
        f"vehicle {cells.name} ({cells.n_cells} cells), scenario {scenario.name}: {scenario.speed_kmh:g} km/h, "
        f"overlap {scenario.overlap:g} ({scenario.side})"
    )
    print(f"peak compartment deceleration  {summary['peak_decel_g']:8.1f} g (CFC60) at {summary['t_peak_ms']:.1f} ms")
    print(f"time to zero velocity          {'never' if t0v is None else f'{t0v:8.1f} ms'}")
    print(f"maximum dynamic crush          {summary['max_crush_m']:8.3f} m")
    print(
        f"rebound velocity               {summary['rebound_velocity_ms']:8.2f} m/s "
        f"({100 * summary['rebound_fraction']:.1f} % of impact speed)"
    )
    print(f"energy balance, max rel. error {summary['energy_balance_max_rel_error']:8.1e}")
    print(
        f"impact energy / crush capacity {summary['impact_energy_kj']:8.1f} / {summary['crush_capacity_kj']:.1f} kJ"
        " (plastic work the cells can take)"
    )
    note = bottoming_note(summary)
    if note:
        print(note)
    for name, d in summary["sensors"].items():
        print(
            f"  sensor {name:<16} peak {d['peak_g']:7.1f} g at {d['t_peak_ms']:6.1f} ms, "
            f"delta-v {d['delta_v_ms']:6.2f} m/s"
        )
    for key, label in (("csv", "csv"), ("provenance_file", "provenance"), ("plot", "plot")):
        if key in summary:
            print(f"{label} written to {summary[key]}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from marlcrash.sim.bench import format_benchmark, run_benchmark

    result = run_benchmark(
        batch_sizes=tuple(args.batch_sizes),
        include_uniform=not args.skip_uniform,
        sim_overrides={"dtype": args.dtype},
    )
    if args.json:
        _print_json(result)
    else:
        print(format_benchmark(result))
    return 0


def cmd_pulse(args: argparse.Namespace) -> int:
    from marlcrash.pulse.io import plot_pulse, processed_pulse, pulse_figures
    from marlcrash.pulse.signal import shift_time

    opts = {
        "time_col": args.time_col,
        "acc_col": args.acc_col,
        "unit": args.unit,
        "time_unit": args.time_unit,
        "cfc": None if args.cfc == 0 else args.cfc,
        "sign": -1.0 if args.deceleration_positive else 1.0,
        "time_zero": args.time_zero,
        "breakpoints": args.breakpoints,
    }
    check_output_file(args.plot, "--plot", suffix=".png", inputs=(args.file,))
    raw, work, t0 = processed_pulse(args.file, **opts)
    summary = pulse_figures(raw, work, t0, path=args.file)
    if args.plot:  # the pulse the figures describe: resampled if non-uniform, filtered, t = 0 at time zero
        plot_pulse(shift_time(work, t0), args.plot, title=Path(args.file).name)
        summary["plot"] = str(args.plot)
    if args.cfc:
        from marlcrash.pulse.cfc import f_n

        settle = 2.0 / f_n(args.cfc)  # two periods of the -3 dB frequency: 20 ms for CFC 60
        after = work.time[-1] - t0
        if after < settle:
            print(
                f"note: the record ends {after * 1e3:.1f} ms after time zero, less than the {settle * 1e3:.0f} ms the "
                f"CFC {args.cfc} filter spreads a pulse over; its peak and delta-v are unreliable (record longer, or "
                "--cfc 0 for unfiltered figures)",
                file=sys.stderr,
            )
    if summary["delta_v_150ms_ms"] is None and args.time_zero == "file":  # the option the note below names
        print("note: delta_v_150ms_ms is null: the record ends less than 150 ms after time zero (the file's t = 0)",
              file=sys.stderr)  # fmt: skip
    elif summary["delta_v_150ms_ms"] is None:
        print(
            f"note: delta_v_150ms_ms is null: the record ends less than 150 ms after time zero "
            f"(t0 = {summary['t0_ms']:.2f} ms on the file's clock); if the file's t = 0 is the impact "
            "(e.g. a `marlcrash simulate --csv` record), use --time-zero file",
            file=sys.stderr,
        )
    if args.json:
        _print_json(summary)
    else:
        width = max(len(k) for k in summary)
        for k, v in summary.items():
            print(f"{k:<{width}}  {v:.4g}" if isinstance(v, float) else f"{k:<{width}}  {v}")
    return 0


_CONTRIBUTION_FILES = ("contributions.csv", "contributions.md", "contributions.png", "cells.png")
"""What ``marlcrash contributions`` writes into its folder (an earlier analysis there is refused or replaced whole)."""
_CONTRIBUTION_LOCK = ".contributions.lock"
"""The lock file in that folder while an analysis computes and writes it (not a run's own ``.lock``: ``--out`` may
name a run folder)."""


def cmd_contributions(args: argparse.Namespace) -> int:
    from marlcrash.analysis import agent_contributions, plot_cells_by_contribution, plot_contributions, run_calibration
    from marlcrash.analysis.contributions import require_run_folder
    from marlcrash.analysis.shapley import MAX_EXACT_PLAYERS
    from marlcrash.calibrate.runlock import hold_output_dir
    from marlcrash.outputs import check_output_dir

    if args.run is not None:
        require_run_folder(args.run)  # before --out's check, which names a path inside it
    if args.out is not None or args.run is None:
        out = Path(args.out or "contributions")
    else:
        out = Path(args.run) / "contributions"  # + iteration_<n>/ once the run says which step is analysed
    check_output_dir(out, "--out")  # before the simulations: a bad output path costs nothing
    if args.exact_max > MAX_EXACT_PLAYERS:
        raise ConfigError(f"expected 0 to {MAX_EXACT_PLAYERS} agents, got {args.exact_max}", key="--exact-max")
    if args.permutations < 4 or args.permutations % 2:
        raise ConfigError(f"expected an even number >= 4 (antithetic pairs), got {args.permutations}",
                          key="--permutations")  # fmt: skip
    if args.run is None:  # the twin's hidden perturbation: every agent at the truth (what a calibration must find)
        from marlcrash.calibrate.problem import ProblemConfig, build_problem

        if args.iteration is not None:
            raise ConfigError("--iteration needs a RUN (the twin's truth has no iterations)", key="--iteration")
        problem = build_problem(ProblemConfig(scenario="full_width_40", reference="twin", reference_seed=0))
        assert problem.true_params is not None  # a twin reference always carries its hidden truth
        initial, calibrated, iteration = problem.init, problem.true_params, None
        what = "twin truth (full_width_40, reference seed 0)"
    else:
        run = run_calibration(args.run)
        problem, initial = run.problem, run.initial
        iteration = run.selected_iteration if args.iteration is None else args.iteration
        last = run.per_iteration.shape[0] - 1
        if not 0 <= iteration <= last:
            raise ConfigError(f"expected a calibration step 0 to {last} of {args.run}, got {iteration}",
                              key="--iteration")  # fmt: skip
        calibrated = run.per_iteration[iteration]
        what = f"{args.run}, calibration step {iteration}"
        if args.out is None:  # one folder per step: analysing another step never replaces this one's files
            out = out / f"iteration_{iteration}"
    # one analysis per folder at once: another that started earlier and writes later would replace this one's files
    with hold_output_dir(out, "--out", _CONTRIBUTION_LOCK, _CONTRIBUTION_FILES):
        ours = [out / n for n in _CONTRIBUTION_FILES]
        earlier = [p.name for p in ours if p.exists()]
        if earlier and not args.replace:  # checked before the simulations; the tables do not say their settings
            raise ConfigError(f"{out} holds an earlier analysis ({', '.join(earlier)}); --replace to write over it, or "
                              "--out another folder", key="--out")  # fmt: skip
        try:
            contrib = agent_contributions(problem, calibrated, initial, exact_max=args.exact_max,
                                          n_permutations=args.permutations, seed=args.seed)  # fmt: skip
        except ValueError as e:  # parameters that do not fit the problem (another vehicle or layout) or simulate to NaN
            raise ConfigError(f"{what}: {e}", key="run") from None
        for p in ours:  # --replace: none of the earlier analysis stays beside this one (its pictures with --no-plots)
            p.unlink(missing_ok=True)
        areas = [q for q in contrib.quantities if q.startswith("area/")]
        table, text, bars, cells = ours  # the tables' heading lists the settings (Contributions.settings_lines)
        files = [contrib.write_csv(table), contrib.write_markdown(text, heading=f"Contributions: {what}")]
        if not args.no_plots:
            worst = max(areas, key=lambda q: float(contrib.initial[contrib.column(q)]))
            files += [plot_contributions(contrib, bars),
                      plot_cells_by_contribution(problem, contrib, cells, quantity=worst)]  # fmt: skip
        if args.json:
            quantities = {}
            for q in contrib.quantities:
                j = contrib.column(q)
                ranked = contrib.ranking(q)
                rows = [(a, contrib.agents.index(a)) for a, _ in ranked]
                quantities[q] = {
                    "initial": float(contrib.initial[j]),
                    "calibrated": float(contrib.calibrated[j]),
                    "shapley": dict(ranked),
                    "shapley_stderr": {a: float(contrib.shapley_stderr[i, j]) for a, i in rows},
                    "leave_one_out": {a: float(contrib.leave_one_out[i, j]) for a, i in rows},
                    "add_one": {a: float(contrib.add_one[i, j]) for a, i in rows},
                }
            _print_json({"analysed": what, "iteration": iteration, "provenance": None if args.run is None else
                         run.provenance, "agents_moved": int(contrib.players.sum()),
                         "n_agents": len(contrib.agents), "exact": contrib.exact, "simulations": contrib.n_simulations,
                         "settings": contrib.settings, "quantities": quantities,
                         "files": [str(f) for f in files]})  # fmt: skip
            return 0
        print(f"{what}: {int(contrib.players.sum())} of {len(contrib.agents)} agents moved; {contrib.n_simulations} "
              f"simulations; Shapley values {'exact' if contrib.exact else 'sampled'}\n")  # fmt: skip
        for q in ["score", *areas]:
            print(contrib.markdown(q))
        print("written: " + ", ".join(str(f) for f in files))
        return 0


# ------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="marlcrash",
        description="Cell surrogates of vehicle frontal crash structures, calibrated with multi-agent RL.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("inspect", help="summarise an FE deck: nodes, elements, parts, masses, sub-assemblies")
    _add_vehicle_args(p, deck_required=True)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("discretize", help="discretize a vehicle front into cells (paper Table 2)")
    _add_vehicle_args(p, deck_required=False)
    p.add_argument("--method", choices=["uniform", "optimized"], help="discretization method (default: config)")
    p.add_argument(
        "--config",
        type=_input_file,
        help="cells config YAML giving every key of configs/cells.yaml (default: that file)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument(
        "--plot", type=_output_path, metavar="FILE.png", help="write a 3D picture of the cells coloured by sub-assembly"
    )
    p.add_argument("--save", type=_output_path, metavar="CELLS.npz", help="write the cell model")
    p.set_defaults(func=cmd_discretize)

    p = sub.add_parser("simulate", help="simulate a frontal crash of a vehicle's cell surrogate")
    _add_vehicle_args(p, deck_required=False)
    p.add_argument("--scenario", help="registered crash scenario (configs/scenarios; default full_width_40)")
    p.add_argument("--speed", type=float, metavar="KMH", help="impact speed [km/h] (overrides the scenario's)")
    p.add_argument(
        "--overlap",
        type=float,
        metavar="F",
        help="barrier overlap as a fraction of vehicle width (default: the scenario's)",
    )
    p.add_argument(
        "--side", choices=["left", "right"], help="struck side for partial overlaps (default: the scenario's)"
    )
    p.add_argument("--duration", type=float, metavar="MS",
                   help="simulated time after first contact [ms] (default: the scenario's, 150; at least 10, the "
                        "figures are CFC 60's); e.g. 200 for a test record that goes on past the compared window, as "
                        "a lab's does")  # fmt: skip
    p.add_argument("--method", choices=["uniform", "optimized"], help="discretization method (default: config)")
    p.add_argument(
        "--config",
        type=_input_file,
        help="cells config YAML giving every key of configs/cells.yaml (default: that file)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--csv",
        type=_output_path,
        metavar="FILE.csv",
        help="write time [s], per-sensor acceleration [g, unfiltered: "
        "the JSON's peaks are CFC 60; marlcrash pulse FILE.csv filters it] and velocity [m/s], crush [m]",
    )
    p.add_argument(
        "--plot", type=_output_path, metavar="FILE.png", help="plot pulses per sensor and energy per sub-assembly"
    )
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("bench", help="simulations per second of the default car's surrogate, with a roofline")
    p.add_argument(
        "--batch-sizes",
        type=_batch_size,
        nargs="+",
        default=[1, 64, 1024],
        metavar="B",
        help="batch sizes (default 1 64 1024)",
    )
    p.add_argument("--skip-uniform", action="store_true", help="skip the uniform-discretization model at B = 64")
    p.add_argument(
        "--dtype",
        choices=["float64", "float32"],
        default="float64",
        help="precision of the simulations (configs/sim.yaml key dtype; default float64)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("pulse", help="read a measured crash pulse (CSV or ISO-MME), CFC-filter and integrate it")
    p.add_argument("file", type=_path, help="CSV file with a header row, an ISO-MME .mme file or test folder")
    p.add_argument("--time-col", help="CSV time column; default: the first column named like time, else the first")
    p.add_argument("--time-unit", choices=["s", "ms"], default="s", help="CSV time unit (default s)")
    p.add_argument("--acc-col", help="acceleration column / ISO-MME channel; default: the first acceleration")
    p.add_argument("--unit", choices=ACC_UNIT_CHOICES, default="g",
                   help="CSV acceleration unit (default g; mm/ms2: an LS-DYNA run in mm-ms-kg or mm-g-ms)")  # fmt: skip
    p.add_argument(
        "--cfc", type=int, default=60, choices=[0, 60, 180, 600, 1000], help="CFC class, 0 for none (default 60)"
    )
    p.add_argument(
        "--breakpoints",
        action="store_true",
        help="the CSV rows are the corners of a piecewise linear pulse (e.g. a trapezoid), not samples: "
        "sampled at 10 kHz between them, no gap warning",
    )
    p.add_argument(
        "--time-zero",
        choices=["threshold", "file"],
        default="threshold",
        help="time zero: the pulse's onset (default; detected against 0.5 g or 5x the pre-trigger noise, zero level "
        "from the samples before it) or the file's t = 0",
    )
    p.add_argument(
        "--deceleration-positive",
        action="store_true",
        help="the file records deceleration as positive (default: SAE J211 sign, a frontal pulse is negative)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", type=_output_path, metavar="FILE.png", help="write acceleration and velocity plots")
    p.set_defaults(func=cmd_pulse)

    p = sub.add_parser(
        "contributions",
        help="per-agent contributions (Shapley, leave-one-out, add-one) to a run's calibration of every metric",
    )
    p.add_argument(
        "run",
        nargs="?",
        type=_path,
        help="an evaluated training run folder (runs/<algorithm>/<name>, with calibrated.npz); default: the twin's "
        "hidden perturbation of the main job's evaluation reference (every agent at the truth)",
    )
    p.add_argument(
        "--iteration", type=_seed, metavar="N", help="calibration step to analyse (default: the evaluation's selected)"
    )
    p.add_argument("--exact-max", type=_seed, default=10, metavar="N",
                   help="enumerate all coalitions when at most N agents moved (default 10)")  # fmt: skip
    p.add_argument("--permutations", type=_positive_int, default=64, metavar="N",
                   help="sampled orderings otherwise (even, >= 4; default 64)")  # fmt: skip
    p.add_argument("--seed", type=_seed, default=0, help="seed of the sampled orderings (default 0)")
    p.add_argument("--out", type=_output_path, metavar="DIR",
                   help="output folder (default: RUN/contributions/iteration_<n>, or ./contributions)")  # fmt: skip
    p.add_argument("--no-plots", action="store_true", help="write the tables only")
    p.add_argument("--replace", action="store_true", help="write over an earlier analysis in the output folder")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_contributions)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``marlcrash`` console script (``argv`` ``None``: ``sys.argv``; given, as by a notebook or
    a test, an interrupt is raised to the caller instead of ending the process)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # what made a command's outputs (their provenance)
    # Warnings (skipped cards, defaulted material values) are messages for the user, not
    # for a developer: print them without the source line that raised them.
    warnings.formatwarning = lambda message, category, *a, **k: f"warning: {message}\n"
    # A file name the system could not decode (latin-1 bytes under UTF-8) is printed back as the bytes given, as `ls`
    # does: a strict standard output stopped at it with a traceback, after the work. The command's own process only:
    # a caller's (a notebook's) standard output is its own.
    if argv is None and getattr(sys.stdout, "errors", None) == "strict" and hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(errors="surrogateescape")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt as e:  # Ctrl-C: no traceback from wherever the work was; outputs are written whole or not
        report_interrupt(e)
        if argv is not None:  # called by Python code (a notebook, a test): the interrupt is the caller's to handle
            raise
        end_by_sigint()
        return 130  # where a process cannot end by a signal
    except BrokenPipeError:  # e.g. `marlcrash ... | head`
        sys.stderr.close()
        return 0
    except MarlcrashError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except FileNotFoundError as e:
        print(f"error: {e.filename}: no such file", file=sys.stderr)
        return 2
    except OSError as e:  # a folder where a file was expected, no permission, disk full: say which path
        print(f"error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
