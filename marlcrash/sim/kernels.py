"""Compiled no-grad fast path of the surrogate: one fused numba loop, parallel over batch chunks.

It performs the operations of :meth:`Surrogate._run_torch` (the tested, differentiable
reference) in the same order per element; only the summation order of scatters and of the
energy ledgers differs, so results agree to rounding (tested to 1e-6 relative).

Memory layout (what makes it fast): the batch is cut into chunks of ``lanes`` simulations
and every array is batch-innermost, ``[chunk, rows, lanes]``, so the inner loop over lanes is
SIMD vectors. A chunk's link data is stored link by link, ``[L, fields, lanes]``: one sequential
stream per step. Only the *current* properties are streamed (``H_*`` fields: compressive yield force,
stiffness, compliance, damping factor; the tensile yield force is a per-link ratio of the compressive one):
saturation is monotone, so when a cell bottoms out in a lane its out-links are densified for the rest of
that step (:func:`_densify`) and rewritten once to their dense values (:func:`_bottom_out`, from the cold
``C_*`` fields) instead of interpolating between intact and dense values in every step. Link stored
energy is summed at output steps only. ``lanes`` balances vector width against keeping both cores busy
and a chunk within the cache (:func:`default_lanes`); chunks run in parallel (``prange``).

Chunk width matters more than any other choice here (``benchmarks/bench_lanes.py``, table at
:data:`LANE_EFFICIENCY`). The per-chunk body is compiled ``noalias`` (:mod:`marlcrash.sim.noalias`), so a lane
loop starts without runtime overlap tests; since then 16 lanes are the fastest chunk in both precisions, 8 float64
lanes tie with them (16 float64 lanes 1.18x as fast per simulation as 32, 16 float32 lanes 1.28x as fast as 64, at
B = 256: the table's 0.85 and 0.78). Before, each link's lane loops paid about a hundred scalar instructions of such
tests, and only wide chunks (32 float64, 64 float32 lanes) amortized them. The link loop reads four property
streams and no per-link scalar inside the lane loop.

Energy ledgers without per-link work arrays: with ``r = v0 dt - ds`` the rearward increment
of a node in the frame moving at the impact speed, a link's work ``fbar (ds_dst - ds_src)``
equals ``fbar (r_src - r_dst)``. Summed over links this needs only node sums of the link
forces by source (``Fs``) and by destination (``Fd``): the total link work per step is
``-sum_i ds_i (flink_prev_i + flink_i) / 2`` with ``flink = Fs - Fd``, the input a cell
receives is ``sum Fdbar_c r_c`` and what it passes on is ``H_a = sum_{src=a} fbar r_dst``
(the only per-link term). These per-cell sums are accumulated only when per-cell energies are
requested: calibration records none, and skipping them ran 1.03x (0.996-1.099 over 6 interleaved rounds, B = 1024).
Node-level ledgers are kept in float64 even for a float32 simulation.
"""

from __future__ import annotations

import time

import numba
import numpy as np
import torch

from marlcrash.sim.noalias import njit_noalias
from marlcrash.sim.surrogate import LinkProps, SimResult, Surrogate, WallProps, load_case

_MODES = {"none": 0, "final": 1, "series": 2}
_BIG = 1e30  # yield force of a bottomed-out link [N] (as in the torch path)
_HUGE = 1e300  # stands in for an infinite saturation energy (cells without links) [J]

# Per-link fields read every step ("hot"), [chunk, L, N_HOT, lanes]: the element's *current* properties
# (compressive yield force, stiffness, compliance ``1 / k``, damping per unit elastic force change
# ``c / (k dt)``, relaxation factor). They start at the intact values and are rewritten once, lane by lane,
# when the source cell bottoms out (saturation is monotone), so the link loop does no interpolation and
# reads no dense-state fields. The tensile yield force is ``H_YU`` times the link's tension ratio (a
# per-link scalar, the same in every lane), ``BIG`` once the source cell bottomed out, not a stream of its own.
H_YU, H_K, H_IK, H_DC, H_Q = range(5)
N_HOT = 5
# Fields read only when the source cell bottoms out ("cold"), [chunk, L, N_COLD, lanes].
C_KD, C_IKD, C_QD = range(3)
N_COLD = 3
# Per-node property fields, [chunk, n, N_NODE, lanes].
W_ES, W_K, W_C, W_GAP, W_COV = range(5)
N_NODE = 5

KERNEL_SECONDS = [0.0]
"""Cumulative wall time spent inside the compiled kernel [s] (for overhead accounting in benchmarks)."""

LANE_EFFICIENCY = {
    "float64": {1: 0.22, 2: 0.34, 4: 0.73, 8: 0.99, 16: 1.0, 32: 0.85, 64: 0.76},
    "float32": {1: 0.13, 2: 0.20, 4: 0.33, 8: 0.80, 16: 1.0, 32: 0.91, 64: 0.78, 128: 0.73},
}
"""Per-simulation throughput of a chunk of this many lanes relative to the fastest width of the same dtype, measured
on the default car with the ``noalias`` kernel (2026-11-23): ``python benchmarks/bench_lanes.py --widths 1 2 4 8 16
32 64 128 --batch 256 --repeat 3 [--float32]`` (per-cell energies at the final step, 2 threads): float64 130 sims/s
at 16 lanes, 129 at 8, 111 at 32; float32 202 at 16, 198 at 32, 182 at 64. At B = 1024 (interleaved, 3 rounds) 16
float64 lanes ran 1.10-1.13x as fast as 32, and 16 float32 lanes 1.09-1.11x as fast as 64; at the main job's 48
simulations the width chosen from this table, 8 float64 lanes, ran 1.55-1.64x as fast as 32 (the choice before).
Re-measured the same day with the link update written out in the lane loop (:func:`_links`): float64 unchanged
within noise (136.3 sims/s at 8 lanes, 136.7 at 16, 113.7 at 32, best of 5), float32 the table above (244 sims/s
at 16 lanes, 222 at 32, 195 at 8, 192 at 64); the widths chosen stay the same."""

CHUNK_BYTES = 16 * 2**20
"""Largest estimated working set of one chunk [bytes] (:func:`chunk_bytes_per_lane`): two chunks in flight, one
per core, stay within this machine's 32 MB L3 cache. On the per-block uniform model (6891 cells) 8 lanes (about 15
MB per chunk) ran 1.49x as fast as 32 lanes (about 60 MB, before the ``noalias`` kernel); on the default car 32
lanes take about 6.5 MB."""

_FASTMATH = {"nsz", "arcp", "contract", "reassoc", "afn"}  # no nnan/ninf: BIG and saturation tests use huge values


def n_hot(relief: bool) -> int:
    """Hot link fields the kernel reads: the relaxation factor only with springback relief."""
    return N_HOT if relief else H_Q


def n_cold(relief: bool) -> int:
    """Cold link fields: the bottomed-out relaxation factor only with springback relief."""
    return N_COLD if relief else C_QD


def chunk_bytes_per_lane(n_links: int, n_cells: int, itemsize: int = 8) -> int:
    """Estimated bytes one lane of a chunk touches per step: about 7 values per link (hot properties, force,
    start force of a saturation crossing, contact opening, ledger force) and 26 per cell (state, node properties,
    ledgers, the two saturation-crossing bounds)."""
    return itemsize * (7 * int(n_links) + 26 * int(n_cells))


def default_lanes(batch: int, threads: int, bytes_per_lane: int = 0, dtype: str = "float64") -> int:
    """Simulations per chunk: the width that minimises the estimated wall time of ``batch`` simulations.

    Chunks run in parallel, ``threads`` at a time; a chunk of ``w`` lanes costs ``w / LANE_EFFICIENCY[dtype][w]``
    and the last chunk is padded. Wide chunks vectorise best, narrow ones keep both cores busy at small
    ``batch`` (e.g. 24 simulations: 6 chunks of 4 beat one chunk of 32 on one core). Widths whose chunk
    would exceed :data:`CHUNK_BYTES` (``w * bytes_per_lane``, see :func:`chunk_bytes_per_lane`) are left
    out, except one lane: large models stream from memory instead of cache when chunks are wide. ``dtype``
    (``float64`` or ``float32``) selects the efficiency table.
    """
    if dtype not in LANE_EFFICIENCY:
        raise ValueError(f"dtype must be one of {sorted(LANE_EFFICIENCY)}, got {dtype!r}")
    best, best_cost = 1, float("inf")
    for w, eff in LANE_EFFICIENCY[dtype].items():
        if w > 1 and w * bytes_per_lane > CHUNK_BYTES:
            continue
        chunks = -(-batch // w)
        rounds = -(-chunks // max(threads, 1))
        cost = rounds * w / eff
        if cost < best_cost - 1e-12:
            best, best_cost = w, cost
    return best


def lanes_for(batch: int, n_links: int, n_cells: int, dtype: str) -> int:
    """The chunk width :func:`run_numba` picks for ``batch`` simulations of a model of this size in ``dtype``."""
    per_lane = chunk_bytes_per_lane(n_links, n_cells, np.dtype(dtype).itemsize)
    return default_lanes(batch, numba.get_num_threads(), per_lane, dtype)


@numba.njit(cache=True, fastmath=_FASTMATH, inline="always")
def _links(
    P, lo, hi, gap, relief, ledger, src, dst, ds, f_el, o, yd, plastic, fs, fd, h_step, f_prev, step_in, trl, cst
):
    """Update links ``lo .. hi-1`` (all of one kind) in every lane and scatter their forces to the nodes.

    Plain links are elastic-plastic with tension up to ``tl P[H_YU]`` (``tl = trl[ll]``, the link's tension ratio)
    while intact, and up to ``BIG`` once their source cell has bottomed out (``P[H_YU]`` is then ``BIG``), as the
    torch path's tensile yield force (``tl BIG`` left links of tension ratio 0 unable to pull after densifying);
    gap (contact) links carry compression only once their opening ``o`` has closed. Springback relief (module doc
    of :mod:`marlcrash.sim.surrogate`): a link that has yielded (``yd``) and unloads (``|f_ret| < |f0|``, same sign)
    has its force scaled by its relaxation factor ``q <= 1``.

    ``gap``, ``relief`` and ``ledger`` are literal booleans at the call sites, so each loop is compiled for one
    link kind without a branch per lane; ``ledger`` adds the per-link term of the per-cell energies (``h_step``:
    this step's transmitted work by source cell, in the simulation's precision; needs ``f_prev``). Per-link
    scalars are read once per link, outside the lane loop: read inside it (``trl[ll]`` in every lane) the loop ran
    0.85x. The update is written out in the lane loop: the same arithmetic in a function inlined per lane (the
    kernel of commit ``a123cab``) gave the same outputs bit for bit at 0.68-0.77x the speed in float64 and
    0.50-0.58x in float32 (B = 1024 and 48, interleaved; README, Simulator speed).
    """
    CH = ds.shape[1]
    half, zero, big = cst[0], cst[1], cst[5]
    for ll in range(lo, hi):
        a = src[ll]
        c = dst[ll]
        tl = trl[ll]
        for j in range(CH):
            dd = ds[c, j] - ds[a, j]
            k = P[ll, H_K, j]
            ik = P[ll, H_IK, j]
            yu = P[ll, H_YU, j]
            f0 = f_el[ll, j]
            if gap:
                z = f0 * ik - o[ll, j] + dd
                f_tr = k * max(z, zero)
                o[ll, j] = max(-z, zero)
                f_ret = min(f_tr, yu)
            else:
                f_tr = f0 + k * dd
                f_ret = min(max(f_tr, -(big if yu >= big else yu * tl)), yu)
            f_new = f_ret
            if relief:
                y = max(yd[ll, j], cst[2] if f_tr != f_ret else zero)
                yd[ll, j] = y
                if y > zero and f_ret * f0 > zero and abs(f_ret) < abs(f0):
                    f_new = f_ret * P[ll, H_Q, j]
                plastic[a, j] += (f_ret * (f_tr - f_ret) + half * (f_ret * f_ret - f_new * f_new)) * ik
            else:
                plastic[a, j] += f_ret * (f_tr - f_ret) * ik
            f_el[ll, j] = f_new
            f_tot = f_new + P[ll, H_DC, j] * (f_ret - f0)  # with the damping of the elastic force change
            if gap:
                f_tot = max(f_tot, zero)  # a contact never pulls
            fs[a, j] += f_tot
            fd[c, j] += f_tot
            if ledger:
                h_step[a, j] += half * (f_prev[ll, j] + f_tot) * (step_in[j] - ds[c, j])
                f_prev[ll, j] = f_tot


@numba.njit(cache=True, fastmath=_FASTMATH, inline="always")
def _bottom_out(P, PC, i, j, out_ptr, out_idx, relief, cst):
    """Lane ``j`` of cell ``i`` has bottomed out: rewrite its out-links' hot fields to the dense state.

    The expressions are those of the torch path's interpolation ``x0 + sat (x_dense - x0)`` at ``sat = 1``
    (the yield force becomes ``BIG`` where the link has a share, and with it the tensile one, :func:`_links`;
    stiffness and compliance their dense values; the damping factor ``c / (k dt)`` follows the dense stiffness),
    evaluated once instead of every step.
    """
    one, zero, big = cst[2], cst[1], cst[5]
    for q in range(out_ptr[i], out_ptr[i + 1]):
        ll = out_idx[q]
        yc = P[ll, H_YU, j]
        P[ll, H_YU, j] = yc + one * (big - yc) if yc > zero else zero
        k0 = P[ll, H_K, j]
        P[ll, H_DC, j] = P[ll, H_DC, j] * PC[ll, C_IKD, j] * k0
        P[ll, H_K, j] = k0 + one * (PC[ll, C_KD, j] - k0)
        ik0 = P[ll, H_IK, j]
        P[ll, H_IK, j] = ik0 + one * (PC[ll, C_IKD, j] - ik0)
        if relief:
            q0 = P[ll, H_Q, j]
            P[ll, H_Q, j] = q0 + one * (PC[ll, C_QD, j] - q0)


@numba.njit(cache=True, fastmath=_FASTMATH, inline="always")
def _densify(
    P, PC, i, j, phi, out_ptr, out_idx, n_plain, dst, ds, f_el, f_start, fs, fd, ledger, h_step, f_prev, step_in, cst
):
    """Lane ``j`` of cell ``i`` bottomed out within this step, the last fraction ``phi`` of it past ``E_s``.

    Each out-link's force ``f_el`` moves ``phi`` of the way from this step's update toward the dense update
    ``f_start + k_dense dd`` (``f_start`` its force at the step's start, kept by :func:`_keep_start_forces`;
    module doc of :mod:`marlcrash.sim.surrogate`, "Saturation"), its damping likewise; node sums and ledgers
    take the same increment. Called before :func:`_bottom_out`, so ``P`` still holds the intact properties.
    """
    zero = cst[1]
    for q in range(out_ptr[i], out_ptr[i + 1]):
        ll = out_idx[q]
        yu = P[ll, H_YU, j]
        f = f_el[ll, j]
        if yu <= zero or (ll >= n_plain and f <= zero):  # no share, or an open contact: nothing to densify
            continue
        c = dst[ll]
        dd = ds[c, j] - ds[i, j]
        k = P[ll, H_K, j]
        el = f - f_start[ll, j]  # this step's force change (the torch path's; its elastic part where it yielded)
        df = phi * (PC[ll, C_KD, j] * dd - el)
        tot = df + phi * P[ll, H_DC, j] * (k * dd - el)
        f_el[ll, j] = f + df
        fs[i, j] += tot
        fd[c, j] += tot
        if ledger:
            h_step[i, j] += cst[0] * tot * (step_in[j] - ds[c, j])
            f_prev[ll, j] += tot


@numba.njit(cache=True, fastmath=_FASTMATH, inline="always")
def _keep_start_forces(P, NP, out_ptr, out_idx, ds, dsm, plastic, sat, bound, f_el, f_start, cst):
    """Keep the forces at this step's start of the out-links of every cell that may bottom out in it.

    :func:`_densify` needs a crossing link's force change in the step (``f_el`` is updated in place). Keeping every
    link's start force cost the kernel a third of its speed, so only cells that can cross are kept: a link's plastic
    work in a step is at most its yield force times ``|dd| <= |ds_src| + |ds_dst|`` (return mapping: the trial force
    passes the yield force by at most ``k |dd|``), so a cell's is at most ``bound_a (|ds_a| + max |ds|)`` with
    ``bound_a`` the sum of its out-links' yield forces (``bound`` ``[n, 2, lanes]``: that sum, and with springback
    relief the most elastic energy its links can release, ``sum yu^2 / 2k``). A cell is kept where its plastic work
    plus twice that reaches ``E_s`` in some lane. This ran 0.93-1.04x the kernel that estimated the start force
    from the return mapping (wrong where a link started to yield within the crossing step), B = 256, interleaved.
    """
    zero, one = cst[1], cst[2]
    CH = ds.shape[1]
    for i in range(out_ptr.shape[0] - 1):
        hit = zero
        for j in range(CH):
            reach = plastic[i, j] + 2.0 * (bound[i, 0, j] * (abs(ds[i, j]) + dsm[j]) + bound[i, 1, j])
            hit += one if (sat[i, j] == zero and reach >= NP[i, W_ES, j]) else zero
        if hit > zero:
            for q in range(out_ptr[i], out_ptr[i + 1]):
                ll = out_idx[q]
                for j in range(CH):
                    f_start[ll, j] = f_el[ll, j]


@njit_noalias(cache=True, fastmath=_FASTMATH)
def _chunk(
    cst, P, PC, NP, sp, src, dst, n_plain, out_ptr, out_idx, gap0, trl, mass, mass_ke, sidx, comp, dt, sub, n_out,
    snap, mode, relief, vel_o, s_o, vc_o, pen_o, ke_o, st_o, ab_o, pl_o, cin_o, cab_o, ctr_o, plastic_o, s, v, ds,
    fs, fd, plastic, sat, w0, fw_prev, acc, wall_node, fs_prev, fd_prev, w_work, w_in, a_out, p_in, h_out,
    stored_w, st_cell, h_step, f_el, f_start, bound, dsm, o, yd, f_prev, st_l, step_in, fwv, w_link, pmax, ww, a_ke,
    a_st, a_w, a_p,
):  # fmt: skip
    """Advance one chunk of ``CH`` simulations through every step (the body of :func:`_simulate`'s parallel loop).

    Every array argument is its own allocation, or a view of one no other argument shares, so they are compiled
    ``noalias`` (:mod:`marlcrash.sim.noalias`): the lane loops need no runtime overlap tests. ``P``, ``PC``, ``NP``,
    ``sp`` and the outputs are the chunk's slices of :func:`_simulate`'s arrays; the rest is the chunk's work state
    (zeros; ``wall_node`` and ``step_in`` are filled here).
    """
    L, _, CH = P.shape
    n = mass.shape[0]
    K = sidx.shape[0]
    half, zero, one, dtf = cst[0], cst[1], cst[2], cst[4]
    n_steps = (n_out - 1) * sub
    # cells the barrier covers in some lane of this chunk: the only ones that need the contact terms
    for i in range(n):
        for j in range(CH):
            if NP[i, W_COV, j] > zero:
                wall_node[i] = True
    for j in range(CH):
        step_in[j] = sp[j] * dtf
    for ll in range(n_plain, L):
        for j in range(CH):
            o[ll, j] = gap0[ll]
    for ll in range(L):  # the bounds of a step's plastic work per cell (_keep_start_forces), from intact links
        a = src[ll]
        for j in range(CH):
            yu = P[ll, H_YU, j]
            bound[a, 0, j] += yu
            if relief:
                bound[a, 1, j] += half * yu * yu * P[ll, H_IK, j]
    for i in range(n):
        for j in range(CH):
            v[i, j] = sp[j]
    for j in range(CH):
        e0 = 0.0
        for i in range(n):
            e0 += 0.5 * mass_ke[i] * float(sp[j]) * float(sp[j])
        for q in range(K):
            vel_o[j, q, 0] = sp[j]
        vc_o[j, 0] = sp[j]
        ke_o[j, 0] = e0
    # the first step's travel; every later step's is taken in the node update of the step before (fused loop)
    for i in range(n):
        for j in range(CH):
            d = dtf * v[i, j]
            ds[i, j] = d
            s[i, j] += d
            dsm[j] = max(dsm[j], abs(d))
    for step in range(1, n_steps + 1):
        record = step % sub == 0
        t = step // sub
        _keep_start_forces(P, NP, out_ptr, out_idx, ds, dsm, plastic, sat, bound, f_el, f_start, cst)
        # plain links (elastic-plastic), then gap (contact) links; one specialised loop per kind
        led = mode > 0
        if relief:
            _links(P, 0, n_plain, False, True, led, src, dst, ds, f_el, o, yd, plastic, fs, fd, h_step, f_prev,
                   step_in, trl, cst)  # fmt: skip
            _links(P, n_plain, L, True, True, led, src, dst, ds, f_el, o, yd, plastic, fs, fd, h_step, f_prev,
                   step_in, trl, cst)  # fmt: skip
        else:
            _links(P, 0, n_plain, False, False, led, src, dst, ds, f_el, o, yd, plastic, fs, fd, h_step, f_prev,
                   step_in, trl, cst)  # fmt: skip
            _links(P, n_plain, L, True, False, led, src, dst, ds, f_el, o, yd, plastic, fs, fd, h_step, f_prev,
                   step_in, trl, cst)  # fmt: skip
        # saturation within the step: a cell whose plastic work crossed E_s densifies its out-links for the
        # part of the step past the crossing, keeps E_s as its plastic work and switches them to their dense
        # properties once (saturation is monotone)
        for i in range(n):
            new = zero
            for j in range(CH):
                new += (one if plastic[i, j] >= NP[i, W_ES, j] else zero) - sat[i, j]
            if new > zero:
                for j in range(CH):
                    e_s = NP[i, W_ES, j]
                    if sat[i, j] == zero and plastic[i, j] >= e_s:
                        phi = (plastic[i, j] - e_s) / (plastic[i, j] - w0[i, j])
                        _densify(P, PC, i, j, phi, out_ptr, out_idx, n_plain, dst, ds, f_el, f_start, fs, fd, led,
                                 h_step, f_prev, step_in, cst)  # fmt: skip
                        plastic[i, j] = e_s
                        sat[i, j] = one
                        _bottom_out(P, PC, i, j, out_ptr, out_idx, relief, cst)
        for j in range(CH):
            pmax[j] = 0.0
            w_link[j] = 0.0
            a_ke[j] = 0.0
            dsm[j] = zero  # the largest travel of the next step, taken in the node update below
        for i in range(n):
            mi = mass[i]
            mk = mass_ke[i]
            if wall_node[i]:
                for j in range(CH):
                    pen = s[i, j] - NP[i, W_GAP, j]
                    inc = NP[i, W_COV, j] > zero and pen > zero
                    fw = max(NP[i, W_K, j] * pen + NP[i, W_C, j] * min(v[i, j], pen * cst[3]), zero) if inc else zero
                    stored_w[i, j] = 0.5 * float(NP[i, W_K, j]) * float(pen) * float(pen) if inc else 0.0
                    fwbar = 0.5 * (float(fw_prev[i, j]) + float(fw))
                    dsi = float(ds[i, j])
                    w_work[i, j] += fwbar * dsi
                    w_in[i, j] += fwbar * float(step_in[j])
                    fw_prev[i, j] = fw
                    pmax[j] = max(pmax[j], float(pen * NP[i, W_COV, j]) if inc else 0.0)  # SimResult.crush
                    fwv[j] = fw  # taken (and reset to zero) by the update below
            if led:  # per-cell ledgers: only where per-cell energies are recorded
                for j in range(CH):
                    h_out[i, j] += float(h_step[i, j])
                    h_step[i, j] = zero
                    r = float(step_in[j]) - float(ds[i, j])
                    a_out[i, j] += 0.5 * (fs_prev[i, j] + float(fs[i, j])) * r
                    p_in[i, j] += 0.5 * (fd_prev[i, j] + float(fd[i, j])) * r
            if record and i == comp:
                for j in range(CH):
                    s_o[j, t] = s[i, j]
            # one fused pass: this step's link work, acceleration and velocity, then the next step's travel (so
            # ``s`` and ``ds`` run one step ahead from here; the first step's are taken before the loop)
            for j in range(CH):
                dsi = float(ds[i, j])
                fsi = float(fs[i, j])
                fdi = float(fd[i, j])
                w_link[j] += (0.5 * (fd_prev[i, j] + fdi) - 0.5 * (fs_prev[i, j] + fsi)) * dsi
                fs_prev[i, j] = fsi
                fd_prev[i, j] = fdi
                acc_ij = (fs[i, j] - fd[i, j] - fwv[j]) / mi
                fwv[j] = zero
                acc[i, j] = acc_ij
                v_old = v[i, j]
                v_new = v_old + dtf * acc_ij
                a_ke[j] += float(half * mk * v_old * v_new)  # leapfrog kinetic energy
                v[i, j] = v_new
                w0[i, j] = plastic[i, j]  # the next step's starting plastic work (nothing else changes it)
                d = dtf * v_new
                ds[i, j] = d
                s[i, j] += d
                dsm[j] = max(dsm[j], abs(d))
                fs[i, j] = zero
                fd[i, j] = zero
        for j in range(CH):
            a_w[j] += w_link[j]
        if record:
            # elastic energy of the links (only needed at output steps); a plain per-lane sum: the per-cell
            # split below is needed only where per-cell energies are recorded (summing by cell at every output
            # step measured 4 % slower)
            for j in range(CH):
                st_l[j] = zero
            for ll in range(L):
                for j in range(CH):
                    st_l[j] += half * f_el[ll, j] * f_el[ll, j] * P[ll, H_IK, j]
            for j in range(CH):
                for q in range(K):
                    vel_o[j, q, t] = v[sidx[q], j] - 0.5 * dt * acc[sidx[q], j]
                vc_o[j, t] = v[comp, j] - 0.5 * dt * acc[comp, j]
                pen_o[j, t] = pmax[j]
                a_st[j] = float(st_l[j])
                a_p[j] = 0.0
                ww[j] = 0.0
            for i in range(n):
                for j in range(CH):
                    a_st[j] += stored_w[i, j]
                    ww[j] += w_work[i, j]
                    a_p[j] += plastic[i, j]
            for j in range(CH):
                ke_o[j, t] = a_ke[j]
                st_o[j, t] = a_st[j]
                ab_o[j, t] = a_w[j] + ww[j] - a_st[j]
                pl_o[j, t] = a_p[j]
            if t == snap:
                for i in range(n):
                    for j in range(CH):
                        plastic_o[j, i] = plastic[i, j]
            if mode == 2 or (mode == 1 and t == snap):
                tt = t if mode == 2 else 0
                for i in range(n):
                    for j in range(CH):
                        st_cell[i, j] = 0.0
                for ll in range(L):
                    a = src[ll]
                    for j in range(CH):
                        st_cell[a, j] += 0.5 * float(f_el[ll, j]) * float(f_el[ll, j]) * float(P[ll, H_IK, j])
                for j in range(CH):
                    for i in range(n):
                        cin_o[j, i, tt] = w_in[i, j] + p_in[i, j]
                        cab_o[j, i, tt] = w_work[i, j] - stored_w[i, j] + a_out[i, j] - h_out[i, j] - st_cell[i, j]
                        ctr_o[j, i, tt] = h_out[i, j]


@numba.njit(cache=True, fastmath=_FASTMATH, parallel=True)
def _simulate(
    cst, lp, lc, npr, speed, src, dst, n_plain, out_ptr, out_idx, gap0, trl, mass, mass_ke, sidx, comp, dt, sub, n_out,
    snap, mode, relief, vel_o, s_o, vc_o, pen_o, ke_o, st_o, ab_o, pl_o, cin_o, cab_o, ctr_o, plastic_o,
):  # fmt: skip
    """Advance all chunks in parallel; links ``0 .. n_plain-1`` are plain links, the rest gap (contact) links.

    Each chunk's work state is allocated here and the chunk is run by :func:`_chunk`.

    Args:
        lp: ``[C, L, n_hot, lanes]`` current link properties (dtype of the simulation; rewritten in place when
            a source cell bottoms out, see :func:`_bottom_out`).
        lc: ``[C, L, n_cold, lanes]`` dense (bottomed-out) stiffness, compliance (and relaxation factor).
        npr: ``[C, n, N_NODE, lanes]`` node properties (saturation energy, wall contact).
        speed: ``[C, lanes]`` impact speeds [m/s].
        src, dst, gap0, trl: ``[L]`` link ends, initial gap [m] and tension ratio [-].
        out_ptr, out_idx: the links by source cell (CSR: links ``out_idx[out_ptr[i]:out_ptr[i + 1]]`` start at i).
        mass, mass_ke: ``[n]`` scaled mass and kinetic-energy mass [kg].
        snap: the output sample of the per-cell energies (``mode`` 1) and of ``plastic_o``.
        Outputs are ``[C, lanes, ...]`` float64 arrays (see :func:`run_numba`).
    """
    n_chunks, L, _, CH = lp.shape
    n = mass.shape[0]
    for ch in numba.prange(n_chunks):
        # node state [n, lanes], in the simulation's precision
        s = np.zeros((n, CH), lp.dtype)
        v = np.zeros((n, CH), lp.dtype)
        ds = np.zeros((n, CH), lp.dtype)
        fs = np.zeros((n, CH), lp.dtype)  # link forces summed by source node
        fd = np.zeros((n, CH), lp.dtype)  # ... and by destination node
        plastic = np.zeros((n, CH), lp.dtype)
        sat = np.zeros((n, CH), lp.dtype)  # cell bottomed out (its out-links hold their dense properties)
        w0 = np.zeros((n, CH), lp.dtype)  # plastic work at the start of the step (written by the saturation scan)
        fw_prev = np.zeros((n, CH), lp.dtype)
        acc = np.zeros((n, CH), lp.dtype)
        wall_node = np.zeros(n, np.bool_)  # the barrier covers the cell in some lane of this chunk
        # float64 node ledgers
        fs_prev = np.zeros((n, CH))
        fd_prev = np.zeros((n, CH))
        w_work = np.zeros((n, CH))
        w_in = np.zeros((n, CH))
        a_out = np.zeros((n, CH))  # sum Fsbar r_src
        p_in = np.zeros((n, CH))  # sum Fdbar r_dst
        h_out = np.zeros((n, CH))  # sum_{src} fbar r_dst (per-cell modes only)
        stored_w = np.zeros((n, CH))
        st_cell = np.zeros((n, CH))
        # ... this step's share, summed over the source's out-links in the simulation's precision and added to the
        # float64 ledger once per cell (widening every link's term to float64 ran float32 at about 0.85x)
        h_step = np.zeros((n if mode else 0, CH), lp.dtype)
        # link state [L, lanes]
        f_el = np.zeros((L, CH), lp.dtype)
        f_start = np.zeros((L, CH), lp.dtype)  # start forces of links that may cross saturation (_keep_start_forces)
        bound = np.zeros((n, 2, CH), lp.dtype)
        dsm = np.zeros(CH, lp.dtype)
        o = np.zeros((L, CH), lp.dtype)
        yd = np.zeros((L if relief else 0, CH), lp.dtype)  # 1 once the link has yielded (springback relief)
        f_prev = np.zeros((L if mode else 0, CH), lp.dtype)
        # per-lane sums and constants [lanes]
        st_l = np.zeros(CH, lp.dtype)
        step_in = np.zeros(CH, lp.dtype)
        fwv = np.zeros(CH, lp.dtype)  # the wall force on the node being updated
        w_link = np.zeros(CH)
        pmax = np.zeros(CH)
        ww = np.zeros(CH)
        a_ke = np.zeros(CH)
        a_st = np.zeros(CH)
        a_w = np.zeros(CH)
        a_p = np.zeros(CH)
        _chunk(
            cst, lp[ch], lc[ch], npr[ch], speed[ch], src, dst, n_plain, out_ptr, out_idx, gap0, trl, mass, mass_ke,
            sidx, comp, dt, sub, n_out, snap, mode, relief, vel_o[ch], s_o[ch], vc_o[ch], pen_o[ch], ke_o[ch], st_o[ch],
            ab_o[ch], pl_o[ch], cin_o[ch], cab_o[ch], ctr_o[ch], plastic_o[ch], s, v, ds, fs, fd, plastic, sat, w0,
            fw_prev, acc, wall_node, fs_prev, fd_prev, w_work, w_in, a_out, p_in, h_out, stored_w, st_cell, h_step,
            f_el, f_start, bound, dsm, o, yd, f_prev, st_l, step_in, fwv, w_link, pmax, ww, a_ke, a_st, a_w, a_p,
        )  # fmt: skip


def run_numba(
    sim: Surrogate,
    props: LinkProps,
    wall: WallProps,
    n_out: int,
    sensor_idx,
    record_cells: str,
    lanes: int | None = None,
    snap: int | None = None,
) -> SimResult:
    """Run the fused kernel (no gradients); same inputs and result layout as the torch path.

    Args:
        sim: the surrogate (static arrays, dtype, time step).
        props: ``[B, L]`` link and ``[B, n]`` saturation properties from :meth:`Surrogate.link_props`.
        wall: ``[B, n]`` contact properties from :meth:`Surrogate.scenario_tensors`.
        n_out: output samples including t = 0.
        sensor_idx: ``(names, [K] cell indices)``.
        record_cells: ``none``, ``final`` or ``series``.
        lanes: simulations per chunk (default :func:`default_lanes`; results do not depend on it).
        snap: the output sample of the ``final`` per-cell energies and of the plastic work per cell (default:
            the last).
    """
    names, sidx = sensor_idx
    B, n = props.k.shape[0], sim.n
    npdt = np.float32 if sim.dtype == torch.float32 else np.float64
    tdt = torch.float32 if npdt is np.float32 else torch.float64
    mode = _MODES[record_cells]
    relief = bool(sim.config.springback_relief)
    nh, nc = n_hot(relief), n_cold(relief)
    # Links whose transmission share is zero in every row carry no force, before or after saturation
    # (crush strength 0): leaving them out changes no number.
    with torch.no_grad():
        live = (props.yield_c.detach() != 0).any(dim=0).numpy()
    order = sim.link_order[live[sim.link_order]]
    L = len(order)
    n_plain = int((~sim.is_gap.numpy()[order]).sum())
    src = sim.src.numpy()[order]
    # links by source cell (CSR), for the one-time switch to dense properties when a cell bottoms out
    out_idx = np.argsort(src, kind="stable").astype(np.int64)
    out_ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=out_ptr[1:])
    if lanes is None:
        lanes = lanes_for(B, L, n, np.dtype(npdt).name)
    lanes = int(lanes)
    if lanes < 1:
        raise ValueError(f"lanes must be >= 1, got {lanes}")
    n_chunks = -(-B // lanes)
    Bp = n_chunks * lanes

    with torch.no_grad():
        k = props.k.detach()
        kd = props.k_dense.detach()
        yc = props.yield_c.detach()
        hot = [yc.to(tdt), k, 1.0 / k, props.damping.detach() / k / sim.dt]
        cold = [kd, 1.0 / kd]
        if relief:
            hot.append(props.relax.detach())
            cold.append(props.relax_dense.detach())
        lp = torch.stack([x.to(tdt) for x in hot], dim=1)[:, :, order]  # [B, nh, L]
        lc = torch.stack([x.to(tdt) for x in cold], dim=1)[:, :, order]  # [B, nc, L]
        e_s = props.e_s.detach().clamp(max=min(_HUGE, torch.finfo(props.e_s.dtype).max))
        npr = torch.stack([e_s, wall.k, wall.damping, wall.gap, wall.coverage.to(e_s.dtype)], dim=1).to(tdt)
        sp = wall.speed.detach().to(tdt)
        if Bp > B:  # pad the last chunk by repeating the last row
            lp = torch.cat([lp, lp[-1:].expand(Bp - B, -1, -1)])
            lc = torch.cat([lc, lc[-1:].expand(Bp - B, -1, -1)])
            npr = torch.cat([npr, npr[-1:].expand(Bp - B, -1, -1)])
            sp = torch.cat([sp, sp[-1:].expand(Bp - B)])
        # [Bp, F, rows] -> [chunks, rows, F, lanes]
        lp_a = np.ascontiguousarray(lp.reshape(n_chunks, lanes, nh, L).permute(0, 3, 2, 1).numpy())
        lc_a = np.ascontiguousarray(lc.reshape(n_chunks, lanes, nc, L).permute(0, 3, 2, 1).numpy())
        np_a = np.ascontiguousarray(npr.reshape(n_chunks, lanes, N_NODE, n).permute(0, 3, 2, 1).numpy())
        sp_a = np.ascontiguousarray(sp.reshape(n_chunks, lanes).numpy())

    K = len(names)
    tc = {0: 0, 1: 1, 2: n_out}[mode]
    z = lambda *shape: np.zeros((n_chunks, lanes, *shape))  # noqa: E731
    vel = z(K, n_out)
    s_o, vc, pen, ke, st, ab, pl = (z(n_out) for _ in range(7))
    cin, cab, ctr = (z(n, tc) for _ in range(3))
    plastic = z(n)
    dt = sim.dt
    t0 = time.perf_counter()
    cst = np.array([0.5, 0.0, 1.0, 1.0 / dt, dt, _BIG], dtype=npdt)
    _simulate(
        cst,
        lp_a,
        lc_a,
        np_a,
        sp_a,
        src,
        sim.dst.numpy()[order],
        n_plain,
        out_ptr,
        out_idx,
        sim.gap.to(torch.float64).numpy()[order].astype(npdt),
        sim.tension_ratio_np[order].astype(npdt),
        sim.mass.to(torch.float64).numpy().astype(npdt),
        sim.mass_ke.to(torch.float64).numpy().astype(npdt),
        sidx.numpy(),
        sim.comp,
        dt,
        sim.substeps,
        n_out,
        n_out - 1 if snap is None else int(snap),
        mode,
        relief,
        vel,
        s_o,
        vc,
        pen,
        ke,
        st,
        ab,
        pl,
        cin,
        cab,
        ctr,
        plastic,
    )
    KERNEL_SECONDS[0] += time.perf_counter() - t0

    def T(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(a.reshape(Bp, *a.shape[2:])[:B]).to(sim.dtype)

    plastic_t = T(plastic)
    s_t = T(s_o)
    return SimResult(
        time=torch.arange(n_out, dtype=sim.dtype) * sim.output_dt,
        sensor_names=names,
        velocity=T(vel),
        compartment_displacement=s_t,
        compartment_velocity=T(vc),
        crush=s_t - T(pen),
        kinetic=T(ke),
        stored=T(st),
        absorbed=T(ab),
        plastic=T(pl),
        initial=T(ke[..., 0]),
        cell_input=T(cin),
        cell_absorbed=T(cab),
        cell_transmitted=T(ctr),
        cell_plastic=plastic_t,
        saturated=plastic_t >= props.e_s.detach(),
        **load_case(wall),
    )
