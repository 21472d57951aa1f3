"""Pictures of per-agent contributions: bars per agent, and the cells in 3D coloured by their agent's share."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from marlcrash.analysis.contributions import Contributions, quantity_unit
from marlcrash.calibrate.problem import CalibrationProblem
from marlcrash.cells.plot import draw_vehicle_frame
from marlcrash.outputs import save_figure


def plot_contributions(contrib: Contributions, path: str | Path, quantities: list[str] | None = None) -> Path:
    """Horizontal bars of the moving agents' Shapley values (when sampled, with whiskers of one standard error, and
    ``s.e. n/a`` beside a bar whose standard error the orderings cannot tell) and the leave-one-out effects, one
    panel per quantity (default: ``score`` and every sensor's area), each in its unit. Written
    atomically to ``path``, in the format its suffix names (PNG where it has none).

    Raises:
        ValueError: an empty list of quantities or an unknown one (:meth:`Contributions.selected`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    qs = contrib.selected(quantities)
    cols = [contrib.column(q) for q in qs]
    agents = [a for a, _ in contrib.ranking(qs[0])]
    rows = [contrib.agents.index(a) for a in agents]
    y = np.arange(len(agents))
    fig, axes = plt.subplots(1, len(qs), figsize=(3.6 * len(qs) + 1.5, 0.32 * len(agents) + 1.6), sharey=True,
                             squeeze=False)  # fmt: skip
    for ax, q, j in zip(axes[0], qs, cols, strict=True):
        phi = contrib.shapley[rows, j].numpy()
        err = None if contrib.exact else contrib.shapley_stderr[rows, j].numpy()
        good = phi > 0 if q == "score" else phi < 0
        label = "Shapley" if err is None else "Shapley ± one standard error"
        ax.barh(y, phi, xerr=err, color=np.where(good, "tab:green", "tab:red"), alpha=0.8, label=label)
        for k in [] if err is None else np.flatnonzero(np.isnan(err)):  # no whisker drawn: not an exact value
            ax.annotate("s.e. n/a", (phi[k], y[k]), xytext=(3 if phi[k] >= 0 else -3, 0), textcoords="offset points",
                        ha="left" if phi[k] >= 0 else "right", va="center", fontsize=6)  # fmt: skip
        ax.plot(contrib.leave_one_out[rows, j].numpy(), y, "k|", markersize=9, label="leave-one-out")
        ax.axvline(0.0, color="0.3", lw=0.8)
        change = float(contrib.calibrated[j] - contrib.initial[j])
        ax.set_title(f"{q}\n{float(contrib.initial[j]):.4g} -> {float(contrib.calibrated[j]):.4g} ({change:+.3g})",
                     fontsize=9)  # fmt: skip
        ax.set_xlabel(f"contribution [{quantity_unit(q)}]", fontsize=8)
        ax.grid(axis="x", alpha=0.3)
    axes[0, 0].set_yticks(y, agents, fontsize=8)
    axes[0, 0].invert_yaxis()
    axes[0, 0].legend(fontsize=7, loc="lower right")
    fig.suptitle("per-agent contributions (green: improves the fit)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_cells_by_contribution(
    problem: CalibrationProblem, contrib: Contributions, path: str | Path, quantity: str = "score"
) -> Path:
    """The cells in 3D (centroids, size by mass), coloured by their agent's Shapley value of ``quantity``;
    cells of no agent or of agents that did not move are grey. Improvement is green for every quantity. Written
    atomically to ``path``, in the format its suffix names (PNG where it has none).

    Raises:
        ValueError: ``contrib`` is not of the problem's agents (another layout: its values would colour the cells of
            other agents), or an unknown ``quantity``.
    """
    if list(contrib.agents) != list(problem.agent_names):
        raise ValueError(f"contrib: its {len(contrib.agents)} agents {contrib.agents} are not the "
                         f"{problem.n_agents} agents of the problem {list(problem.agent_names)}; expected the "
                         "contributions of a calibration of this problem (the same agent layout)")  # fmt: skip
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    j = contrib.column(quantity)
    cells = problem.cells
    agent = problem.layout.agent_of_cell.numpy()
    phi = contrib.shapley[:, j].numpy() * (1.0 if quantity == "score" else -1.0)  # > 0: improves
    value = np.where(agent >= 0, phi[np.clip(agent, 0, None)], np.nan)
    value[(agent >= 0) & ~contrib.players.numpy()[np.clip(agent, 0, None)]] = np.nan
    xyz = np.asarray(cells.centroid)
    size = 4 + 60 * np.sqrt(np.asarray(cells.mass) / max(float(np.max(cells.mass)), 1e-12))
    lim = float(np.nanmax(np.abs(value))) if np.isfinite(value).any() else 1.0
    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    grey = ~np.isfinite(value)
    ax.scatter(xyz[grey, 0], xyz[grey, 1], xyz[grey, 2], s=size[grey] * 0.5, c="0.8", alpha=0.4, depthshade=False)
    sc = ax.scatter(xyz[~grey, 0], xyz[~grey, 1], xyz[~grey, 2], s=size[~grey], c=value[~grey], cmap="RdYlGn",
                    norm=TwoSlopeNorm(0.0, -lim or -1.0, lim or 1.0), depthshade=False)  # fmt: skip
    ax.set_xlabel("x (rearward) [m]")
    ax.set_ylabel("y (left) [m]")
    ax.set_zlabel("z (up) [m]")
    draw_vehicle_frame(ax)
    ax.set_box_aspect(np.ptp(xyz, axis=0) + 1e-3)
    ax.view_init(elev=25, azim=-125)
    what = "score" if quantity == "score" else f"-{quantity}"
    fig.colorbar(
        sc, ax=ax, shrink=0.6, label=f"agent's Shapley value of {what} [{quantity_unit(quantity)}] (> 0 improves)"
    )
    ax.set_title(f"cells coloured by their agent's contribution to {quantity}", fontsize=10)
    return save_figure(fig, path)
