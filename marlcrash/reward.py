"""Rewards and termination from the similarity metrics (DESIGN 1.5, paper Eq. 12, Table 3).

A reward *form* maps the metrics of the current iteration ``t`` and of the
previous one ``t-1`` to one team reward per batch element:

- ``paper_factor`` (the paper's default): ``F = a/A + b/DFD + c/RMSE`` and
  ``r = F(t) - F(t-1)``, the improvement of the factor. ``F`` explodes near a
  perfect fit; ``min_metric`` floors each metric so it stays finite.
- ``log_ratio`` (well scaled): ``S = wA*A/A0 + wD*DFD/D0 + wR*RMSE/R0`` and
  ``r = log(S(t-1) / S(t))``; halving the weighted error earns ``log 2``
  whatever its size.
- ``neg_weighted_sum``: ``r = -S(t)``, a dense state reward (no difference).

Metrics arrive per sensor, ``[*batch, n_sensors]``; they are combined over the
sensors (``mean`` or ``max``) before the form is applied. Each form has a YAML
file ``configs/reward/<name>.yaml`` (:func:`load_reward_config`) whose
``params`` fill the form's parameter dataclass.

Termination (:func:`termination`): success when every metric of every sensor
is below its success threshold; failure when any metric of any sensor is above
its failure limit (a hopeless state); truncation after ``max_iterations``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar, Literal, NamedTuple

import torch

from marlcrash.config import (
    MAX_STEPS,
    checked,
    config_dir,
    from_dict,
    load_config,
    load_yaml,
    require,
    require_complete,
)
from marlcrash.errors import ConfigError, PulseError
from marlcrash.metrics import Metrics, MetricsConfig, compute_metrics


def paper_factor(
    area: torch.Tensor | float,
    dfd: torch.Tensor | float,
    rmse: torch.Tensor | float,
    a: float = 1.0,
    b: float = 1.0,
    c: float = 1.0,
) -> torch.Tensor:
    """The paper's reward factor ``a/A + b/DFD + c/RMSE`` (Table 3 uses ``a = b = c = 1``), elementwise."""
    area, dfd, rmse = (
        torch.as_tensor(x, dtype=torch.float64) if not torch.is_tensor(x) else x for x in (area, dfd, rmse)
    )
    return a / area + b / dfd + c / rmse


def _some_sensors(metrics: Metrics) -> Metrics:
    """``metrics`` unless they are ``[*batch, 0]``, of no sensors: a :class:`PulseError` (every one of no sensors
    met the success thresholds, and their mean was NaN)."""
    if metrics.area.dim() and metrics.area.shape[-1] == 0:
        raise PulseError(f"expected metrics per sensor [*batch, n_sensors], got no sensors (shape "
                         f"{tuple(metrics.area.shape)}); compare at least one sensor")  # fmt: skip
    return metrics


def reduce_sensors(metrics: Metrics, how: str) -> Metrics:
    """Combine ``[*batch, n_sensors]`` metrics over the last dimension: ``mean`` or ``max``."""
    metrics = _some_sensors(metrics)
    if how == "mean":
        return Metrics(*(m.mean(-1) for m in metrics))
    if how == "max":
        return Metrics(*(m.amax(-1) for m in metrics))
    raise ConfigError(f"expected 'mean' or 'max', got {how!r}", key="sensor_reduction")


# ------------------------------------------------------------------------------------- reward forms

MAX_REWARD_WEIGHT = 1e6
"""Largest weight of a metric in a reward form (``a``, ``b``, ``c``, ``w_*``) [-]. With :data:`MIN_REWARD_SCALE` and
:data:`MIN_METRIC_FLOOR` it keeps every score finite in float32 (at most about 1e18 for velocity errors of 100 m/s);
``w_area: 1e308`` made ``w * A / A0`` inf, and the reward NaN, without a word."""

MIN_REWARD_SCALE = 1e-6
"""Smallest typical metric size ``area_scale``, ``dfd_scale``, ``rmse_scale`` of a weighted sum [SI unit of the
metric]: a thousandth of the paper's smallest success threshold (0.0015 m)."""

MIN_METRIC_FLOOR = 1e-12
"""Smallest ``min_metric`` of ``paper_factor`` [SI unit of the metric]: 1e-40 is 0 in float32, and a perfect fit's
reciprocal inf."""


def require_weights(params: Any, keys: tuple[str, ...], prefix: str = "params.") -> None:
    """Refuse, naming ``<prefix><key>``, a metric weight of ``params`` outside ``[0, MAX_REWARD_WEIGHT]``."""
    for k in keys:
        v = getattr(params, k)
        require(0 <= v <= MAX_REWARD_WEIGHT, f"{prefix}{k}",
                f"expected a weight in [0, {MAX_REWARD_WEIGHT:g}] (MAX_REWARD_WEIGHT: a larger one overflows the "
                f"reward to inf), got {v}")  # fmt: skip


def require_scales(params: Any, keys: tuple[str, ...], prefix: str = "params.") -> None:
    """Refuse, naming ``<prefix><key>``, a metric scale (divisor) of ``params`` below ``MIN_REWARD_SCALE``."""
    for k in keys:
        v = getattr(params, k)
        require(v >= MIN_REWARD_SCALE, f"{prefix}{k}",
                f"must be > 0, at least {MIN_REWARD_SCALE:g} (MIN_REWARD_SCALE: the reward divides by it and "
                f"overflows to inf), got {v}")  # fmt: skip


@dataclass
class PaperFactorParams:
    """Parameters of ``paper_factor`` (weights of the reciprocal metrics, and their floor)."""

    a: float = 1.0
    b: float = 1.0
    c: float = 1.0
    min_metric: float = 1e-6

    def validate(self) -> None:
        """Weights in [0, MAX_REWARD_WEIGHT] and not all 0; the floor >= MIN_METRIC_FLOOR."""
        require_weights(self, ("a", "b", "c"))
        require(self.a + self.b + self.c > 0, "params", "at least one of a, b, c must be > 0")
        require(self.min_metric >= MIN_METRIC_FLOOR, "params.min_metric",
                f"must be >= {MIN_METRIC_FLOOR:g} (MIN_METRIC_FLOOR: the reciprocal of a smaller floor overflows "
                f"float32), got {self.min_metric}")  # fmt: skip


@dataclass
class WeightedSumParams:
    """Parameters of ``neg_weighted_sum`` (and the base of ``log_ratio``'s): ``S = sum_k w_k * metric_k / scale_k``."""

    w_area: float = 1.0
    w_dfd: float = 1.0
    w_rmse: float = 1.0
    area_scale: float = 0.02
    dfd_scale: float = 0.4
    rmse_scale: float = 0.25

    def validate(self) -> None:
        """Weights in [0, MAX_REWARD_WEIGHT] and not all 0; scales >= MIN_REWARD_SCALE."""
        require_weights(self, ("w_area", "w_dfd", "w_rmse"))
        require(self.w_area + self.w_dfd + self.w_rmse > 0, "params", "at least one weight must be > 0")
        require_scales(self, ("area_scale", "dfd_scale", "rmse_scale"))

    def weighted_sum(self, m: Metrics) -> torch.Tensor:
        """``S = wA*A/A0 + wD*DFD/D0 + wR*RMSE/R0``, elementwise."""
        return (
            self.w_area * m.area / self.area_scale
            + self.w_dfd * m.dfd / self.dfd_scale
            + self.w_rmse * m.rmse / self.rmse_scale
        )


@dataclass
class LogRatioParams(WeightedSumParams):
    """Parameters of ``log_ratio``: those of the weighted sum, and ``eps > 0`` added to it before the logarithm
    (``neg_weighted_sum`` takes no logarithm and no ``eps``)."""

    eps: float = 1e-9

    def validate(self) -> None:
        """As :meth:`WeightedSumParams.validate`, and ``eps > 0``: with ``eps = 0`` a perfect fit (``S = 0``) would
        score ``+inf``, and its reward and the next step's (``inf - inf``) would reach the PPO loss as inf and NaN."""
        super().validate()
        require(self.eps > 0, "params.eps", f"must be > 0 for log_ratio (log(S + eps) at S = 0), got {self.eps}")


class RewardForm(ABC):
    """A reward form: ``score`` of one iteration's metrics, and the reward from two iterations.

    Subclasses set ``name``, ``params_cls`` and implement :meth:`score`; the reward is the
    improvement of the score (DESIGN 1.5) unless a form overrides :meth:`reward`. The fields of ``params_cls`` are
    the options the form takes, each one used by it: any other is refused (:func:`form_params`).
    Metrics passed here are already combined over sensors (``[*batch]``).
    """

    name: ClassVar[str]
    params_cls: ClassVar[type]

    def __init__(self, params: Any):
        self.params = params

    @abstractmethod
    def score(self, m: Metrics) -> torch.Tensor:
        """A quality of one iteration's fit, higher is better, ``[*batch]``."""

    def reward(self, m: Metrics, prev: Metrics | None) -> torch.Tensor:
        """Reward ``[*batch]`` for reaching ``m`` from ``prev``: ``score(m) - score(prev)`` (zero at the first step)."""
        s = self.score(m)
        return torch.zeros_like(s) if prev is None else s - self.score(prev)


class PaperFactor(RewardForm):
    """``r = F(t) - F(t-1)`` with ``F = a/A + b/DFD + c/RMSE`` (metrics floored at ``min_metric``)."""

    name = "paper_factor"
    params_cls = PaperFactorParams

    def score(self, m: Metrics) -> torch.Tensor:
        """The factor ``F``."""
        f = self.params
        lo = f.min_metric
        return paper_factor(m.area.clamp_min(lo), m.dfd.clamp_min(lo), m.rmse.clamp_min(lo), f.a, f.b, f.c)


class LogRatio(RewardForm):
    """``r = log(S(t-1) / S(t))`` of the weighted, normalised metric sum ``S``."""

    name = "log_ratio"
    params_cls = LogRatioParams

    def score(self, m: Metrics) -> torch.Tensor:
        """``-log(S + eps)``."""
        return -torch.log(self.params.weighted_sum(m) + self.params.eps)


class NegWeightedSum(RewardForm):
    """``r = -S(t)``: a dense reward on the state, not on the improvement."""

    name = "neg_weighted_sum"
    params_cls = WeightedSumParams

    def score(self, m: Metrics) -> torch.Tensor:
        """``-S``."""
        return -self.params.weighted_sum(m)

    def reward(self, m: Metrics, prev: Metrics | None) -> torch.Tensor:
        """``-S(t)`` (``prev`` is not used)."""
        return self.score(m)


REWARD_FORMS: dict[str, type[RewardForm]] = {c.name: c for c in (PaperFactor, LogRatio, NegWeightedSum)}
"""Reward forms by name; each has ``configs/reward/<name>.yaml``."""


def _form_class(name: str, key: str = "name") -> type[RewardForm]:
    if name not in REWARD_FORMS:
        raise ConfigError(f"unknown reward form {name!r}; known forms: {sorted(REWARD_FORMS)}", key=key)
    return REWARD_FORMS[name]


def require_reward(name: str, key: str) -> None:
    """Refuse, naming ``key`` (the setting that names the reward, for a schema's ``validate()``), a reward that is
    neither a registered form nor a reward config file (``.yaml``, read where the reward is built)."""
    if Path(name).suffix not in (".yaml", ".yml"):
        _form_class(name, key)


def form_params(form: type[RewardForm], params: dict[str, Any]) -> Any:
    """``params`` as ``form``'s parameter dataclass, checked like config keys (``params.<key>``).

    Raises:
        ConfigError: an option the form does not take (an unused ``eps`` of ``neg_weighted_sum`` was accepted and did
            nothing), naming the form and the options it takes; a bad value.
    """
    options = sorted(f.name for f in fields(form.params_cls))
    for k in params:
        if k not in options:
            raise ConfigError(f"reward form {form.name!r} takes no option {k!r}; its options: {options}",
                              key=f"params.{k}")  # fmt: skip
    return from_dict(form.params_cls, params, prefix="params")


def get_reward(name: str, **params: Any) -> RewardForm:
    """A reward form by name, with parameters (checked like config keys; defaults otherwise).

    Raises:
        ConfigError: unknown name (the message lists the known ones), an option the form does not take or a bad
            parameter.
    """
    cls = _form_class(name)
    return cls(form_params(cls, params))


# ------------------------------------------------------------------------------------------- configs


@dataclass
class TerminationConfig:
    """Episode ends (DESIGN 1.5); a ``None`` threshold or limit is not checked.

    Attributes:
        success_area, success_dfd, success_rmse: success when every sensor is below all of these [SI].
        failure_area, failure_dfd, failure_rmse: failure when any sensor exceeds any of these [SI].
        max_iterations: truncation after this many iterations.
    """

    success_area: float | None = None
    success_dfd: float | None = None
    success_rmse: float | None = None
    failure_area: float | None = None
    failure_dfd: float | None = None
    failure_rmse: float | None = None
    max_iterations: int = 50

    def validate(self) -> None:
        """Thresholds > 0, each success threshold below its failure limit, max_iterations in [1, MAX_STEPS]."""
        for metric in ("area", "dfd", "rmse"):
            lo, hi = getattr(self, f"success_{metric}"), getattr(self, f"failure_{metric}")
            for k, v in ((f"success_{metric}", lo), (f"failure_{metric}", hi)):
                require(v is None or v > 0, f"termination.{k}", f"must be > 0 or null, got {v}")
            require(
                lo is None or hi is None or lo < hi,
                f"termination.success_{metric}",
                f"must be below failure_{metric}, got {lo} >= {hi}",
            )
        require(1 <= self.max_iterations <= MAX_STEPS, "termination.max_iterations",
                f"must be in [1, 2**63 - 1] (MAX_STEPS), got {self.max_iterations}")  # fmt: skip


def shipped_termination() -> TerminationConfig:
    """The ``termination`` block of the shipped reward and env files: the default of :class:`RewardConfig` and
    :class:`~marlcrash.envs.core.EnvConfig` made in Python (``tests/test_config_defaults.py`` keeps it equal to the
    files). A bare ``TerminationConfig()`` checks nothing but the iteration limit."""
    return TerminationConfig(
        success_area=0.002, success_dfd=0.05, success_rmse=0.03, failure_area=1.0, failure_dfd=10.0, failure_rmse=6.0
    )


@dataclass
class RewardConfig:
    """One reward setup: the form and its parameters, how metrics are measured, termination.

    Attributes:
        name: a key of :data:`REWARD_FORMS`.
        sensor_reduction: ``mean`` or ``max`` over sensors before the form.
        params: the form's parameters (keys of its parameter dataclass); keys left out take the named
            form's defaults.
        metrics: how A, DFD and RMSE are computed.
        termination: success/failure thresholds and the iteration limit.
    """

    name: str = "paper_factor"
    sensor_reduction: Literal["mean", "max"] = "mean"
    params: dict[str, float] = field(default_factory=dict)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    termination: TerminationConfig = field(default_factory=shipped_termination)

    def __post_init__(self) -> None:
        # the defaults of the form named, not of paper_factor: RewardConfig(name="log_ratio") failed on params.a
        form = REWARD_FORMS.get(self.name) if isinstance(self.name, str) else None
        if form is not None and isinstance(self.params, dict):
            self.params = {**asdict(form.params_cls()), **self.params}

    def validate(self) -> None:
        """Check the name is registered and the params fit the form."""
        form_params(_form_class(self.name), self.params)


def reward_config_path(name: str) -> Path:
    """``configs/reward/<name>.yaml``."""
    return config_dir() / "reward" / f"{name}.yaml"


def load_reward_config(name_or_path: str | Path, overrides: dict[str, Any] | None = None) -> RewardConfig:
    """Load a :class:`RewardConfig` by form name (``configs/reward/<name>.yaml``) or from a file."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        _form_class(str(name_or_path))
        path = reward_config_path(str(name_or_path))
    # params is a mapping to the schema, so an override of it as a mapping replaced the file's whole block: the
    # parameters it left out took the code's defaults ({'params': {'a': 2}} reset the file's b: 3 to 1); key by key
    overrides = dict(overrides or {})
    if isinstance(overrides.get("params"), dict):
        spread = {f"params.{k}": v for k, v in overrides.pop("params").items()}
        overrides = {**spread, **overrides}  # a dotted params.<k> given beside it wins
    cfg = load_config(RewardConfig, path, overrides, complete=True)
    # params is a mapping to the schema, so the completeness check stops at it; the form's parameters left out would
    # take the code's defaults (RewardConfig fills them in)
    given = load_yaml(path).get("params")
    given = dict(given) if isinstance(given, dict) else {}
    for key, value in overrides.items():
        if key.startswith("params."):
            given[key[len("params.") :]] = value
    form = REWARD_FORMS.get(cfg.name)
    if form is not None:
        require_complete(form.params_cls, given, path, "params.", f" (a parameter of the {cfg.name!r} form)")
    return cfg


class Termination(NamedTuple):
    """Episode-end flags, each ``[*batch]`` bool."""

    success: torch.Tensor
    failure: torch.Tensor
    truncated: torch.Tensor


def termination(metrics: Metrics, cfg: TerminationConfig, iteration: int | torch.Tensor) -> Termination:
    """Success, failure and truncation flags from per-sensor metrics ``[*batch, n_sensors]``.

    Args:
        metrics: per-sensor metrics.
        cfg: thresholds and limits.
        iteration: iterations done so far (scalar or ``[*batch]``).

    Returns:
        :class:`Termination`; ``success`` wins over ``failure`` (they cannot both hold when
        every success threshold is below its failure limit).

    Raises:
        PulseError: metrics of no sensors (``[*batch, 0]``); an ``iteration`` neither a scalar nor ``[*batch]``.
    """
    ref = _some_sensors(metrics).area
    success = torch.ones(ref.shape[:-1], dtype=torch.bool, device=ref.device)
    failure = torch.zeros_like(success)
    checked = False
    for metric, value in zip(("area", "dfd", "rmse"), metrics, strict=True):
        lo, hi = getattr(cfg, f"success_{metric}"), getattr(cfg, f"failure_{metric}")
        if lo is not None:
            success = success & (value < lo).all(-1)
            checked = True
        if hi is not None:
            failure = failure | (value > hi).any(-1)
        failure = failure | value.isnan().any(-1)  # a NaN fit is no fit: the episode fails (NaN > hi is False)
    if not checked:
        success = torch.zeros_like(success)
    it = torch.as_tensor(iteration, device=ref.device)
    if it.dim() and it.shape != success.shape:  # torch's expand failed naming no argument, or broadcast the counts
        raise PulseError(f"iteration: expected a scalar or shape {tuple(success.shape)} (the batch), got shape "
                         f"{tuple(it.shape)}")  # fmt: skip
    truncated = (it >= cfg.max_iterations).expand(success.shape).clone()
    return Termination(success=success, failure=failure & ~success, truncated=truncated)


class Reward:
    """A reward config made callable: metrics, reward and termination in one object.

    Example::

        rw = Reward(load_reward_config("log_ratio"))
        m = rw.metrics(v_est, v_ref, dt=5e-4)          # [B, n_sensors] each
        r = rw(m, m_prev)                               # [B]
        done = rw.termination(m, iteration)
    """

    def __init__(self, cfg: RewardConfig):
        # a config made in Python skipped the loader's checks: a Frechet time scale of 0 or a success threshold
        # above its failure limit was used as it was
        self.cfg = cfg = checked(cfg)
        self.form = get_reward(cfg.name, **cfg.params)

    def metrics(self, q: torch.Tensor, p: torch.Tensor, time: torch.Tensor | None = None, *, dt=None) -> Metrics:
        """Per-sensor metrics of estimate ``q [..., K, T]`` against reference ``p`` (see ``compute_metrics``)."""
        return compute_metrics(q, p, time, dt=dt, config=self.cfg.metrics)

    def score(self, metrics: Metrics) -> torch.Tensor:
        """The form's score ``[*batch]`` of per-sensor metrics."""
        return self.form.score(reduce_sensors(metrics, self.cfg.sensor_reduction))

    def __call__(self, metrics: Metrics, prev: Metrics | None) -> torch.Tensor:
        """Team reward ``[*batch]`` for per-sensor metrics ``metrics`` after ``prev``."""
        how = self.cfg.sensor_reduction
        return self.form.reward(reduce_sensors(metrics, how), None if prev is None else reduce_sensors(prev, how))

    def termination(self, metrics: Metrics, iteration: int | torch.Tensor) -> Termination:
        """Episode-end flags (see :func:`termination`)."""
        return termination(metrics, self.cfg.termination, iteration)
