"""Fast gradients of the sensor velocities: a compiled forward pass and its hand-written reverse pass.

:meth:`Surrogate.run` with ``backend="torch"`` is differentiable through torch autograd, but it records
about 40 small tensor operations per explicit step: on the default car (2400 steps, batches of 4) one
simulation with its backward pass takes about 1.3 s and 2 GB. ``backend="adjoint"`` gives the same
sensor velocities ``[B, K, T]`` (those of the fast kernel) with the same gradients (tested against torch
autograd and against finite differences) in about 0.14 s and 0.2 GB
(``python benchmarks/bench_adjoint.py``: 9.8x, 0.73 against 7.9 GB peak for 4 candidates), from two
numba loops, one simulation per thread:

- ``forward``: the steps of :meth:`Surrogate._run_torch` in the same order, element by element,
  storing the state at the start of every step (cell travel ``s``, velocity ``v`` and plastic work,
  link force and gap opening): about 50 kB per step, 120 MB per simulation, one simulation per thread
  at a time;
- ``backward``: reverse mode over the stored steps. Each step's intermediates are recomputed from its
  stored state (the same helper as the forward pass), then the adjoints run back through the node update,
  the wall contact, the saturation switch, the damping, the return mapping and the trial force. Where
  torch has a rule for a tie (``maximum``/``minimum`` split the gradient evenly, ``clamp`` passes it
  at the bound) this does the same, so the gradients agree to rounding, not only almost everywhere.

Gradients flow to the link properties (crush and tensile yield force, intact and dense stiffness, damping)
and the cells' saturation energies; :meth:`Surrogate.link_props` maps them back to the parameters with
torch autograd. The wall's contact properties and the impact speed depend on no parameter and get none: a
``speed``, ``overlap`` or ``side`` that requires grad is refused (``ModelError``; the torch path differentiates it).

Only the sensor velocities are differentiable on this path; the energies and the other outputs of its
:class:`~marlcrash.sim.surrogate.SimResult` are the fast kernel's, without gradients. Springback relief is not
supported here (``ModelError``); the torch path covers it. First derivatives only: differentiating the gradients
again (``create_graph=True``) raises ``ModelError``; the torch path gives second derivatives.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from marlcrash.errors import ModelError

_BIG = 1e30  # yield force of a bottomed-out link [N] (as in the torch path)


@numba.njit(cache=True, inline="always")
def _grad_max(a, b):
    """torch.maximum's backward: the share of the gradient that goes to ``a`` (0, 1/2 at a tie, 1)."""
    return 1.0 if a > b else (0.5 if a == b else 0.0)


@numba.njit(cache=True, inline="always")
def _crossing(pn, pl, es, i):
    """Cell ``i`` reached its saturation energy in this step (plastic work ``pl`` before, ``pn`` after)."""
    return pn[i] >= es[i] and pl[i] < es[i]


@numba.njit(cache=True)
def _links(v, f_el, o, pl, yc0, yt0, k0, kd, c, es, src, dst, gap, dt, w):
    """One step's link quantities from the state at its start (the torch path's operations, in order).

    Writes into the work arrays ``w`` (rows: dd, k, z, f_tr, f_ret, f_tot0, f_new, f_tot, phi, el,
    flags) and returns the plastic work after the step (before the saturation clamp) and whether any
    cell crossed its saturation energy. ``flags`` bits: 1 sat, 2 dense, 4 live (crossing).
    """
    L = src.shape[0]
    n = v.shape[0]
    dd, kk, z, f_tr, f_ret, f_tot0, f_new, f_tot, phi, el, flags = (
        w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7], w[8], w[9], w[10],
    )  # fmt: skip
    pn = pl.copy()
    for li in range(L):
        a, b = src[li], dst[li]
        dd[li] = dt * v[b] - dt * v[a]
        sat = pl[a] >= es[a]
        k = kd[li] if sat else k0[li]
        kk[li] = k
        dense = sat and yc0[li] > 0
        yc = _BIG if dense else yc0[li]
        yt = _BIG if (dense and not gap[li]) else yt0[li]
        zz = f_el[li] / k - o[li] + dd[li]
        z[li] = zz
        ft = k * (max(zz, 0.0) if gap[li] else zz)
        f_tr[li] = ft
        fr = min(max(ft, -yt), yc)
        f_ret[li] = fr
        pn[a] += fr * (ft - fr) / k
        t = fr + c[li] * (fr - f_el[li]) / (k * dt)
        f_tot0[li] = t
        f_tot[li] = max(t, 0.0) if gap[li] else t
        f_new[li] = fr
        flags[li] = (1.0 if sat else 0.0) + (2.0 if dense else 0.0)
        phi[li] = 0.0
        el[li] = 0.0
    cross = False
    for i in range(n):
        if _crossing(pn, pl, es, i):
            cross = True
    if cross:
        for li in range(L):
            a = src[li]
            if not _crossing(pn, pl, es, a):
                continue
            fr = f_ret[li]
            live = yc0[li] > 0 and (not gap[li] or fr > 0)
            if not live:
                continue
            p = (pn[a] - es[a]) / (pn[a] - pl[a])
            e = fr - f_el[li]  # this step's force change (the surrogate's _step)
            df = p * (kd[li] * dd[li] - e)
            dv = p * c[li] * (dd[li] - e / kk[li]) / dt
            f_new[li] = fr + df
            f_tot[li] = f_tot[li] + df + dv
            phi[li] = p
            el[li] = e
            flags[li] += 4.0
    return pn, cross


@numba.njit(cache=True)
def _nodes(v, s, f_tot, kw, cw, gapw, covered, m, src, dst, dt):
    """Node update: new travel ``s``, wall force and new velocity (the torch path's order)."""
    n = v.shape[0]
    s_new = s + dt * v
    force = np.zeros(n)
    for li in range(src.shape[0]):
        force[src[li]] += f_tot[li]
        force[dst[li]] -= f_tot[li]
    v_new = np.empty(n)
    for i in range(n):
        pen = s_new[i] - gapw[i]
        fw = 0.0
        if covered[i] and pen > 0:
            fw = max(kw[i] * pen + cw[i] * min(v[i], pen / dt), 0.0)
        v_new[i] = v[i] + dt * ((force[i] - fw) / m[i])
    return s_new, v_new


@numba.njit(cache=True)
def _forward_one(v0, yc0, yt0, k0, kd, c, es, kw, cw, gapw, covered, m, src, dst, gap, gap0, sidx, dt, sub,
                 n_out, vel, tv, ts, tp, tf, to):  # fmt: skip
    """Simulate one crash, writing sensor velocities ``vel [K, n_out]`` and (if ``tv`` has rows) the
    state at the start of every step."""
    n, L = m.shape[0], src.shape[0]
    v = np.full(n, v0)
    s = np.zeros(n)
    pl = np.zeros(n)
    f_el = np.zeros(L)
    o = np.empty(L)
    for li in range(L):
        o[li] = gap0[li]
    w = np.empty((11, L))
    store = tv.shape[0] > 0
    for q in range(sidx.shape[0]):
        vel[q, 0] = v0
    for step in range(1, (n_out - 1) * sub + 1):
        if store:
            tv[step - 1] = v
            ts[step - 1] = s
            tp[step - 1] = pl
            tf[step - 1] = f_el
            to[step - 1] = o
        pn, cross = _links(v, f_el, o, pl, yc0, yt0, k0, kd, c, es, src, dst, gap, dt, w)
        if cross:
            for i in range(n):
                if _crossing(pn, pl, es, i):
                    pn[i] = es[i]
        s_new, v_new = _nodes(v, s, w[7], kw, cw, gapw, covered, m, src, dst, dt)
        if step % sub == 0:
            t = step // sub
            for q in range(sidx.shape[0]):
                vel[q, t] = 0.5 * (v[sidx[q]] + v_new[sidx[q]])
        for li in range(L):
            f_el[li] = w[6, li]
            zz = w[2, li]
            o[li] = max(-zz, 0.0) if gap[li] else 0.0
        v, s, pl = v_new, s_new, pn


@numba.njit(cache=True)
def _backward_one(v0, yc0, yt0, k0, kd, c, es, kw, cw, gapw, covered, m, src, dst, gap, gap0, sidx, dt, sub,
                  n_out, gvel, g_yc, g_yt, g_k, g_kd, g_c, g_es):  # fmt: skip
    """Add the gradients of ``sum(gvel * vel)`` with respect to the link properties and saturation energies."""
    n, L = m.shape[0], src.shape[0]
    steps = (n_out - 1) * sub
    tv, ts, tp = np.empty((steps, n)), np.empty((steps, n)), np.empty((steps, n))
    tf, to = np.empty((steps, L)), np.empty((steps, L))
    vel = np.empty((sidx.shape[0], n_out))
    _forward_one(v0, yc0, yt0, k0, kd, c, es, kw, cw, gapw, covered, m, src, dst, gap, gap0, sidx, dt, sub,
                 n_out, vel, tv, ts, tp, tf, to)  # fmt: skip
    # adjoints of the state after the step being reversed (velocity, travel, plastic work; link force, opening)
    gv, gs, gpl = np.zeros(n), np.zeros(n), np.zeros(n)
    gfel, go = np.zeros(L), np.zeros(L)
    w = np.empty((11, L))
    g_vin, g_force, g_ds = np.zeros(n), np.zeros(n), np.zeros(n)
    g_pn, g_phic, g_plx = np.zeros(n), np.zeros(n), np.zeros(n)
    # a crossing link's stiffness, deformation and force-change adjoints (switch part)
    x_k, x_dd, x_e = np.zeros(L), np.zeros(L), np.zeros(L)
    for step in range(steps, 0, -1):
        v, s, pl, f_el, o = tv[step - 1], ts[step - 1], tp[step - 1], tf[step - 1], to[step - 1]
        pn, cross = _links(v, f_el, o, pl, yc0, yt0, k0, kd, c, es, src, dst, gap, dt, w)
        dd, kk, z, f_tr, f_ret, f_tot0, phi, el, flags = w[0], w[1], w[2], w[3], w[4], w[5], w[8], w[9], w[10]
        if step % sub == 0:  # recorded velocity 0.5 (v + v_new)
            t = step // sub
            for q in range(sidx.shape[0]):
                gv[sidx[q]] += 0.5 * gvel[q, t]
                g_vin[sidx[q]] += 0.5 * gvel[q, t]
        # node update v_new = v + dt (force - fw) / m; travel s_new = s + ds, ds = dt v
        for i in range(n):
            g_vin[i] += gv[i]
            g_force[i] = gv[i] * dt / m[i]
            g_ds[i] = gs[i]
            pen = s[i] + dt * v[i] - gapw[i]
            # fw = max(kw pen + cw min(v, pen / dt), 0) in contact; torch's max passes the gradient at the bound
            if covered[i] and pen > 0 and kw[i] * pen + cw[i] * min(v[i], pen / dt) >= 0:
                g_fw = -g_force[i]
                a = _grad_max(pen / dt, v[i])  # share of min(v, pen / dt) that goes to v
                g_vin[i] += g_fw * cw[i] * a
                g_pen = g_fw * (kw[i] + cw[i] * (1.0 - a) / dt)
                g_ds[i] += g_pen
                gs[i] += g_pen
        # plastic work after the step: crossing cells were set to their saturation energy
        for i in range(n):
            crossing = cross and _crossing(pn, pl, es, i)
            g_pn[i] = 0.0 if crossing else gpl[i]
            if crossing:
                g_es[i] += gpl[i]
            g_phic[i] = 0.0
            g_plx[i] = 0.0
        if cross:  # the switch to dense properties within the step: df, dv of the live links
            for li in range(L):
                if not (int(flags[li]) & 4):
                    continue
                a, b = src[li], dst[li]
                k, p, e = kk[li], phi[li], el[li]
                g_ft = g_force[a] - g_force[b]
                g_df = gfel[li] + g_ft  # f_new = f_ret + df; f_tot = . + df + dv
                g_dv = g_ft
                g_phic[a] += g_df * (kd[li] * dd[li] - e) + g_dv * c[li] * (dd[li] - e / k) / dt
                g_kd[li] += g_df * p * dd[li]
                g_c[li] += g_dv * p * (dd[li] - e / k) / dt
                g_e = -g_df * p - g_dv * p * c[li] / (k * dt)
                x_k[li] = g_dv * p * c[li] * e / (k * k * dt)
                x_dd[li] = g_df * p * kd[li] + g_dv * p * c[li] / dt
                x_e[li] = g_e  # e = f_ret - f_el
            for i in range(n):  # phi = (pn - es) / (pn - pl)
                if g_phic[i] != 0.0:
                    gain = pn[i] - pl[i]
                    r = (pn[i] - es[i]) / gain
                    g_pn[i] += g_phic[i] * (1.0 - r) / gain
                    g_es[i] -= g_phic[i] / gain
                    g_plx[i] = g_phic[i] * r / gain
        for li in range(L):
            a, b = src[li], dst[li]
            fl = int(flags[li])
            k = kk[li]
            fr, fe, ft, zz = f_ret[li], f_el[li], f_tr[li], z[li]
            g_ft = g_force[a] - g_force[b]
            g_fr = gfel[li]
            g_k_, g_dd, g_e = 0.0, 0.0, 0.0
            if fl & 4:
                g_k_, g_dd, g_e = x_k[li], x_dd[li], x_e[li]
                x_k[li], x_dd[li], x_e[li] = 0.0, 0.0, 0.0
            g_fr += g_e
            # f_tot = f_tot0 (a gap link's clamped at 0), f_tot0 = f_ret + c (f_ret - f_el) / (k dt)
            g_t0 = g_ft if (not gap[li] or f_tot0[li] >= 0) else 0.0
            g_fr += g_t0 * (1.0 + c[li] / (k * dt))
            g_c[li] += g_t0 * (fr - fe) / (k * dt)
            g_fe = -g_t0 * c[li] / (k * dt) - g_e
            g_k_ -= g_t0 * c[li] * (fr - fe) / (k * k * dt)
            # plastic work f_ret (f_tr - f_ret) / k, summed into the source cell
            g_w = g_pn[a]
            g_fr += g_w * (ft - 2.0 * fr) / k
            g_ftr = g_w * fr / k
            g_k_ -= g_w * fr * (ft - fr) / (k * k)
            # return mapping f_ret = min(max(f_tr, -yt), yc)
            dense = (fl & 2) != 0
            yc = _BIG if dense else yc0[li]
            yt = _BIG if (dense and not gap[li]) else yt0[li]
            m1 = max(ft, -yt)
            g_m1 = g_fr * _grad_max(yc, m1)
            if not dense:
                g_yc[li] += g_fr * _grad_max(m1, yc)
            g_ftr += g_m1 * _grad_max(ft, -yt)
            if not (dense and not gap[li]):
                g_yt[li] -= g_m1 * _grad_max(-yt, ft)
            # trial force f_tr = k (gap: max(z, 0)); a gap link's opening o_new = max(-z, 0)
            if gap[li]:
                g_k_ += g_ftr * max(zz, 0.0)
                g_z = (g_ftr * k if zz >= 0 else 0.0) - (go[li] if zz <= 0 else 0.0)
            else:
                g_k_ += g_ftr * zz
                g_z = g_ftr * k
            # z = f_el / k - o + dd
            g_fe += g_z / k
            g_k_ -= g_z * fe / (k * k)
            go[li] = -g_z
            g_dd += g_z
            gfel[li] = g_fe
            if fl & 1:  # k = k_dense once the source cell bottomed out
                g_kd[li] += g_k_
            else:
                g_k[li] += g_k_
            g_ds[b] += g_dd  # dd = ds_dst - ds_src
            g_ds[a] -= g_dd
        for i in range(n):
            gpl[i] = g_pn[i] + g_plx[i]
            gv[i] = g_vin[i] + dt * g_ds[i]
            g_vin[i] = 0.0


@numba.njit(cache=True, parallel=True)
def _forward_batch(
    v0, yc0, yt0, k0, kd, c, es, kw, cw, gapw, covered, m, src, dst, gap, gap0, sidx, dt, sub, n_out, vel
):
    none2 = np.empty((0, 0))
    for b in numba.prange(v0.shape[0]):
        _forward_one(v0[b], yc0[b], yt0[b], k0[b], kd[b], c[b], es[b], kw[b], cw[b], gapw[b], covered[b], m, src,
                     dst, gap, gap0, sidx, dt, sub, n_out, vel[b], none2, none2, none2, none2, none2)  # fmt: skip


@numba.njit(cache=True, parallel=True)
def _backward_batch(v0, yc0, yt0, k0, kd, c, es, kw, cw, gapw, covered, m, src, dst, gap, gap0, sidx, dt, sub,
                    n_out, gvel, g_yc, g_yt, g_k, g_kd, g_c, g_es):  # fmt: skip
    for b in numba.prange(v0.shape[0]):
        _backward_one(v0[b], yc0[b], yt0[b], k0[b], kd[b], c[b], es[b], kw[b], cw[b], gapw[b], covered[b], m, src,
                      dst, gap, gap0, sidx, dt, sub, n_out, gvel[b], g_yc[b], g_yt[b], g_k[b], g_kd[b], g_c[b],
                      g_es[b])  # fmt: skip


def _statics(sim, wall, n_out: int, sidx: torch.Tensor) -> dict:
    """Arrays of the compiled passes that carry no gradient (float64, contiguous)."""
    f64 = lambda t: np.ascontiguousarray(t.detach().to(torch.float64).numpy())  # noqa: E731
    return {
        "v0": f64(wall.speed), "kw": f64(wall.k), "cw": f64(wall.damping), "gapw": f64(wall.gap),
        "covered": np.ascontiguousarray(wall.covered.numpy()), "m": f64(sim.mass), "src": sim.src.numpy(),
        "dst": sim.dst.numpy(), "gap": np.ascontiguousarray(sim.is_gap.numpy()), "gap0": f64(sim.gap),
        "sidx": sidx.numpy().astype(np.int64), "dt": float(sim.dt), "sub": int(sim.substeps),
        "n_out": int(n_out),
    }  # fmt: skip


def _args(props: tuple[torch.Tensor, ...], st: dict) -> tuple:
    yc, yt, k, kd, c, es = (np.ascontiguousarray(p.detach().to(torch.float64).numpy()) for p in props)
    return (st["v0"], yc, yt, k, kd, c, es, st["kw"], st["cw"], st["gapw"], st["covered"], st["m"], st["src"],
            st["dst"], st["gap"], st["gap0"], st["sidx"], st["dt"], st["sub"], st["n_out"])  # fmt: skip


def forward_velocity(props: tuple[torch.Tensor, ...], st: dict) -> torch.Tensor:
    """Sensor velocities ``[B, K, n_out]`` of the plain compiled forward pass (the one the gradients are of)."""
    args = _args(props, st)
    vel = np.zeros((args[0].shape[0], st["sidx"].shape[0], st["n_out"]))
    _forward_batch(*args, vel)  # type: ignore[call-arg]  # numba's Dispatcher stub does not see the njit signature
    return torch.from_numpy(vel)


class _FirstDerivativeOnly(torch.autograd.Function):
    """The adjoint's gradients ``[B, L]`` or ``[B, n]`` where a graph of them is asked for (``create_graph=True``):
    differentiating them again raises instead of giving second derivatives without the simulation's curvature."""

    @staticmethod
    def forward(ctx, grad, *props):
        return grad.clone()

    @staticmethod
    def backward(ctx, *_):
        raise ModelError(
            "backend 'adjoint' gives first derivatives only: its gradients cannot be differentiated again "
            "(create_graph=True); use backend 'torch' for second derivatives"
        )


class _SensorVelocity(torch.autograd.Function):
    """Sensor velocities as a function of the link properties; backward by the compiled reverse pass (first
    derivatives: :class:`_FirstDerivativeOnly`)."""

    @staticmethod
    def forward(ctx, yc, yt, k, kd, c, es, velocity, st):
        ctx.save_for_backward(yc, yt, k, kd, c, es)
        ctx.st = st
        return velocity.clone()

    @staticmethod
    def backward(ctx, gvel):
        props = ctx.saved_tensors
        args = _args(props, ctx.st)
        B, L = args[1].shape
        n = args[6].shape[1]
        grads = [np.zeros((B, L)) for _ in range(5)] + [np.zeros((B, n))]
        g = np.ascontiguousarray(gvel.detach().to(torch.float64).numpy())
        _backward_batch(*args, g, *grads)
        out = [torch.from_numpy(a).to(p.dtype) if p.requires_grad else None for a, p in zip(grads, props, strict=True)]
        if torch.is_grad_enabled():  # create_graph: the gradients depend on the properties, through no graph here
            out = [None if g is None else _FirstDerivativeOnly.apply(g, *props) for g in out]
        return (*out, None, None)


def unsupported(config) -> str | None:
    """Why the adjoint cannot differentiate a simulator of ``config`` (a :class:`~marlcrash.sim.surrogate.SimConfig`):
    springback relief on, or a float32 simulation (the reverse pass is float64 only); ``None`` where it can."""
    if config.springback_relief:
        return "backend 'adjoint' does not support springback_relief; use backend 'torch'"
    if config.dtype != "float64":
        return "backend 'adjoint' needs dtype float64; use backend 'torch' for float32 gradients"
    return None


def run_adjoint(sim, props, wall, n_out: int, sensor_idx, record_cells: str, snap: int | None = None):
    """:func:`~marlcrash.sim.kernels.run_numba`'s result with sensor velocities differentiable by the adjoint.

    Raises:
        ModelError: the simulator's config is one the adjoint does not cover (:func:`unsupported`), or a scenario
            tensor (``speed``, ``overlap``, ``side``) requires grad: the adjoint differentiates the cell
            parameters only, so it would get no gradient.
    """
    from marlcrash.sim.kernels import run_numba

    why = unsupported(sim.config)
    if why is not None:
        raise ModelError(why)
    if torch.is_grad_enabled():
        asked = [name for name, t in (("speed", wall.speed), ("overlap or side", wall.k)) if t.requires_grad]
        if asked:
            raise ModelError(
                f"backend 'adjoint' differentiates the cell parameters only, but the {asked[0]} tensor requires "
                "grad (it would get none); use backend 'torch', or pass it without requires_grad"
            )
    res = run_numba(sim, props, wall, n_out, sensor_idx, record_cells, snap=snap)
    tensors = (props.yield_c, props.yield_t, props.k, props.k_dense, props.damping, props.e_s)
    if torch.is_grad_enabled() and any(t.requires_grad for t in tensors):
        st = _statics(sim, wall, n_out, sensor_idx[1])
        res.velocity = _SensorVelocity.apply(*tensors, res.velocity, st)
    return res
