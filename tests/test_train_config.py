"""Training configs: the algorithm registry, schemas, and bad values failing before any training."""

from __future__ import annotations

import dataclasses
import re
import sys
from pathlib import Path

import pytest
import yaml

from marlcrash.calibrate.logging import make_logger
from marlcrash.calibrate.marl import (
    ALGORITHMS,
    TrainConfig,
    load_algorithm_config,
    load_train_config,
    make_env_config,
    value_keys,
)
from marlcrash.config import config_dir
from marlcrash.errors import ConfigError

ALGO_DIR = config_dir() / "train" / "algorithm"


def composed(overrides: list[str] | None = None, name: str = "train") -> dict:
    """configs/train/<name>.yaml composed by Hydra exactly as train/<name>.py sees it."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    with initialize_config_dir(config_dir=str(config_dir() / "train"), version_base=None):
        cfg = compose(config_name=name, overrides=overrides or [])
    return OmegaConf.to_container(cfg, resolve=True)


def test_every_algorithm_file_is_registered():
    files = sorted(p.stem for p in ALGO_DIR.glob("*.yaml"))
    assert files == sorted(ALGORITHMS)


@pytest.mark.parametrize("name", ALGORITHMS)
def test_algorithm_files_load_and_name_themselves(name):
    algo = load_algorithm_config(name)
    assert algo.name == name
    assert algo.centralised_critic == (name != "ippo")


@pytest.mark.parametrize("name", ALGORITHMS)
def test_train_yaml_composes_for_every_algorithm(name):
    cfg = load_train_config(composed([f"algorithm={name}"]), ci=False)
    assert isinstance(cfg, TrainConfig)
    assert cfg.algorithm.name == name
    assert cfg.frames_per_batch % cfg.algorithm.minibatch_size == 0
    env = make_env_config(cfg)
    assert env.termination.max_iterations == cfg.episode_length
    assert env.seed == cfg.seed


def test_every_yaml_key_has_a_comment():
    paths = sorted(config_dir().rglob("*.yaml"))
    assert config_dir() / "train" / "evaluate.yaml" in paths and len(paths) > 20
    for path in paths:
        for i, line in enumerate(path.read_text().splitlines(), 1):
            s = line.strip()
            if s and not s.startswith("#") and not s.startswith("- ") and ":" in s:
                assert "  # " in line, f"{path.name} line {i} has no comment: {line!r}"


def test_ci_overrides_shrink_the_run():
    data = composed()
    full = load_train_config(data, ci=False)
    ci = load_train_config(data, ci=True)
    assert ci.n_envs < full.n_envs and ci.iterations < full.iterations
    assert ci.frames_per_batch % ci.algorithm.minibatch_size == 0
    assert ci.eval.iterations == data["ci"]["eval.iterations"]


def test_command_line_values_win_over_the_ci_block_and_ci_errors_name_it():
    data = composed(["iterations=7", "eval.iterations=2"])
    ci = load_train_config(data, ci=True, explicit=["iterations", "eval.iterations"])
    assert ci.iterations == 7 and ci.eval.iterations == 2  # kept
    assert ci.n_envs == data["ci"]["n_envs"]  # the rest of the block applies
    data["ci"]["n_envs"] = 0
    with pytest.raises(ConfigError, match="MARLCRASH_CI=1 applied it") as e:
        load_train_config(data, ci=True)
    assert e.value.key == "ci.n_envs"
    with pytest.raises(ConfigError) as e:  # the same value from the command line is the command line's key
        load_train_config(composed(["n_envs=0"]), ci=True, explicit=["n_envs"])
    assert e.value.key == "n_envs"
    whole = composed(["eval={iterations: 9, reference_seed: 0}"])  # a whole mapping keeps its nested keys
    assert load_train_config(whole, ci=True, explicit=value_keys(["eval"])).eval.iterations == 9
    ippo = composed(["algorithm=ippo"])  # a config-group choice picks a file; the ci block still sizes it
    explicit = value_keys(["algorithm", "n_envs"])
    assert explicit == ["n_envs"]
    cfg = load_train_config(ippo, ci=True, explicit=explicit)
    assert cfg.algorithm.minibatch_size == ippo["ci"]["algorithm.minibatch_size"]


def test_a_ci_entry_given_as_a_mapping_changes_only_its_keys():
    """``+ci.env_overrides.max_step=0.05`` (the command line's only way to add a nested ``ci`` entry; Hydra makes it
    ``{"env_overrides": {"max_step": 0.05}}``) replaced the run's whole ``env_overrides``: the observation scales
    of train.yaml fell back to the env file's 1.0 without a word. ``+ci.eval.iterations=2`` replaced the whole
    ``eval`` section, refused as a missing ``eval.scenario``; a bad key inside one was not named ``ci.<key>``."""
    full = load_train_config(composed(), ci=False)
    cfg = load_train_config(composed(["+ci.env_overrides.max_step=0.05"]), ci=True)
    assert cfg.env_overrides["max_step"] == 0.05
    assert make_env_config(cfg).observation == make_env_config(full).observation  # the block's other keys kept
    cfg = load_train_config(composed(["+ci.eval.iterations=2", "+ci.algorithm.lr=3e-4"]), ci=True)
    assert cfg.eval.iterations == 2 and cfg.eval.scenario == full.eval.scenario
    assert cfg.algorithm.lr == 3e-4 and cfg.algorithm.minibatch_size == composed()["ci"]["algorithm.minibatch_size"]
    for override, key in (  # a bad value, named as the ci entry (a bad key or type fails on every run: next test)
        ("+ci.algorithm.lr=-1", "ci.algorithm.lr"),
        ("+ci.env_overrides.max_step=7", "ci.env_overrides.max_step"),
        ("+ci.env_overrides.masking.min_fraction=0.0", "ci.env_overrides.masking.min_fraction"),
    ):
        with pytest.raises(ConfigError, match="MARLCRASH_CI=1 applied it") as e:
            load_train_config(composed([override]), source="configs/train/train.yaml", ci=True)
        assert e.value.key == key
    # a command-line value keeps winning over a nested ci entry of the same key
    data = composed(["+ci.eval.iterations=2", "eval.iterations=9"])
    assert load_train_config(data, ci=True, explicit=["eval.iterations"]).eval.iterations == 9
    # an env section set in both places: the ci block's key joins the command line's others
    data = composed(["+env_overrides.masking.min_fraction=0.5", "+ci.env_overrides.masking.mode=primary"])
    masking = make_env_config(load_train_config(data, ci=True, explicit=["env_overrides.masking.min_fraction"])).masking
    assert (masking.mode, masking.min_fraction) == ("primary", 0.5)


def test_a_typo_in_the_ci_block_fails_on_every_run():
    """The ``ci`` block was read only under MARLCRASH_CI=1: ``ci: {n_env: 8}`` or ``ci: {eval.iteration: 4}`` loaded
    without a word on every other run, and CI then failed on a key nobody had run. Its keys are checked always; its
    values apply only under MARLCRASH_CI."""
    for override, key in (
        ("+ci.n_env=8", "ci.n_env"),
        ("+ci.eval.iteration=4", "ci.eval.iteration"),
        ("+ci.algorithm.lrr=1", "ci.algorithm.lrr"),
        ("+ci.env_overrides.masking.mod=all", "ci.env_overrides.masking.mod"),
        ("+ci.env_overrides.max_stepp=0.1", "ci.env_overrides.max_stepp"),
    ):
        with pytest.raises(ConfigError, match="unknown key") as e:
            load_train_config(composed([override]), source="configs/train/train.yaml", ci=False)
        assert e.value.key == key and e.value.path == "configs/train/train.yaml"
    for override, key, words in (  # a value of the wrong type too
        ("ci.n_envs=eight", "ci.n_envs", "expected an integer, got 'eight'"),
        ("ci.time_limit_s=true", "ci.time_limit_s", "expected a number, got True"),
        ("+ci.env_overrides.masking.mode=[1]", "ci.env_overrides.masking.mode", "expected one of"),
        ("+ci.algorithm=ippo", "ci.algorithm", "expected a mapping, got 'ippo'"),
    ):
        with pytest.raises(ConfigError, match=re.escape(words)) as e:
            load_train_config(composed([override]), source="configs/train/train.yaml", ci=False)
        assert e.value.key == key
    # known keys (a mapping-valued env key among them) load, and apply only under ci
    data = composed(["+ci.env_overrides.scenarios.full_width_56=1.0", "+ci.eval.iterations=2"])
    assert load_train_config(data, ci=False).eval.iterations == data["eval"]["iterations"]
    assert load_train_config(data, ci=True).eval.iterations == 2


def test_ci_reads_the_environment(monkeypatch):
    data = composed()
    monkeypatch.setenv("MARLCRASH_CI", "1")
    assert load_train_config(data).iterations == data["ci"]["iterations"]
    monkeypatch.setenv("MARLCRASH_CI", "0")
    assert load_train_config(data).iterations == data["iterations"]


@pytest.mark.parametrize(
    ("overrides", "key", "words"),
    [
        (["algorithm.lr=-0.001"], "algorithm.lr", "learning rate > 0"),
        (["algorithm.name=sac"], "algorithm.name", "unknown algorithm 'sac'"),
        (["algorithm.minibatch_size=7"], "algorithm.minibatch_size", "divisor of the batch"),
        (["n_envs=0"], "n_envs", "[1, 10000] parallel episodes"),
        # one batched simulation per step: 10**12 failed allocating 29 PB after the run folder existed
        (["n_envs=1000000000000"], "n_envs", "[1, 10000] parallel episodes"),
        # 4.8e13 env steps per iteration: the run never finished its first one (its rollout: 175 kB a step)
        (["episode_length=1000000000000"], "episode_length", "at most 100000 env steps per iteration"),
        (["n_envs=10000", "episode_length=11", "algorithm.minibatch_size=50"], "episode_length", "110000"),
        (["logger=wandb"], "logger", "unknown logger"),
        (["algorithm.gamma=1.5"], "algorithm.gamma", "[0, 1]"),
        (["algorithm.centralised_critic=false"], "algorithm.centralised_critic", "centralised critic"),
        # a centralised critic is one network: false was accepted, saved in config.yaml and built the shared one
        (["algorithm.share_critic_params=false"], "algorithm.share_critic_params", "shared by every agent"),
        (["+algorithm.learning_rate=0.1"], "algorithm.learning_rate", "unknown key"),
        (["eval.iterations=0"], "eval.iterations", ">= 1"),
        # the env counts steps in int64: 2**63 compared as -2**63 and truncated the evaluation after its first step
        (["eval.iterations=9223372036854775808"], "eval.iterations", "at most 2**63 - 1"),
        (["time_limit_s=-5"], "time_limit_s", "> 0 s"),
        (["name=.."], "name", "got '..', which names the output folder's parent"),  # no '/' in it: say why
        (["name=."], "name", "got '.', which names the output folder itself"),
        (["name=a/b"], "name", "without '/'"),
        # resume=$RUN with the variable unset: the launch folder, whose run (if it is one) was continued unasked
        (["resume="], "resume", "got an empty one"),
        (["seed=-1"], "seed", "seed in [0, 2**64 - 1]"),
        # torch.manual_seed's overflow: a traceback once the run folder existed, not an error naming the key
        (["seed=18446744073709551616"], "seed", "seed in [0, 2**64 - 1]"),
        (["eval.scenario=nope"], "eval.scenario", "unknown scenario 'nope'"),
        (["eval.reference_seed=-1"], "eval.reference_seed", "seed >= 0"),
        (["algorithm.init_std=inf"], "algorithm.init_std", "expected a finite number"),
        # an infinite initial scale: the first update's loss was NaN, refused as a diverged 'algorithm.lr'
        (["algorithm.init_std=100"], "algorithm.init_std", "softplus head can represent in float32"),
        (["algorithm.mean_init_gain=nan"], "algorithm.mean_init_gain", "expected a finite number"),
        # the loss holds its coefficients in float32: 1e39 became inf, and the first update was refused as a diverged
        # 'algorithm.lr'
        (["algorithm.entropy_coef=1e39"], "algorithm.entropy_coef", "float32 holds (at most 3.403e+38)"),
        (["algorithm.entropy_coef_final=1e39"], "algorithm.entropy_coef_final", "float32 holds"),
        (["algorithm.critic_coef=1e39"], "algorithm.critic_coef", "float32 holds"),
        (["algorithm.mean_init_gain=1e39"], "algorithm.mean_init_gain", "float32 holds"),
        # Adam's step lr / (1 - beta1) on the float32 weights: a traceback from inside torch's optimizer step
        (["algorithm.lr=4e37"], "algorithm.lr", "Adam step (10 x lr) float32 holds (at most 3.403e+37)"),
        (["algorithm.lr_final=1e38"], "algorithm.lr_final", "float32 holds"),
        # a floor <= 0 on its own was named algorithm.init_std, the key the user had not touched
        (["algorithm.min_std=0"], "algorithm.min_std", "expected a standard deviation floor > 0, got 0.0"),
        (["algorithm.min_std=0.5"], "algorithm.init_std", "min_std (0.5) < init_std (0.3)"),
        (["resume=1"], "resume", "expected true or false or a string, got 1"),  # one message for the union
        # torch starts as many threads as asked: 100,000 crashed the process at the first matrix product
        (["threads=100000"], "threads", "thread count in [0, 1024]"),
        # torch failed allocating 3.9 TB for the first layer, a traceback instead of the key
        (["algorithm.hidden=[128,1000000000]"], "algorithm.hidden", "layer widths in [1, 16384]"),
    ],
)
def test_bad_values_name_the_key(overrides, key, words):
    with pytest.raises(ConfigError) as e:
        load_train_config(composed(overrides), ci=False)
    assert e.value.key == key
    assert words in str(e.value)


def test_unavailable_device_is_refused():
    import torch

    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    with pytest.raises(ConfigError) as e:
        load_train_config(composed(["device=cuda"]), ci=False)
    assert e.value.key == "device"
    with pytest.raises(ConfigError, match="torch device"):
        load_train_config(composed(["device=gpu0"]), ci=False)


@pytest.mark.parametrize(
    "override, key, words",
    [
        ("env_overrides.max_step=-1", "env_overrides.max_step", "expected a log increment"),
        ("+env_overrides.reward=nope", "env_overrides.reward", "unknown reward form 'nope'"),  # not the form's 'name'
        # not termination.max_iterations, the key the training adds for its episode length
        ("+env_overrides.termination=3", "env_overrides.termination", "expected a mapping, got 3"),
        # keys the training sets from its own settings: an override would be replaced without a word
        ("+env_overrides.termination.max_iterations=9", "env_overrides.termination.max_iterations", "episode_length"),
        ("+env_overrides.seed=3", "env_overrides.seed", "the run's seed"),
        ("env=nope", "env", "unknown env config 'nope'"),
        # refused only when the env was built, after the run folder was made, as the env file's key 'vehicle'
        ("+env_overrides.vehicle=b_segmnet", "env_overrides.vehicle", "unknown vehicle 'b_segmnet'"),
        # a numpy traceback from inside the vehicle generator; an error after the discretization, naming default.yaml
        ("+env_overrides.vehicle_seed=-3", "env_overrides.vehicle_seed", "expected a seed >= 0 or null"),
        (
            "+env_overrides.scenarios.full_width_4O=1",
            "env_overrides.scenarios.full_width_4O",
            "unknown scenario 'full_width_4O'",
        ),
        (
            "+env_overrides.reference.cross_fidelity.vehicle_seeds=[-1]",
            "env_overrides.reference.cross_fidelity.vehicle_seeds[0]",
            "expected a seed >= 0",
        ),
    ],
)
def test_bad_env_override_names_the_training_key(override, key, words):
    """The key the user set, in train.yaml, when the config is loaded: not the env file's, nor the reward's."""
    with pytest.raises(ConfigError, match=words) as e:
        load_train_config(composed([override]), source="configs/train/train.yaml", ci=False)
    assert e.value.key == key and str(e.value).startswith(f"train.yaml key '{key}': ")
    cfg = load_train_config(composed([]), ci=False)
    cfg.env_overrides = {"reward": "nope"}  # set after loading: make_env_config names it all the same
    with pytest.raises(ConfigError, match="unknown reward form") as e:
        make_env_config(cfg)
    assert e.value.key == "env_overrides.reward"


def test_an_algorithm_file_missing_a_key_is_named_not_defaulted(tmp_path, monkeypatch):
    """load_algorithm_config filled a key left out of the file with the schema's default (mappo's values), where every
    other loader of a shipped file refuses one."""
    import shutil

    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    path = configs / "train" / "algorithm" / "ippo.yaml"
    path.write_text("".join(x for x in path.read_text().splitlines(True) if not x.startswith("lr:")))
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(configs))
    with pytest.raises(ConfigError, match="missing") as e:
        load_algorithm_config("ippo")
    assert e.value.key == "lr" and e.value.path == str(path)


def test_unknown_algorithm_file():
    with pytest.raises(ConfigError, match="unknown algorithm 'dqn'"):
        load_algorithm_config("dqn")


def test_tensorboard_logger_needs_its_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # as if the extra were not installed
    with pytest.raises(ConfigError) as e:
        make_logger("tensorboard", tmp_path)
    assert e.value.key == "logger"
    assert "tensorboard" in str(e.value) and "pip install" in str(e.value)


def _tensorboard_steps(run_dir) -> list[int]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_dir / "tensorboard"))
    acc.Reload()
    return [e.step for e in acc.Scalars("x")]


@pytest.mark.parametrize("checkpoint_at", [4, 2])
def test_tensorboard_resume_keeps_every_step_once(tmp_path, checkpoint_at):
    """A resume cuts the rows written after the checkpoint from the CSV and from TensorBoard, then rewrites them."""
    pytest.importorskip("tensorboard")
    logger = make_logger("tensorboard", tmp_path)
    for i in range(1, 5):
        logger.log({"iteration": float(i), "x": float(i)})
    logger.close()
    resumed = make_logger("tensorboard", tmp_path)
    resumed.truncate(checkpoint_at)  # what Trainer.load_state_dict does with the checkpoint's log position
    for i in range(checkpoint_at + 1, 7):
        resumed.log({"iteration": float(i), "x": 10.0 * i})
    resumed.close()
    assert _tensorboard_steps(tmp_path) == [1, 2, 3, 4, 5, 6]


def test_saved_run_config_round_trips(tmp_path):
    from marlcrash.calibrate.marl import load_run_config, save_run_config

    cfg = load_train_config(composed(["algorithm=ippo", "seed=3"]), ci=False)
    save_run_config(cfg, tmp_path)
    back = load_run_config(tmp_path)
    assert dataclasses.asdict(back) == dataclasses.asdict(cfg)
    assert yaml.safe_load((tmp_path / "config.yaml").read_text())["algorithm"]["name"] == "ippo"
    assert not list(Path(tmp_path).glob(".*tmp"))


def test_the_eval_folder_of_a_run_given_as_the_run_names_the_re_evaluations_in_it(tmp_path):
    """``<run>/eval`` given where ``<run>`` or ``<run>/eval/<checkpoint>`` belongs (contributions, evaluate): it said
    only that there is no config.yaml in it."""
    from marlcrash.analysis.contributions import run_calibration
    from marlcrash.calibrate.marl import load_run_config

    run = tmp_path / "run"
    (run / "eval" / "iter_00002").mkdir(parents=True)
    (run / "eval" / "checkpoint_steps2").mkdir()
    (run / "eval" / "notes.txt").write_text("not a re-evaluation")
    (run / "config.yaml").write_text("seed: 3\n")
    eval_dir, again = run / "eval", [str(run / "eval" / n) for n in ("checkpoint_steps2", "iter_00002")]
    words = f"found none in {eval_dir}, a folder inside the run {run}: name the run (train/evaluate.py, resume) or "
    words = re.escape(words + f"one of its re-evaluations (marlcrash contributions): {', '.join(again)}") + "$"
    for read in (load_run_config, run_calibration):
        with pytest.raises(ConfigError, match=words) as e:
            read(run / "eval")
        assert e.value.key == "run"
    with pytest.raises(
        ConfigError, match=re.escape(f"found none in {tmp_path}") + "$"
    ):  # not inside a run: nothing more to say
        load_run_config(tmp_path)


@pytest.mark.parametrize(
    "text, words",
    [
        ("algorithm: {name: mappo\n", r"config\.yaml: invalid YAML at line 2"),  # a torn or hand-edited file
        ("", r"config\.yaml: empty; expected the run's settings \(a mapping\)"),
        ("- 1\n- 2\n", r"config\.yaml: expected a mapping at the top level, got list"),
        ("seed: 3\n", r"config\.yaml key 'algorithm': missing"),
    ],
)
def test_a_bad_saved_run_config_names_the_file(tmp_path, text, words):
    """evaluate, resume, contributions and amortized read a run's config.yaml: a broken one is named, not a
    traceback from the YAML parser."""
    from marlcrash.calibrate.marl import load_run_config

    (tmp_path / "config.yaml").write_text(text)
    with pytest.raises(ConfigError, match=words) as e:
        load_run_config(tmp_path)
    assert e.value.path == str(tmp_path / "config.yaml")
    (tmp_path / "config.yaml").write_bytes(b"\xff\xfe\x00junk")
    with pytest.raises(ConfigError, match=r"config\.yaml: not a text file"):
        load_run_config(tmp_path)


def test_a_key_missing_from_an_older_runs_config_names_the_runs_file(tmp_path):
    """A run saved by an older version lacks a key added since: 'config.yaml key ...: missing ... add this key' named
    the file by its name only, which every run folder has."""
    from marlcrash.calibrate.marl import load_run_config, save_run_config

    run = tmp_path / "runs" / "mappo" / "old"
    save_run_config(load_train_config(composed([]), ci=False), run)
    data = yaml.safe_load((run / "config.yaml").read_text())
    del data["time_limit_s"], data["algorithm"]["lr"]
    (run / "config.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match=re.escape(f"add this key to {run / 'config.yaml'} (and 1 more")) as e:
        load_run_config(run)
    assert e.value.key == "algorithm.lr" and e.value.path == str(run / "config.yaml")


@pytest.mark.parametrize(
    ("name", "drop"),
    [("train", "algorithm.lr"), ("train", "time_limit_s"), ("baseline", "gradient.lr"), ("compare", "budget"),
     ("amortized", "seed"), ("evaluate", "checkpoint")],
)  # fmt: skip
def test_a_key_deleted_from_a_config_file_is_named_not_defaulted(name, drop):
    """Values live in the YAML files: every script's composed config gives every schema key, and one missing
    fails naming it instead of falling back to a dataclass default (which may differ from the file's value)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from marlcrash.calibrate.amortized import AmortizedConfig, load_amortized_config
    from marlcrash.calibrate.baselines import BaselineRunConfig
    from marlcrash.calibrate.baselines import load_run_config as load_baseline_config
    from marlcrash.calibrate.compare import CompareConfig, load_compare_config
    from marlcrash.calibrate.evaluate import EvaluateRunConfig, load_evaluate_config
    from marlcrash.config import missing_keys

    schema, load = {
        "train": (TrainConfig, load_train_config),
        "baseline": (BaselineRunConfig, load_baseline_config),
        "compare": (CompareConfig, load_compare_config),
        "amortized": (AmortizedConfig, load_amortized_config),
        "evaluate": (EvaluateRunConfig, load_evaluate_config),
    }[name]
    with initialize_config_dir(config_dir=str(config_dir() / "train"), version_base=None):
        data = OmegaConf.to_container(compose(config_name=name), resolve=True)
    data.pop("hydra", None)
    assert missing_keys(schema, data) == []
    node = data
    *parents, last = drop.split(".")
    for p in parents:
        node = node[p]
    del node[last]
    with pytest.raises(ConfigError, match="missing") as e:
        load(data, source=f"configs/train/{name}.yaml")
    assert e.value.key == drop


@pytest.mark.parametrize("name", ["train", "evaluate", "baseline", "compare", "amortized", "ablate"])
def test_scripts_log_to_stderr_so_stdout_stays_their_json(name):
    """Library warnings (matplotlib's findfont, torch, ...) must not land in the JSON a script prints on stdout."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(config_dir() / "train"), version_base=None):
        cfg = compose(config_name=name, return_hydra_config=True)
    handlers = cfg.hydra.job_logging.handlers
    assert [h.stream for h in handlers.values()] == ["ext://sys.stderr"]
    assert list(cfg.hydra.job_logging.root.handlers) == list(handlers)


@pytest.mark.parametrize("name", ["train", "evaluate", "baseline", "compare", "amortized", "ablate"])
def test_a_multirun_sweep_records_itself_beside_the_runs_not_in_the_launch_directory(name):
    """``--multirun`` writes only ``multirun.yaml``, under ``<out_dir>/multirun/`` (``runs/`` by default)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    fixed = name in ("evaluate", "amortized")  # no out_dir, or (amortized) one that may be null
    parent = "runs" if fixed else "elsewhere"
    with initialize_config_dir(config_dir=str(config_dir() / "train"), version_base=None):
        cfg = compose(config_name=name, overrides=[] if fixed else [f"out_dir={parent}"], return_hydra_config=True)
        sweep = OmegaConf.to_container(cfg.hydra.sweep, resolve=True)
    assert sweep["dir"].startswith(f"{parent}/multirun/") and len(sweep["dir"]) > len(f"{parent}/multirun/")
    assert sweep["subdir"] == "."  # no empty per-job folders


@pytest.mark.parametrize("bad", [0, 2**63])
def test_the_evaluate_scripts_step_count_is_refused_naming_its_key(bad):
    """``train/evaluate.py iterations=2**63`` passed the script's check and was refused later as the env file's
    ``termination.max_iterations``, a key the user never set."""
    from marlcrash.calibrate.evaluate import load_evaluate_config

    with pytest.raises(ConfigError, match=r"1 to 2\*\*63 - 1 \(MAX_STEPS\)") as e:
        load_evaluate_config({"run": "runs/mappo/x", "checkpoint": "latest", "iterations": bad})
    assert e.value.key == "iterations"


@pytest.mark.parametrize(
    ("terms", "key"),
    [
        ((1.0, 2.0, float("inf")), "algorithm.entropy_coef"),
        ((1.0, float("nan"), -1.0), "algorithm.critic_coef"),
        ((float("nan"), 2.0, -1.0), "algorithm.lr"),
        ((1.0, 2.0, -1.0), "algorithm.lr"),  # every term finite, the gradient not
        ((1.0, float("inf"), float("inf")), "algorithm.lr"),
    ],
)
def test_a_diverged_update_names_the_coefficient_of_its_one_non_finite_loss_term(terms, key):
    """An entropy or critic coefficient too large for the loss made that term infinite, and the error blamed the
    learning rate."""
    from types import SimpleNamespace

    import torch
    from tensordict import TensorDict

    from marlcrash.calibrate.marl import _diverged

    names = ("loss_objective", "loss_critic", "loss_entropy")
    out = TensorDict(
        {**{k: torch.tensor(v) for k, v in zip(names, terms, strict=True)}, "kl_approx": torch.tensor(0.0)}
    )
    loss = SimpleNamespace(entropy_coeff=torch.tensor(3e38), critic_coeff=torch.tensor(1.0))
    e = _diverged(out, torch.tensor(sum(terms)), torch.tensor(float("inf")), 3e-4, loss)
    assert e.key == key
    if key == "algorithm.entropy_coef":
        assert "loss_entropy is not finite" in str(e) and "entropy_coef 3e+38" in str(e)
    if key == "algorithm.lr":
        assert "learning rate 0.0003" in str(e)
