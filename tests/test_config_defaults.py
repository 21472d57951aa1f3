"""A schema made in Python holds the shipped files' values.

Values live in the YAML files under ``configs/``, and every loader refuses a file that leaves a key out. A schema
made in Python (``EnvConfig()``, ``AlgorithmConfig()`` in a notebook) must still simulate and train what the tools
do: defaults that had drifted from the files gave a 0.4 crush efficiency against the shipped 0.22, one scenario
against five, reward scales 2.5-4x off and other PPO hyperparameters, silently.
"""

from __future__ import annotations

from dataclasses import asdict, fields, is_dataclass

import pytest
from test_train_config import composed

from marlcrash.calibrate.ablate import AblationConfig, load_ablation_config
from marlcrash.calibrate.amortized import AmortizedConfig, load_amortized_config
from marlcrash.calibrate.baselines import BaselineRunConfig, load_run_config
from marlcrash.calibrate.compare import CompareConfig, load_compare_config
from marlcrash.calibrate.evaluate import EvaluateRunConfig
from marlcrash.calibrate.marl import AlgorithmConfig, TrainConfig, load_algorithm_config, load_train_config
from marlcrash.cells.discretize import DiscretizationConfig, load_discretization_config
from marlcrash.config import config_dir, from_dict, load_yaml
from marlcrash.envs.core import EnvConfig, load_env_config
from marlcrash.reward import LogRatioParams, PaperFactorParams, RewardConfig, WeightedSumParams, load_reward_config
from marlcrash.sim import SimConfig
from marlcrash.sim.surrogate import load_sim_config


def _params(name: str, cls: type):
    return lambda: from_dict(cls, load_yaml(config_dir() / "reward" / f"{name}.yaml")["params"])


def _entry(name: str, load):
    return lambda: load(composed(name=name))


# (schema made in Python, the shipped file loaded as the tools load it, keys that cannot be equal)
CASES = {
    "sim.yaml": (SimConfig, lambda: load_sim_config(config_dir() / "sim.yaml"), ()),
    "cells.yaml": (DiscretizationConfig, load_discretization_config, ()),
    "env/default.yaml": (EnvConfig, load_env_config, ()),
    "reward/paper_factor.yaml": (RewardConfig, lambda: load_reward_config("paper_factor"), ()),
    "reward/log_ratio.yaml params": (LogRatioParams, _params("log_ratio", LogRatioParams), ()),
    "reward/neg_weighted_sum.yaml params": (WeightedSumParams, _params("neg_weighted_sum", WeightedSumParams), ()),
    "reward/paper_factor.yaml params": (PaperFactorParams, _params("paper_factor", PaperFactorParams), ()),
    "train/algorithm/mappo.yaml": (AlgorithmConfig, lambda: load_algorithm_config("mappo"), ()),
    # a run's name is a time stamp; the ci block applies only under MARLCRASH_CI, to the files
    "train/train.yaml": (TrainConfig, lambda: load_train_config(composed(), ci=False), ("name", "ci")),
    "train/compare.yaml": (CompareConfig, _entry("compare", load_compare_config), ("name",)),
    "train/ablate.yaml": (AblationConfig, _entry("ablate", load_ablation_config), ("name",)),
    "train/amortized.yaml": (AmortizedConfig, _entry("amortized", load_amortized_config), ()),
    "train/baseline.yaml": (BaselineRunConfig, _entry("baseline", load_run_config), ("name",)),
    # its run folder is given on the command line (validate() refuses none): the file's keys, not loaded
    "train/evaluate.yaml": (EvaluateRunConfig, lambda: EvaluateRunConfig(**composed(name="evaluate")), ()),
}


def differences(made: object, shipped: object, path: str = "") -> list[str]:
    """Dotted keys whose values differ, each with both values."""
    if isinstance(made, dict) and isinstance(shipped, dict):
        out = []
        for k in sorted(set(made) | set(shipped), key=str):
            if k not in made or k not in shipped:
                out.append(f"{path}{k}: only in {'the file' if k in shipped else 'the schema'}")
            else:
                out += differences(made[k], shipped[k], f"{path}{k}.")
        return out
    if isinstance(made, list | tuple) and isinstance(shipped, list | tuple):
        made, shipped = list(made), list(shipped)
    return [] if made == shipped else [f"{path[:-1]}: schema {made!r}, file {shipped!r}"]


@pytest.mark.parametrize("file", list(CASES))
def test_a_schema_made_in_python_holds_the_shipped_values(file):
    cls, load, skip = CASES[file]
    made, got = asdict(cls()), asdict(load())
    for k in skip:
        made.pop(k), got.pop(k)
    assert differences(made, got) == [], f"{cls.__name__}() differs from configs/{file}"
    one, two = cls(), cls()  # both alive, so no id is reused
    assert not set(_containers(one)) & set(_containers(two)), f"two {cls.__name__}() share a list or dict"


def _containers(obj: object):
    """Ids of the lists and dicts reachable from ``obj`` through dataclass fields, dicts and lists."""
    if is_dataclass(obj):
        for f in fields(obj):
            yield from _containers(getattr(obj, f.name))
    elif isinstance(obj, list | dict):
        yield id(obj)
        for v in obj.values() if isinstance(obj, dict) else obj:
            yield from _containers(v)


def test_the_comparison_finds_a_difference():
    """The check itself: a changed value, a missing key and a nested change are all reported."""
    made = {"a": 1, "b": {"c": [1, 2]}, "d": 0}
    assert differences(made, {"a": 1, "b": {"c": [1, 3]}, "e": 0}) == [
        "b.c: schema [1, 2], file [1, 3]",
        "d: only in the schema",
        "e: only in the file",
    ]


def test_the_suite_reads_the_shipped_configs_whatever_the_shell_names(tmp_path):
    """A MARLCRASH_CONFIGS set in the user's shell was honoured by the suite: these tests read that folder and failed
    falsely ("differs from configs/sim.yaml") or could not be collected; conftest drops it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, "MARLCRASH_CONFIGS": str(tmp_path / "nowhere")}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
           f"{Path(__file__).name}::test_a_schema_made_in_python_holds_the_shipped_values"]  # fmt: skip
    done = subprocess.run(cmd, cwd=Path(__file__).parent, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
