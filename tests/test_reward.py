"""Reward forms, their registry and YAML configs, the paper's Table 3, termination."""

from __future__ import annotations

import dataclasses
import itertools
import math
import re

import pytest
import torch

from marlcrash.config import config_dir
from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics
from marlcrash.reward import (
    REWARD_FORMS,
    Reward,
    RewardConfig,
    TerminationConfig,
    get_reward,
    load_reward_config,
    paper_factor,
    reduce_sensors,
    require_reward,
    termination,
)

# The paper's Table 3 (DESIGN 1.5): metric rows and the factor a/A + b/DFD + c/RMSE, a = b = c = 1.
TABLE3_A = [0.0259, 0.0311, 0.0363, 0.0189, 0.0015, 0.0415]
TABLE3_DFD = [0.423, 0.455, 0.487, 0.411, 0.335, 0.519]
TABLE3_RMSE = [0.2585, 0.2737, 0.2889, 0.22, 0.1511, 0.3041]
TABLE3_FACTOR = [44.84, 38.00, 33.06, 59.89, 676.27, 29.31]
REWARD_DIR = config_dir() / "reward"


def table3_metrics() -> Metrics:
    """The six iterations as [6, 1] (one sensor)."""
    return Metrics(*(torch.tensor(row, dtype=torch.float64)[:, None] for row in (TABLE3_A, TABLE3_DFD, TABLE3_RMSE)))


def test_paper_table3_factor_row():
    f = paper_factor(*(torch.tensor(row, dtype=torch.float64) for row in (TABLE3_A, TABLE3_DFD, TABLE3_RMSE)))
    for got, want in zip(f.tolist(), TABLE3_FACTOR, strict=True):
        assert abs(got - want) < 0.01, (got, want)
    # the same through the configured paper form (the metric floor 1e-6 is far below Table 3's values)
    rw = Reward(load_reward_config("paper_factor"))
    torch.testing.assert_close(rw.score(table3_metrics()), f, rtol=0, atol=1e-12)


def test_paper_reward_is_the_factor_improvement():
    m = table3_metrics()
    rw = Reward(load_reward_config("paper_factor"))
    prev = Metrics(*(x[:-1] for x in m))
    cur = Metrics(*(x[1:] for x in m))
    r = rw(cur, prev)
    want = [b - a for a, b in itertools.pairwise(TABLE3_FACTOR)]
    for got, w in zip(r.tolist(), want, strict=True):
        assert abs(got - w) < 0.02
    assert (rw(cur, None) == 0).all()


def test_every_yaml_is_registered_and_every_form_has_a_yaml():
    files = {p.stem for p in REWARD_DIR.glob("*.yaml")}
    assert files == set(REWARD_FORMS), (files, set(REWARD_FORMS))


@pytest.mark.parametrize("name", sorted(REWARD_FORMS))
def test_each_config_loads_names_its_form_and_comments_every_key(name):
    cfg = load_reward_config(name)
    assert cfg.name == name
    rw = Reward(cfg)
    assert rw.form.name == name
    for lineno, line in enumerate((REWARD_DIR / f"{name}.yaml").read_text().splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            assert " # " in line, f"{name}.yaml line {lineno} has no comment: {line!r}"
    # a better fit scores higher under every form
    m = table3_metrics()
    s = rw.score(m)
    assert s[4] > s[0] > s[5]


def test_unknown_form_lists_the_known_ones():
    with pytest.raises(ConfigError, match=r"unknown reward form 'nope'.*log_ratio.*paper_factor"):
        get_reward("nope")
    with pytest.raises(ConfigError, match="unknown reward form"):
        load_reward_config("nope")
    with pytest.raises(ConfigError, match=r"key 'fit': unknown reward form 'nope'"):  # the setting that names it
        require_reward("nope", "fit")
    require_reward("log_ratio", "fit")
    require_reward("my_reward.yaml", "fit")  # a file: read (and checked) where the reward is built


def test_bad_params_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"key 'params.a'"):
        get_reward("paper_factor", a=-1.0)
    with pytest.raises(ConfigError, match=r"key 'params.w'"):
        get_reward("log_ratio", w=1.0)
    text = (REWARD_DIR / "log_ratio.yaml").read_text().replace("rmse_scale: 0.25", "rmse_scale: -1")
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(ConfigError, match=r"bad\.yaml key 'params.rmse_scale': must be > 0"):
        load_reward_config(bad)
    with pytest.raises(ConfigError, match=r"success_rmse"):
        load_reward_config("log_ratio", overrides={"termination.success_rmse": 7.0})


def test_a_reward_file_that_leaves_out_a_parameter_of_its_form_is_refused(tmp_path):
    """Every loader refuses a file that leaves a key out, but the form's parameters (a mapping to the schema) were
    not checked: a log_ratio file without eps and rmse_scale loaded with the code's 1e-9 and 0.25."""
    lines = (REWARD_DIR / "log_ratio.yaml").read_text().splitlines(keepends=True)
    short = tmp_path / "short.yaml"
    short.write_text("".join(x for x in lines if not x.lstrip().startswith(("eps:", "rmse_scale:"))))
    with pytest.raises(
        ConfigError, match=r"short\.yaml key 'params\.rmse_scale': missing: .*\(and 1 more: params\.eps\)"
    ):
        load_reward_config(short)
    cfg = load_reward_config(short, overrides={"params.rmse_scale": 0.3, "params.eps": 1e-6})
    assert cfg.params["rmse_scale"] == 0.3 and cfg.params["eps"] == 1e-6


def test_a_params_override_given_as_a_mapping_keeps_the_files_other_parameters(tmp_path):
    """``{'params': {'a': 2.0}}`` replaced the file's whole params block: the parameters it left out took the code's
    defaults (the file's b: 3 became 1), which the completeness check, reading the file, did not see."""
    text = (REWARD_DIR / "paper_factor.yaml").read_text()
    path = tmp_path / "pf.yaml"
    path.write_text(re.sub(r"(?m)^(\s*)b:\s*[0-9.eE+-]+", r"\g<1>b: 3.0", text, count=1))
    assert load_reward_config(path).params["b"] == 3.0
    cfg = load_reward_config(path, overrides={"params": {"a": 2.0}})
    assert cfg.params["a"] == 2.0 and cfg.params["b"] == 3.0
    assert cfg == load_reward_config(path, overrides={"params.a": 2.0})
    both = load_reward_config(path, overrides={"params": {"a": 2.0, "c": 4.0}, "params.c": 5.0})
    assert (both.params["a"], both.params["b"], both.params["c"]) == (2.0, 3.0, 5.0)  # the dotted key wins


def test_all_weights_zero_is_refused_naming_params_once(tmp_path):
    """The section named itself, and the key came out as 'params.params', a key no config has."""
    zero = {"params.w_area": 0.0, "params.w_dfd": 0.0, "params.w_rmse": 0.0}
    with pytest.raises(ConfigError, match=r"log_ratio\.yaml key 'params': at least one weight must be > 0"):
        load_reward_config("log_ratio", overrides=zero)
    with pytest.raises(ConfigError, match=r"key 'params': at least one of a, b, c must be > 0"):
        load_reward_config("paper_factor", overrides={"params.a": 0.0, "params.b": 0.0, "params.c": 0.0})


@pytest.mark.parametrize(
    "name, key, value",
    [
        ("log_ratio", "w_area", 1e308),
        ("neg_weighted_sum", "w_rmse", 1e38),
        ("paper_factor", "a", 1e308),
        ("log_ratio", "area_scale", 1e-310),
        ("neg_weighted_sum", "dfd_scale", 1e-30),
        ("paper_factor", "min_metric", 1e-40),
    ],
)
def test_weights_that_overflow_the_reward_are_refused(name, key, value):
    """``w_area: 1e308`` (or a scale of 1e-310) made ``w * A / A0`` inf: log_ratio's reward was NaN, neg_weighted_sum's
    -inf, the paper factor's NaN, fed to the PPO loss and the optimizers' ranking without a word; ``min_metric`` of
    1e-40 is 0 in float32, and a perfect fit scored inf. The weights and scales are bounded, naming the key."""
    with pytest.raises(ConfigError, match=rf"params\.{key}"):
        get_reward(name, **{key: value})
    with pytest.raises(ConfigError, match=rf"params\.{key}"):
        load_reward_config(name, overrides={f"params.{key}": value})


@pytest.mark.parametrize("key", ["dfd_time_scale", "dfd_value_scale"])
def test_a_frechet_scale_that_overflows_the_distance_is_refused(key):
    """``metrics.dfd_value_scale: 1e308`` made every discrete Frechet distance NaN (1e160: inf) and the reward NaN
    or -inf without a word. The factors are bounded (MAX_DFD_SCALE), naming the key; at the bound the distance of
    float32 curves and the reward stay finite."""
    from marlcrash.metrics import MAX_DFD_SCALE

    with pytest.raises(ConfigError, match=rf"key 'metrics\.{key}'.*MAX_DFD_SCALE"):
        load_reward_config("log_ratio", overrides={f"metrics.{key}": 1e160})
    rw = Reward(load_reward_config("log_ratio", overrides={f"metrics.{key}": MAX_DFD_SCALE}))
    t = torch.linspace(0.0, 0.15, 301)
    m = rw.metrics((20.0 - 100.0 * t)[None, None], (-80.0 + 0.0 * t)[None, None], t)
    assert torch.isfinite(m.dfd).all() and torch.isfinite(rw.score(m)).all()


def test_the_bounds_of_the_weights_keep_every_reward_finite():
    """At the bounds (largest weights, smallest scales and floor) the reward of float32 metrics from a perfect fit
    to a hopeless one (velocity errors of 100 m/s) stays finite."""
    from marlcrash.reward import MAX_REWARD_WEIGHT, MIN_METRIC_FLOOR, MIN_REWARD_SCALE

    extreme = {
        "paper_factor": {"a": MAX_REWARD_WEIGHT, "b": MAX_REWARD_WEIGHT, "c": MAX_REWARD_WEIGHT,
                         "min_metric": MIN_METRIC_FLOOR},
        "log_ratio": {"w_area": MAX_REWARD_WEIGHT, "w_dfd": MAX_REWARD_WEIGHT, "w_rmse": MAX_REWARD_WEIGHT,
                      "area_scale": MIN_REWARD_SCALE, "dfd_scale": MIN_REWARD_SCALE, "rmse_scale": MIN_REWARD_SCALE},
    }  # fmt: skip
    extreme["neg_weighted_sum"] = extreme["log_ratio"]
    worst = Metrics(*(torch.full((1,), x, dtype=torch.float32) for x in (15.0, 100.0, 100.0)))
    zero = Metrics(*(torch.zeros(1, dtype=torch.float32) for _ in range(3)))
    for name, params in extreme.items():
        rw = get_reward(name, **params)
        for m, prev in ((zero, worst), (worst, zero), (zero, zero)):
            assert torch.isfinite(rw.reward(m, prev)).all(), name


def test_log_ratio_is_scale_free():
    rw = get_reward("log_ratio", area_scale=0.02, dfd_scale=0.4, rmse_scale=0.25, eps=1e-15)
    m = Metrics(torch.tensor([0.02, 2e-4]), torch.tensor([0.4, 4e-3]), torch.tensor([0.25, 2.5e-3]))
    half = Metrics(*(x / 2 for x in m))
    torch.testing.assert_close(rw.reward(half, m), torch.full((2,), math.log(2.0), dtype=torch.float32))
    assert rw.reward(m, half).tolist() == pytest.approx([-math.log(2.0)] * 2)
    # the paper's factor gives wildly different rewards for the same relative improvement
    pf = get_reward("paper_factor")
    r = pf.reward(half, m)
    assert r[1] / r[0] > 50


def test_log_ratio_refuses_a_zero_eps():
    """With ``eps: 0`` a perfect fit scored ``-log(0) = +inf``: its reward was +inf and the next step's NaN
    (``inf - inf``), both fed to the PPO loss."""
    with pytest.raises(ConfigError, match=r"params\.eps.*must be > 0 for log_ratio"):
        get_reward("log_ratio", eps=0.0)
    with pytest.raises(ConfigError, match=r"params\.eps"):
        load_reward_config("log_ratio", overrides={"params.eps": 0.0})
    rw = get_reward("log_ratio")
    exact = Metrics(*(torch.zeros(1, dtype=torch.float64) for _ in range(3)))
    near = Metrics(*(torch.full((1,), 1e-3, dtype=torch.float64) for _ in range(3)))
    assert torch.isfinite(rw.reward(exact, near)).all() and torch.isfinite(rw.reward(exact, exact)).all()


def test_a_form_refuses_an_option_it_does_not_use():
    """``neg_weighted_sum`` took an ``eps`` it never used (it takes no logarithm): a user who set it believed it did
    something. Every form takes only the options its score uses; any other is refused naming the form, the option and
    the options the form takes, wherever the parameters come from."""
    with pytest.raises(ConfigError, match=r"params\.eps.*'neg_weighted_sum'.*eps.*area_scale.*w_rmse"):
        get_reward("neg_weighted_sum", eps=0.0)
    with pytest.raises(ConfigError, match=r"params\.eps.*'neg_weighted_sum'"):
        load_reward_config("neg_weighted_sum", overrides={"params.eps": 1e-9})
    with pytest.raises(ConfigError, match=r"params\.a.*'log_ratio'.*a.*area_scale.*eps"):
        Reward(RewardConfig(name="log_ratio", params={"a": 1.0}))
    for name, form in REWARD_FORMS.items():  # every shipped file holds only options its form takes
        assert set(load_reward_config(name).params) == {f.name for f in dataclasses.fields(form.params_cls)}
    assert "eps" not in {f.name for f in dataclasses.fields(REWARD_FORMS["neg_weighted_sum"].params_cls)}


def test_neg_weighted_sum():
    rw = get_reward("neg_weighted_sum", w_area=2.0, w_dfd=0.0, w_rmse=1.0, area_scale=0.01, rmse_scale=0.1)
    m = Metrics(torch.tensor([0.01]), torch.tensor([9.0]), torch.tensor([0.2]))
    assert rw.reward(m, None).item() == pytest.approx(-(2.0 * 1.0 + 2.0))


def test_sensor_reduction_and_perfect_fit_stays_finite():
    m = Metrics(torch.tensor([[1.0, 3.0]]), torch.tensor([[2.0, 4.0]]), torch.tensor([[0.0, 1.0]]))
    assert reduce_sensors(m, "mean").area.item() == 2.0 and reduce_sensors(m, "max").dfd.item() == 4.0
    with pytest.raises(ConfigError, match="sensor_reduction"):
        reduce_sensors(m, "median")
    zero = Metrics(*(torch.zeros(1, 3) for _ in range(3)))
    for name in REWARD_FORMS:
        assert torch.isfinite(Reward(load_reward_config(name)).score(zero)).all()


def test_termination_flags():
    cfg = TerminationConfig(0.01, 0.1, 0.1, 1.0, 5.0, 3.0, max_iterations=10)
    good = Metrics(torch.tensor([[0.001, 0.002]]), torch.tensor([[0.05, 0.05]]), torch.tensor([[0.01, 0.02]]))
    mixed = Metrics(torch.tensor([[0.001, 0.02]]), torch.tensor([[0.05, 0.05]]), torch.tensor([[0.01, 0.02]]))
    hopeless = Metrics(torch.tensor([[0.5, 0.5]]), torch.tensor([[6.0, 0.5]]), torch.tensor([[0.5, 0.5]]))
    batch = Metrics(*(torch.cat([a, b, c]) for a, b, c in zip(good, mixed, hopeless, strict=True)))
    t = termination(batch, cfg, iteration=3)
    assert t.success.tolist() == [True, False, False]  # every sensor must pass every threshold
    assert t.failure.tolist() == [False, False, True]  # any sensor over any limit fails
    assert t.truncated.tolist() == [False, False, False]
    assert termination(batch, cfg, iteration=10).truncated.tolist() == [True, True, True]
    off = TerminationConfig(max_iterations=5)
    t = termination(batch, off, torch.tensor([1, 5, 9]))
    assert not t.success.any() and not t.failure.any() and t.truncated.tolist() == [False, True, True]


def test_termination_refuses_an_iteration_count_not_of_the_batch():
    """An ``iteration`` of another size than the batch failed in torch's ``expand`` (``[2]`` for a batch of 3), or was
    broadcast across the wrong dimension (``[4]`` for a ``[4, 4]`` batch: each row took the counts of the columns)."""
    from marlcrash.errors import PulseError

    cfg = TerminationConfig(max_iterations=5)
    three = Metrics(*(torch.full((3, 2), 0.1) for _ in range(3)))
    grid = Metrics(*(torch.full((4, 4, 2), 0.1) for _ in range(3)))
    for metrics, iteration in (
        (three, torch.tensor([1, 2])),
        (three, torch.tensor([[1], [2], [3]])),
        (grid, torch.tensor([1, 5, 9, 2])),
        (three, [1, 2, 3, 4]),
    ):
        with pytest.raises(PulseError, match=r"iteration.*expected a scalar or shape \(.*\) \(the batch\), got"):
            termination(metrics, cfg, iteration)
    assert termination(three, cfg, torch.tensor([1, 5, 9])).truncated.tolist() == [False, True, True]
    assert termination(grid, cfg, torch.full((4, 4), 5)).truncated.all()
    assert termination(three, cfg, torch.tensor(5)).truncated.all() and not termination(three, cfg, 4).truncated.any()


def test_reward_end_to_end_on_velocity_curves():
    """Metrics of a surrogate that moves toward the reference earn a positive reward under every form."""
    dt = 5e-4
    t = torch.arange(301, dtype=torch.float64) * dt
    ref = (11.1 * torch.cos(math.pi * t / 0.16)).clamp_min(-1.0).expand(2, 3, 301)
    far, near = ref * 1.2, ref * 1.05
    for name in ("paper_factor", "log_ratio"):
        rw = Reward(load_reward_config(name))
        m_far, m_near = rw.metrics(far, ref, dt=dt), rw.metrics(near, ref, dt=dt)
        assert m_far.area.shape == (2, 3)
        assert (rw(m_near, m_far) > 0).all() and (rw(m_far, m_near) < 0).all()
        assert rw.termination(rw.metrics(ref, ref, dt=dt), 0).success.all()


def test_a_reward_config_made_in_python_takes_the_defaults_of_the_form_it_names():
    """``RewardConfig(name="log_ratio")`` kept ``paper_factor``'s parameters as its default and failed on a key
    the user never set (``params.a: unknown key``)."""
    for name, form in REWARD_FORMS.items():
        rw = Reward(RewardConfig(name=name))
        assert rw.form.params == form.params_cls()
        assert RewardConfig(name=name).params == dataclasses.asdict(form.params_cls())
    assert Reward(RewardConfig(name="log_ratio", params={"w_dfd": 0.0})).form.params.w_dfd == 0.0
    assert RewardConfig() == load_reward_config("paper_factor")  # the shipped default is unchanged
    with pytest.raises(ConfigError, match=r"key 'params.a'"):  # another form's key is still refused
        Reward(RewardConfig(name="log_ratio", params={"a": 1.0}))


def test_a_reward_made_from_a_config_built_in_python_checks_every_key_of_it():
    """``Reward(cfg)`` checked only the form's params: a config made in Python with a Frechet time scale of 0 (the
    distance then ignores time), a success threshold above its failure limit or a misspelt sensor reduction was
    used as it was (the last failed at the first reward, not where it was set)."""
    from marlcrash.metrics import MetricsConfig

    bad = [
        (RewardConfig(metrics=MetricsConfig(dfd_time_scale=0.0)), "metrics.dfd_time_scale"),
        (RewardConfig(metrics=MetricsConfig(area_method="simpson")), "metrics.area_method"),
        (RewardConfig(termination=TerminationConfig(success_area=2.0, failure_area=1.0)), "termination.success_area"),
        (RewardConfig(name="log_ratio", sensor_reduction="median"), "sensor_reduction"),
        (RewardConfig(params={"a": "1"}), "params.a"),
    ]
    for cfg, key in bad:
        with pytest.raises(ConfigError) as e:
            Reward(cfg)
        assert e.value.key == key, (key, e.value)
    Reward(RewardConfig(name="log_ratio", params={"w_area": 2}))  # a good one still builds


def test_metrics_of_no_sensors_are_refused_by_name():
    """Metrics ``[B, 0]`` (no sensor compared) ended every episode in success at once (every one of no sensors is
    below its threshold), scored a NaN reward with ``mean`` and raised torch's amax error with ``max``."""
    from marlcrash.errors import PulseError

    none = Metrics(*(torch.zeros(2, 0) for _ in range(3)))
    for how in ("mean", "max"):
        with pytest.raises(PulseError, match="no sensors"):
            reduce_sensors(none, how)
        with pytest.raises(PulseError, match="no sensors"):
            Reward(RewardConfig(sensor_reduction=how))(none, None)
    with pytest.raises(PulseError, match="no sensors"):
        termination(none, TerminationConfig(success_area=1.0), 1)
    one = Metrics(*(torch.zeros(2, 1) for _ in range(3)))
    assert termination(one, TerminationConfig(success_area=1.0), 1).success.tolist() == [True, True]
