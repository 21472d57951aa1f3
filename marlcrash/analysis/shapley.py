"""Cooperative-game attribution over batched value functions: Shapley values and one-at-a-time effects.

A *game* here is a batched value function ``value(masks) -> values``: ``masks [C, n]`` bool, one row per
coalition (``True``: the player takes part), and ``values [C, Q]`` float64, ``Q`` quantities measured for each
coalition at once (for marlcrash: every metric of every sensor, from one batched simulation). Everything
below asks the game for coalitions in batches and never loops over players in Python.

- :func:`exact_shapley`: every one of the ``2**n`` coalitions; the Shapley value of player ``i`` is
  ``sum over S not containing i of |S|! (n - |S| - 1)! / n! * (v(S + i) - v(S))``.
- :func:`sampled_shapley`: random orderings of the players (Castro, Gomez, Tejada 2009), drawn in antithetic
  pairs (an ordering and its reverse); each ordering costs ``n + 1`` coalitions, shared ones are asked once.
  Returns the standard error of every estimate: the spread (ddof 1) of the pairs' means, the independent draws,
  over the square root of their number. It is 0 where every marginal of the player was the same and equals its
  add-one and leave-one-out effects (asked for besides, ``2 n`` coalitions: consistent with a null or additive player,
  whose estimate is exact) and for 2 players (the one pair is every ordering), and NaN (unavailable) where the
  sampled marginals agree but an end effect differs (a player that is never pivotal in the few orderings drawn: of
  5 players worth 1 only when players 0, 1 and 2 all take part, 4 orderings gave one of those 0 +- 0 against its
  1/3 in 51 of 200 seeds), where the
  marginals differ yet every pair's mean agrees: with few pairs of few players that happens by chance (an end of an
  ordering is an end of its reverse, so 2 pairs of 3 players give an end player one value), and the estimate may be
  far off while the spread of the draws is 0. So is one whose every pair splits the other players around it alike
  (its predecessors and its successors, as one unordered pair of sets): its pairs agree whatever the game.
- :func:`one_at_a_time`: leave-one-out (``v(N) - v(N - i)``) and add-one (``v({i}) - v({})``) effects.

Both Shapley estimates satisfy ``sum_i phi_i = v(N) - v({})`` exactly (efficiency; the sampled ones too, because
every ordering's marginals telescope). The one-at-a-time effects need not add up to it where players interact: a
bonus that two players earn only together is in the leave-one-out effect of each and in the add-one effect of neither.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable
from dataclasses import dataclass
from typing import SupportsIndex, cast

import numpy as np
import torch

ValueFn = Callable[[torch.Tensor], torch.Tensor]
"""``value(masks [C, n] bool) -> [C, Q]`` float64."""

MAX_EXACT_PLAYERS = 16
"""Most players :func:`exact_shapley` enumerates (65,536 coalitions)."""

STDERR_RTOL = 1e-9
"""Marginals (and antithetic pairs' means) of a player that differ by no more than this fraction of the largest value
of the quantity count as equal in :func:`sampled_shapley`'s test of whether a standard error can be estimated."""


@dataclass
class Attribution:
    """Per-player attributions of a game.

    Attributes:
        phi: ``[n, Q]`` the attribution of every player to every quantity.
        stderr: ``[n, Q]`` standard error of a sampled estimate (NaN where the sample cannot tell it:
            :func:`sampled_shapley`), ``None`` when exact.
        empty, full: ``[Q]`` the values of the empty and of the grand coalition.
        n_evaluations: coalitions the game was asked for.
        table: ``[2**n, Q]`` the value of every coalition (row ``c`` as in :func:`all_coalitions`) when exact.
    """

    phi: torch.Tensor
    stderr: torch.Tensor | None
    empty: torch.Tensor
    full: torch.Tensor
    n_evaluations: int
    table: torch.Tensor | None = None


def _integer(x: object) -> int | None:
    """``x`` as a Python int where it is an integer of any kind (``int``, a numpy or a 0-d torch integer), else None."""
    if isinstance(x, bool):
        return None
    try:
        return operator.index(cast(SupportsIndex, x))  # any object: a TypeError below is the answer
    except TypeError:
        return None


def _checked(x: object, ok: Callable[[int], bool], message: str) -> int:
    """``x`` as an int where it is an integer (:func:`_integer`) that passes ``ok``, else :class:`ValueError`."""
    k = _integer(x)
    if k is None or not ok(k):
        raise ValueError(message)
    return k


def _check_players(n: int) -> int:
    """``n`` as an int >= 1 (a numpy integer, e.g. a count of moving agents, is one), else :class:`ValueError`."""
    return _checked(n, lambda k: k >= 1, f"expected a number of players >= 1, got {n!r}")


def check_permutations(n_permutations: int) -> int:
    """``n_permutations`` as an int; :class:`ValueError` unless an even number >= 4 (:func:`sampled_shapley`)."""
    return _checked(
        n_permutations,
        lambda k: k >= 4 and k % 2 == 0,
        f"n_permutations: expected an even number of orderings >= 4 (antithetic pairs), got {n_permutations!r}",
    )


def check_exact_max(exact_max: int) -> int:
    """``exact_max`` as an int; :class:`ValueError` naming it unless an integer of 0 to :data:`MAX_EXACT_PLAYERS`
    (the most moving players whose coalitions are all enumerated)."""
    return _checked(
        exact_max,
        lambda k: 0 <= k <= MAX_EXACT_PLAYERS,
        f"exact_max: expected an integer of 0 to {MAX_EXACT_PLAYERS} agents, got {exact_max!r}",
    )


def check_seed(seed: int) -> int:
    """``seed`` as an int; :class:`ValueError` naming it unless an integer >= 0 (the orderings' generator's seed)."""
    return _checked(seed, lambda k: k >= 0, f"seed: expected an integer seed >= 0, got {seed!r}")


def check_batch(batch: int) -> int:
    """``batch`` as an int; :class:`ValueError` naming it unless an integer >= 1 (coalitions per call of a game)."""
    return _checked(
        batch,
        lambda k: k >= 1,
        f"batch: expected a number of coalitions >= 1 per call of the value function, got {batch!r}",
    )


def from_table(table: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Leave-one-out and add-one effects ``[n, Q]`` read from an exact table ``[2**n, Q]`` (:class:`Attribution`)."""
    n = round(math.log2(table.shape[0]))
    if 2**n != table.shape[0]:
        raise ValueError(f"expected a table of 2**n coalitions, got {table.shape[0]} rows")
    bits = 1 << torch.arange(n)
    full = 2**n - 1
    return table[full] - table[full ^ bits], table[bits] - table[0]


def evaluate(value: ValueFn, masks: torch.Tensor, batch: int) -> torch.Tensor:
    """``value`` of every row of ``masks [C, n]``, asked ``batch`` rows at a time; ``[C, Q]`` float64.

    Raises:
        ValueError: a bad batch size, or a value function that returns another number of rows or a non-2D tensor.
    """
    batch = check_batch(batch)
    out = []
    for i in range(0, masks.shape[0], batch):
        chunk = masks[i : i + batch]
        v = torch.as_tensor(value(chunk), dtype=torch.float64)
        if v.dim() != 2 or v.shape[0] != chunk.shape[0]:
            raise ValueError(f"the value function returned shape {tuple(v.shape)} for {chunk.shape[0]} coalitions; "
                             "expected [coalitions, quantities]")  # fmt: skip
        out.append(v)
    return torch.cat(out)


def all_coalitions(n: int) -> torch.Tensor:
    """``[2**n, n]`` bool: row ``c`` holds player ``i`` when bit ``i`` of ``c`` is set."""
    n = _check_players(n)
    c = torch.arange(2**n, dtype=torch.int64)
    return ((c[:, None] >> torch.arange(n)) & 1).bool()


def exact_shapley(value: ValueFn, n: int, *, batch: int = 256) -> Attribution:
    """Shapley values from all ``2**n`` coalitions (``n <= MAX_EXACT_PLAYERS``).

    Raises:
        ValueError: ``n`` outside ``[1, MAX_EXACT_PLAYERS]``, or ``batch`` not an integer >= 1.
    """
    n = _check_players(n)
    batch = check_batch(batch)
    if n > MAX_EXACT_PLAYERS:
        raise ValueError(f"exact Shapley values of {n} players need 2**{n} coalitions; at most {MAX_EXACT_PLAYERS} "
                         "players are enumerated (use sampled_shapley)")  # fmt: skip
    masks = all_coalitions(n)
    v = evaluate(value, masks, batch)  # [2**n, Q]
    size = masks.sum(1)  # [2**n]
    # weight of a coalition S without i: |S|! (n - |S| - 1)! / n!
    w = torch.tensor([math.factorial(s) * math.factorial(n - s - 1) / math.factorial(n) for s in range(n)],
                     dtype=torch.float64)  # fmt: skip
    idx = torch.arange(2**n)
    phi = torch.zeros(n, v.shape[1], dtype=torch.float64)
    for i in range(n):  # n passes over the table, each vectorized over its 2**(n-1) coalitions
        without = idx[~masks[:, i]]
        phi[i] = (w[size[without]][:, None] * (v[without | (1 << i)] - v[without])).sum(0)
    return Attribution(phi=phi, stderr=None, empty=v[0], full=v[-1], n_evaluations=int(masks.shape[0]), table=v)


def sampled_shapley(value: ValueFn, n: int, n_permutations: int, *, seed: int = 0, batch: int = 256) -> Attribution:
    """Shapley values estimated from ``n_permutations`` random orderings (antithetic pairs).

    Args:
        value: the game.
        n: players.
        n_permutations: orderings, an even number >= 4 (each ordering and its reverse; two pairs at least, for a
            standard error).
        seed: seed of the orderings.
        batch: coalitions per call of ``value``.

    Returns:
        The estimates and their standard errors (over the antithetic pairs' means; NaN where the pairs agree while
        the marginals, or the player's add-one and leave-one-out effects, differ, so the sample cannot tell the
        spread: module docstring).

    Raises:
        ValueError: fewer than 4 or an odd number of orderings, a ``seed`` that is not an integer >= 0, or a
            ``batch`` that is not an integer >= 1.
    """
    n = _check_players(n)
    n_permutations = check_permutations(n_permutations)
    seed, batch = check_seed(seed), check_batch(batch)
    rng = np.random.default_rng(seed)
    half = np.stack([rng.permutation(n) for _ in range(n_permutations // 2)])
    perms = np.concatenate([half, half[:, ::-1]])  # [P, n]: pair p is rows p and p + P/2
    P = perms.shape[0]
    chain = np.zeros((P, n + 1, n), dtype=bool)  # prefixes: chain[p, j] holds the first j players of ordering p
    for j in range(n):
        chain[np.arange(P), j + 1 :, perms[:, j]] = True
    alone = np.eye(n, dtype=bool)  # {i} and N - i: each player's add-one and leave-one-out effects
    flat = np.concatenate([chain.reshape(-1, n), alone, ~alone])
    unique, inverse = np.unique(flat, axis=0, return_inverse=True)
    asked = evaluate(value, torch.as_tensor(unique), batch)[torch.as_tensor(inverse.reshape(-1))]
    v = asked[: P * (n + 1)].reshape(P, n + 1, -1)
    ends = torch.stack([asked[P * (n + 1) : -n] - v[0, 0], v[0, -1] - asked[-n:]])  # [2, n, Q]: add-one, leave-one-out
    marg = v[:, 1:] - v[:, :-1]  # [P, n, Q]: marginal of the j-th player of each ordering
    per_player = torch.zeros_like(marg)
    per_player[torch.arange(P)[:, None], torch.as_tensor(perms.copy())] = marg  # [P, player, Q]
    pairs = 0.5 * (per_player[: P // 2] + per_player[P // 2 :])  # [P/2, n, Q]
    phi = pairs.mean(0)
    stderr = pairs.std(0, unbiased=True) / math.sqrt(pairs.shape[0])
    if n <= 2:  # the one antithetic pair holds every ordering: the estimate is exact
        stderr = torch.zeros_like(phi)
    else:  # pairs that agree by the draw, not by the game, say nothing of the spread (module docstring)
        tol = STDERR_RTOL * v.abs().amax((0, 1)).clamp_min(torch.finfo(torch.float64).tiny)  # [Q]
        agree = (pairs.amax(0) - pairs.amin(0)) <= tol  # [n, Q]
        vary = (per_player.amax(0) - per_player.amin(0)) > tol
        off_end = ((ends - per_player[0]).abs() > tol).any(0)  # constant marginals the end effects contradict
        stderr = torch.where(agree & (vary | off_end | _one_split(chain, perms)[:, None]), torch.nan, stderr)
    empty = v[0, 0]
    return Attribution(phi=phi, stderr=stderr, empty=empty, full=v[0, -1], n_evaluations=int(unique.shape[0]))


def _one_split(chain: np.ndarray, perms: np.ndarray) -> torch.Tensor:
    """``[n]`` bool: every antithetic pair of ``perms [P, n]`` (prefixes ``chain [P, n + 1, n]``) splits the other
    players around player ``i`` alike (its predecessors in the ordering and those in the reverse, ``S`` and
    ``N - S - i``, as one unordered pair of sets): then every pair gives it one value, whatever the game."""
    P, n = perms.shape
    half = P // 2
    pos = np.argsort(perms[:half], axis=1)  # [H, n]: where player i stands in ordering p
    before = chain[np.arange(half)[:, None], pos]  # [H, n, n]: the players before i in ordering p
    after = ~before & ~np.eye(n, dtype=bool)[None]  # the players before i in the reverse
    first = np.where(np.arange(n) == 0, 1, 0)  # the lowest player other than i names the part it is in
    side = before[:, np.arange(n), first]  # [H, n]
    key = np.where(side[..., None], before, after)  # [H, n, n]: the part that holds that player
    return torch.as_tensor((key == key[:1]).all(axis=(0, 2)))


def one_at_a_time(value: ValueFn, n: int, *, batch: int = 256) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Leave-one-out and add-one effects from ``2 n + 2`` coalitions.

    Returns:
        ``(leave_one_out [n, Q], add_one [n, Q], values of (empty, full) [2, Q])``: ``v(N) - v(N - i)`` and
        ``v({i}) - v({})``.

    Raises:
        ValueError: ``n`` not an integer >= 1, or ``batch`` not an integer >= 1.
    """
    n = _check_players(n)
    batch = check_batch(batch)
    eye = torch.eye(n, dtype=torch.bool)
    masks = torch.cat([torch.zeros(1, n, dtype=torch.bool), torch.ones(1, n, dtype=torch.bool), ~eye, eye])
    v = evaluate(value, masks, batch)
    empty, full = v[0], v[1]
    return full - v[2 : 2 + n], v[2 + n :] - empty, torch.stack([empty, full])
