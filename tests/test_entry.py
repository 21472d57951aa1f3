"""Hydra's composition errors of the train/ entry scripts come out as ours: ``error:``, the key, exit 2."""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest

from marlcrash.calibrate.entry import (
    check_overrides,
    check_sweep,
    exit_on_bad_overrides,
    fixed_run_folder,
    name_default_run,
    sweep_jobs,
    train_config_dir,
)
from marlcrash.config import config_dir
from marlcrash.errors import ConfigError

TRAIN_CONFIGS = config_dir() / "train"
ENTRY_CONFIGS = ["train", "evaluate", "baseline", "compare", "ablate", "amortized"]


def message(name: str, overrides: list[str]) -> str:
    with pytest.raises(ConfigError) as e:
        check_overrides(TRAIN_CONFIGS, name, overrides)
    return str(e.value)


@pytest.mark.parametrize("name", ENTRY_CONFIGS)
def test_every_entry_config_composes_and_names_an_unknown_top_level_key(name):
    check_overrides(TRAIN_CONFIGS, name, [])  # the shipped configs compose as they are
    m = message(name, ["no_such_key=1"])
    assert m.startswith(f"{name}.yaml key 'no_such_key': unknown key; expected one of [")
    assert "'out_dir'" in m or "'run'" in m  # the keys there are, read from the composed config


def test_an_unknown_nested_key_lists_the_keys_of_the_group_file_picked():
    m = message("train", ["algorithm=ippo", "algorithm.lrr=1e-3"])
    assert "key 'algorithm.lrr': unknown key" in m and "'lr'" in m and "'clip_epsilon'" in m
    assert "'seed'" not in m  # the group's keys, not the top level's
    assert "key 'eval.foo'" in message("train", ["eval.iterations=3", "eval.foo=2"])


def test_a_new_key_of_an_overrides_mapping_is_told_to_use_plus():
    """``env_overrides`` mappings hold the user's own keys: Hydra needs '+' to add one, and the message says so."""
    for name, over in (("train", "env_overrides.observation.velocity_scale=2"),
                       ("baseline", "problem.env_overrides={reference.kind: file}")):  # fmt: skip
        m = message(name, [over])
        assert m == (f"{name}.yaml key '{over.split('=')[0]}': a key the config does not have yet (a mapping of "
                     f"overrides); add it with '+': +{over}")  # fmt: skip
        check_overrides(TRAIN_CONFIGS, name, [f"+{over}"])
    assert message("train", ["seed.x=1"]) == "train.yaml key 'seed.x': unknown key"  # not a mapping: no '+' advice


def test_an_unknown_group_option_lists_the_files_of_the_group():
    m = message("train", ["algorithm=sac"])
    options = sorted(p.stem for p in (TRAIN_CONFIGS / "algorithm").glob("*.yaml"))
    assert len(options) >= 3 and "mappo" in options
    assert m == f"train.yaml key 'algorithm': no config 'sac' in configs/train/algorithm/; expected one of {options}"


@pytest.mark.parametrize(
    ("name", "override", "key", "words"),
    [
        # Hydra's ValueError: a traceback from inside Hydra instead of an error naming the key
        ("train", "algorithm=null", "algorithm", "expected one of ['ippo', 'mappo', 'ppo_single']"),
        ("ablate", "algorithm@ippo=null", "algorithm@ippo", "expected one of ['ippo', 'mappo', 'ppo_single']"),
        # Hydra's messages named no key (an empty choice, the second of a list, a group the file does not use)
        ("train", "algorithm=", "algorithm", "no config '' in configs/train/algorithm/; expected one of ["),
        ("train", "algorithm=[mappo,sac]", "algorithm", "no config 'sac' in configs/train/algorithm/"),
        ("train", "baseline@cmaes=cmaes", "baseline@cmaes", "Could not override 'baseline@cmaes'"),
    ],
)
def test_a_bad_group_choice_is_named_with_its_key(name, override, key, words):
    with pytest.raises(ConfigError) as e:  # beside another override, itself bad (ablate.yaml has seeds, not seed)
        check_overrides(TRAIN_CONFIGS, name, ["seed=1", override])
    assert e.value.key == key, str(e.value)
    assert words in str(e.value)


def test_an_unparsable_override_is_named_with_its_key():
    m = message("train", ["seed=1", "algorithm.hidden=[16,16"])
    assert m.startswith("train.yaml key 'algorithm.hidden': cannot parse the override 'algorithm.hidden=[16,16'")
    assert "key 'seed': Ambiguous value" in message("train", ["seed=0,1,2"])  # a sweep without -m


def test_valid_overrides_pass_and_new_keys_are_left_to_the_config_validation():
    check_overrides(TRAIN_CONFIGS, "train", ["algorithm=ippo", "algorithm.lr=3e-4", "seed=2", "hydra.run.dir=x"])
    check_overrides(TRAIN_CONFIGS, "train", ["+foo=1"])  # load_train_config rejects it, naming the key


def test_exit_status_2_with_the_message_and_flags_left_to_hydra(tmp_path, capsys):
    script = tmp_path / "train" / "script.py"  # config_path is relative to the script's folder, as in hydra.main
    configs = tmp_path / "configs" / "train"
    configs.mkdir(parents=True)
    (configs / "tiny.yaml").write_text("seed: 0  # a seed\n")
    with pytest.raises(SystemExit) as e:
        exit_on_bad_overrides(script, "tiny", argv=["sed=1"])
    assert e.value.code == 2
    assert capsys.readouterr().err == "error: tiny.yaml key 'sed': unknown key; expected one of ['seed']\n"
    exit_on_bad_overrides(script, "tiny", argv=["--cfg", "job", "sed=1"])  # Hydra's flags: Hydra decides
    exit_on_bad_overrides(script, "tiny", argv=["seed=3"])


def test_a_checkout_script_that_imports_another_marlcrash_exits_2(tmp_path, capsys):
    """With a non-editable install, ``python train/train.py`` in a checkout imported the installed copy: its code and
    (since configs ship inside the package) its configs ran under the checkout's training configs, and edits to
    the checkout went unseen. A script of a checkout now refuses a marlcrash imported from elsewhere."""
    import marlcrash

    script = tmp_path / "train" / "script.py"
    configs = tmp_path / "configs" / "train"
    configs.mkdir(parents=True)
    (configs / "tiny.yaml").write_text("seed: 0  # a seed\n")
    (tmp_path / "marlcrash").mkdir()
    (tmp_path / "marlcrash" / "__init__.py").write_text("")
    with pytest.raises(SystemExit) as e:
        exit_on_bad_overrides(script, "tiny", argv=["seed=3"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    imported = Path(marlcrash.__file__).resolve().parent
    assert err.startswith(f"error: {script} belongs to the checkout {tmp_path}, but Python imports marlcrash from ")
    assert str(imported) in err and f"pip install -e {tmp_path}" in err
    here = Path(__file__).resolve().parent.parent / "train" / "train.py"  # this checkout's own script and package
    exit_on_bad_overrides(here, "train", argv=["seed=3"])


def test_marlcrash_configs_moves_the_library_configs_and_says_the_scripts_own_stay(tmp_path, monkeypatch, capsys):
    """``$MARLCRASH_CONFIGS`` points the env, reward, scenario, sim and cells configs at another folder; Hydra composes
    a script's own from the checkout's ``configs/train``. An edited ``train/`` copy in that folder went unread without
    a word, and a folder without ``train/`` made ``algorithm=ippo`` a value key (the ci block's ``algorithm.*`` keys
    were then not applied to the file picked)."""
    from marlcrash.calibrate.marl import value_keys

    lib = tmp_path / "configs"
    lib.mkdir()
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(lib))
    assert train_config_dir() == Path(__file__).resolve().parent.parent / "configs" / "train"
    assert value_keys(["algorithm", "algorithm.lr", "seed"]) == ["algorithm.lr", "seed"]
    here = Path(__file__).resolve().parent.parent / "train" / "train.py"
    exit_on_bad_overrides(here, "train", argv=["seed=3"])
    assert capsys.readouterr().err == ""  # no train/ there: nothing left unread
    shutil.copytree(train_config_dir(), lib / "train")
    exit_on_bad_overrides(here, "train", argv=["seed=3"])
    assert capsys.readouterr().err == ""  # the checkout's own, copied: the same configs either way
    algo = lib / "train" / "algorithm" / "mappo.yaml"
    algo.write_text(algo.read_text().replace("lr: ", "lr: 5.0e-3  # edited\n_was_lr: ", 1))
    exit_on_bad_overrides(here, "train", argv=["seed=3"])
    assert capsys.readouterr().err == (
        f"warning: MARLCRASH_CONFIGS={lib} gives the env, reward, scenario, sim and cells configs; this script's own "
        f"(train.yaml and its groups) come from {train_config_dir()}, not from its train/, which differs (Hydra's "
        "--config-dir adds a folder searched before it)\n"
    )
    monkeypatch.delenv("MARLCRASH_CONFIGS")
    exit_on_bad_overrides(here, "train", argv=["seed=3"])
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("name", ["train", "baseline", "compare", "ablate"])
def test_a_default_run_name_takes_the_next_free_folder_and_a_given_one_is_kept(name, tmp_path):
    """The default name is the launch second: the jobs of a multirun share it, so each takes the next free folder.
    A name the user gave is kept (the run refuses it later where it exists), as is a resumed run's."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(TRAIN_CONFIGS), version_base=None):
        cfg = compose(name)
    stamp = str(cfg.name)  # resolved once: the clock may tick between jobs, not within this test's folders
    config = SimpleNamespace(name=stamp, resume=False)
    for taken in (stamp, f"{stamp}-2"):
        (tmp_path / taken).mkdir()
    name_default_run(cfg, config, lambda c: tmp_path / c.name, given=["seed"])
    assert config.name == f"{stamp}-3"
    for given, resume in ((["name"], False), ([], True)):  # name=<stamp> typed, or a resume: that folder, no other
        config = SimpleNamespace(name=stamp, resume=resume)
        name_default_run(cfg, config, lambda c: tmp_path / c.name, given=given)
        assert config.name == stamp
    with initialize_config_dir(config_dir=str(TRAIN_CONFIGS), version_base=None):
        fixed = compose(name, overrides=["name=mine"])
    config = SimpleNamespace(name="mine", resume=False)
    (tmp_path / "mine").mkdir()
    name_default_run(fixed, config, lambda c: tmp_path / c.name, given=[])  # a plain value in the file: the user's
    assert config.name == "mine"


@pytest.mark.parametrize(
    ("value", "words"),
    [("s${sed}", "Interpolation key 'sed' not found"), ("${oc.env:MARLCRASH_TEST_UNSET}", "MARLCRASH_TEST_UNSET")],
)
def test_an_interpolation_that_does_not_resolve_is_named_with_its_key(value, words, monkeypatch):
    """A typo of the README's ``name=s${seed}`` was OmegaConf's traceback (exit 1), not ``error: key 'name'``."""
    from omegaconf import OmegaConf

    from marlcrash.calibrate.entry import config_mapping

    monkeypatch.delenv("MARLCRASH_TEST_UNSET", raising=False)
    with pytest.raises(ConfigError, match=f"cannot resolve the value: .*{words}") as e:
        config_mapping(OmegaConf.create({"seed": 0, "name": value}))
    assert e.value.key == "name"
    assert config_mapping(OmegaConf.create({"seed": 3, "name": "s${seed}"})) == {"seed": 3, "name": "s3"}


def test_a_sweep_expands_into_hydras_jobs():
    assert sweep_jobs(["seed=0,1", "lr=1,2", "x=3"]) == [
        ["seed=0", "lr=1", "x=3"], ["seed=0", "lr=2", "x=3"], ["seed=1", "lr=1", "x=3"], ["seed=1", "lr=2", "x=3"]
    ]  # fmt: skip
    with pytest.raises(ConfigError, match=r"key 'seed': cannot parse the override 'seed=\[0,'"):
        sweep_jobs(["seed=[0,", "x=1"])


def _sweep_configs(tmp_path) -> Path:
    configs = tmp_path / "configs"
    configs.mkdir()
    (configs / "tiny.yaml").write_text("seed: 0  # a seed\nname: ${now:%Y%m%d-%H%M%S}  # run name\n")
    return configs


def _check(cfg, data, given):  # a script's check of one job: its values, and its run folder
    if data["seed"] < 0:
        raise ConfigError(f"expected a seed >= 0, got {data['seed']}", key="seed")
    return fixed_run_folder(cfg, SimpleNamespace(**data), lambda c: Path("runs") / c.name, given)


def test_every_job_of_a_sweep_is_checked_before_the_first_runs(tmp_path, capsys):
    """Hydra runs a multirun's jobs in turn and each checked its values when it started: ``seed=0,-1,2`` trained
    job 1, then stopped at job 2, and job 3 never ran; ``name=same`` trained job 1, then refused job 2's folder."""
    configs = _sweep_configs(tmp_path)
    with pytest.raises(ConfigError, match=r"key 'seed': multirun job 2 of 3 \(seed=-1 name=s\$\{seed\}\): expected a "
                       r"seed >= 0, got -1; no job was run"):  # fmt: skip
        check_sweep(configs, "tiny", ["seed=0,-1,2", "name=s${seed}"], _check)
    with pytest.raises(ConfigError, match=r"key 'name': multirun jobs 1 and 2 of 2 would write one run folder .*same"):
        check_sweep(configs, "tiny", ["seed=0,1", "name=same"], _check)
    with pytest.raises(ConfigError, match=r"key 'sed': multirun job 1 of 2 \(seed=0 sed=1\): unknown key"):
        check_sweep(configs, "tiny", ["seed=0,1", "sed=1"], _check)
    check_sweep(configs, "tiny", ["seed=0,1,2", "name=s${seed}"], _check)
    check_sweep(configs, "tiny", ["seed=0,1"], _check)  # the default time-stamped name: each job gets its own folder
    script = tmp_path / "train" / "script.py"  # configs/ beside train/, as config_path="../configs" finds it
    with pytest.raises(SystemExit) as e:
        exit_on_bad_overrides(script, "tiny", "../configs", ["-m", "seed=1,-2"], check_job=_check)
    assert e.value.code == 2 and "multirun job 2 of 2 (seed=-2)" in capsys.readouterr().err
    exit_on_bad_overrides(script, "tiny", "../configs", ["-m", "seed=1,-2"])  # no job check given: left to Hydra
    exit_on_bad_overrides(script, "tiny", "../configs", ["-m", "--cfg", "job", "seed=-2"], check_job=_check)
