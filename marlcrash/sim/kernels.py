"""Compiled no-grad fast path of the surrogate: one fused numba loop, parallel over the batch.

It performs exactly the operations of :meth:`Surrogate._run_torch` (the tested,
differentiable reference) in the same order per element; only summation order
of the scatters differs, so results agree to rounding (tested to 1e-6). Element
properties are computed by the torch code (:meth:`Surrogate.link_props`,
:meth:`Surrogate.scenario_tensors`) and passed in as arrays.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from marlcrash.sim.surrogate import LinkProps, SimResult, Surrogate, WallProps

_MODES = {"none": 0, "final": 1, "series": 2}


CHUNK = 16
"""Simulations advanced together in SIMD lanes (two AVX-512 registers of float64)."""


@numba.njit(cache=True, fastmath=True, parallel=True)
def _simulate(
    yc,
    yt,
    k0,
    kd,
    ik0,
    ikd,
    damp,
    e_s,
    wk,
    wc,
    wgap,
    covered,
    speed,
    src,
    dst,
    is_gap,
    gap0,
    mass,
    mass_ke,
    sidx,
    comp,
    dt,
    sub,
    n_out,
    mode,
    acc_o,
    vel_o,
    s_o,
    vc_o,
    pen_o,
    ke_o,
    st_o,
    ab_o,
    pl_o,
    cin_o,
    cab_o,
    ctr_o,
    plastic_o,
):
    """Chunked kernel: batch arrays are ``[n_chunks, rows, CHUNK]``, lanes innermost."""
    n_chunks, L, CH = yc.shape
    n = mass.shape[0]
    K = sidx.shape[0]
    inv_dt = 1.0 / dt
    for ch in numba.prange(n_chunks):
        s = np.zeros((n, CH))
        v = np.zeros((n, CH))
        ds = np.zeros((n, CH))
        force = np.zeros((n, CH))
        fw_prev = np.zeros((n, CH))
        plastic = np.zeros((n, CH))
        satc = np.zeros((n, CH))
        w_work = np.zeros((n, CH))
        w_in = np.zeros((n, CH))
        stored_w = np.zeros((n, CH))
        f_el = np.zeros((L, CH))
        o = np.zeros((L, CH))
        f_prev = np.zeros((L, CH))
        work = np.zeros((L, CH))
        passed = np.zeros((L, CH))
        ftmp = np.zeros(CH)
        ptmp = np.zeros(CH)
        pmax = np.zeros(CH)
        a_ke, a_st, a_w, a_p = np.zeros(CH), np.zeros(CH), np.zeros(CH), np.zeros(CH)
        stored_l = np.zeros((L, CH))
        sp = speed[ch]
        step_in = sp * dt
        for l in range(L):
            for j in range(CH):
                o[l, j] = gap0[l]
        for i in range(n):
            for j in range(CH):
                v[i, j] = sp[j]
        for j in range(CH):
            e0 = 0.0
            for i in range(n):
                e0 += 0.5 * mass_ke[i] * sp[j] * sp[j]
            for q in range(K):
                vel_o[ch, j, q, 0] = sp[j]
            vc_o[ch, j, 0] = sp[j]
            ke_o[ch, j, 0] = e0
        n_steps = (n_out - 1) * sub
        for step in range(1, n_steps + 1):
            for i in range(n):
                es = e_s[ch, i]
                for j in range(CH):
                    ds[i, j] = dt * v[i, j]
                    s[i, j] += ds[i, j]
                    force[i, j] = 0.0
                    satc[i, j] = 1.0 if plastic[i, j] >= es[j] else 0.0
            for l in range(L):
                a = src[l]
                c = dst[l]
                if is_gap[l]:
                    for j in range(CH):
                        dd = ds[c, j] - ds[a, j]
                        sat = satc[a, j]
                        ik = ik0[ch, l, j] + sat * (ikd[ch, l, j] - ik0[ch, l, j])
                        yu = yc[ch, l, j] + sat * (1e30 - yc[ch, l, j])
                        z = f_el[l, j] * ik - o[l, j] + dd
                        f_tr = (k0[ch, l, j] + sat * (kd[ch, l, j] - k0[ch, l, j])) * max(z, 0.0)
                        o[l, j] = max(-z, 0.0)
                        f_new = min(f_tr, yu)
                        ptmp[j] = f_new * (f_tr - f_new) * ik
                        f_tot = f_new + (damp[ch, l, j] * dd * inv_dt if (f_tr == f_new and z > 0.0) else 0.0)
                        fbar = 0.5 * (f_prev[l, j] + f_tot)
                        work[l, j] += fbar * dd
                        passed[l, j] += fbar * (step_in[j] - ds[c, j])
                        f_el[l, j] = f_new
                        f_prev[l, j] = f_tot
                        ftmp[j] = f_tot
                else:
                    for j in range(CH):
                        dd = ds[c, j] - ds[a, j]
                        sat = satc[a, j]
                        ik = ik0[ch, l, j] + sat * (ikd[ch, l, j] - ik0[ch, l, j])
                        yu = yc[ch, l, j] + sat * (1e30 - yc[ch, l, j])
                        yl = yt[ch, l, j] + sat * (1e30 - yt[ch, l, j])
                        f_tr = f_el[l, j] + (k0[ch, l, j] + sat * (kd[ch, l, j] - k0[ch, l, j])) * dd
                        f_new = min(max(f_tr, -yl), yu)
                        ptmp[j] = f_new * (f_tr - f_new) * ik
                        f_tot = f_new + (damp[ch, l, j] * dd * inv_dt if f_tr == f_new else 0.0)
                        fbar = 0.5 * (f_prev[l, j] + f_tot)
                        work[l, j] += fbar * dd
                        passed[l, j] += fbar * (step_in[j] - ds[c, j])
                        f_el[l, j] = f_new
                        f_prev[l, j] = f_tot
                        ftmp[j] = f_tot
                for j in range(CH):
                    force[a, j] += ftmp[j]
                for j in range(CH):
                    force[c, j] -= ftmp[j]
                for j in range(CH):
                    plastic[a, j] += ptmp[j]
            record = step % sub == 0
            t = step // sub
            for j in range(CH):
                pmax[j] = 0.0
            for i in range(n):
                wki, wci, wgi, cov, mi, mk = wk[ch, i], wc[ch, i], wgap[ch, i], covered[ch, i], mass[i], mass_ke[i]
                for j in range(CH):
                    pen = s[i, j] - wgi[j]
                    inc = cov[j] and pen > 0.0
                    fw = max(wki[j] * pen + wci[j] * v[i, j], 0.0) if inc else 0.0
                    stored_w[i, j] = 0.5 * wki[j] * pen * pen if inc else 0.0
                    fwbar = 0.5 * (fw_prev[i, j] + fw)
                    w_work[i, j] += fwbar * ds[i, j]
                    w_in[i, j] += fwbar * step_in[j]
                    fw_prev[i, j] = fw
                    acc = (force[i, j] - fw) / mi
                    v_new = v[i, j] + dt * acc
                    force[i, j] = acc  # keep the acceleration for the record
                    ds[i, j] = 0.5 * mk * v[i, j] * v_new  # and the leapfrog kinetic energy
                    v[i, j] = v_new
                    pmax[j] = max(pmax[j], pen if inc else 0.0)
            if record:
                for j in range(CH):
                    for q in range(K):
                        acc_o[ch, j, q, t] = force[sidx[q], j]
                        vel_o[ch, j, q, t] = v[sidx[q], j] - 0.5 * dt * force[sidx[q], j]
                    s_o[ch, j, t] = s[comp, j]
                    vc_o[ch, j, t] = v[comp, j] - 0.5 * dt * force[comp, j]
                    pen_o[ch, j, t] = pmax[j]
                    a_ke[j] = 0.0
                    a_st[j] = 0.0
                    a_w[j] = 0.0
                    a_p[j] = 0.0
                for i in range(n):
                    for j in range(CH):
                        a_ke[j] += ds[i, j]
                        a_st[j] += stored_w[i, j]
                        a_w[j] += w_work[i, j]
                        a_p[j] += plastic[i, j]
                for l in range(L):
                    a = src[l]
                    for j in range(CH):
                        ik = ik0[ch, l, j] + satc[a, j] * (ikd[ch, l, j] - ik0[ch, l, j])
                        stored_l[l, j] = 0.5 * f_el[l, j] * f_el[l, j] * ik
                        a_st[j] += stored_l[l, j]
                        a_w[j] += work[l, j]
                for j in range(CH):
                    ke_o[ch, j, t] = a_ke[j]
                    st_o[ch, j, t] = a_st[j]
                    ab_o[ch, j, t] = a_w[j] - a_st[j]
                    pl_o[ch, j, t] = a_p[j]
                if mode == 2 or (mode == 1 and t == n_out - 1):
                    tt = t if mode == 2 else 0
                    for j in range(CH):
                        for i in range(n):
                            cin_o[ch, j, i, tt] = w_in[i, j]
                            cab_o[ch, j, i, tt] = w_work[i, j] - stored_w[i, j]
                        for l in range(L):
                            cin_o[ch, j, dst[l], tt] += passed[l, j]
                            cab_o[ch, j, src[l], tt] += work[l, j] - stored_l[l, j]
                            ctr_o[ch, j, src[l], tt] += passed[l, j]
        for i in range(n):
            for j in range(CH):
                plastic_o[ch, j, i] = plastic[i, j]


def run_numba(
    sim: Surrogate, props: LinkProps, wall: WallProps, n_out: int, sensor_idx, record_cells: str
) -> SimResult:
    """Run the fused kernel (no gradients); same inputs and result layout as the torch path."""
    names, sidx = sensor_idx
    B, n = props.k.shape[0], sim.n
    chunk = min(CHUNK, B)  # small batches are not padded to a full chunk of lanes
    n_chunks = -(-B // chunk)
    pad = n_chunks * chunk - B

    def lanes(x: torch.Tensor) -> np.ndarray:
        """``[B, rows]`` -> ``[n_chunks, rows, chunk]`` (padding repeats the last row)."""
        x = x.detach().to(torch.float64)
        if pad:
            x = torch.cat([x, x[-1:].expand(pad, *x.shape[1:])])
        x = x.reshape(n_chunks, chunk, *x.shape[1:])
        return np.ascontiguousarray(x.movedim(1, -1).numpy())

    K = len(names)
    mode = _MODES[record_cells]
    tc = {0: 0, 1: 1, 2: n_out}[mode]
    Bp = n_chunks * chunk
    z = lambda *shape: np.zeros((n_chunks, chunk, *shape))  # noqa: E731
    acc, vel = z(K, n_out), z(K, n_out)
    s_o, vc, pen, ke, st, ab, pl = (z(n_out) for _ in range(7))
    cin, cab, ctr = (z(n, tc) for _ in range(3))
    plastic = z(n)
    k, kd = props.k.detach(), props.k_dense.detach()
    _simulate(
        lanes(props.yield_c),
        lanes(props.yield_t),
        lanes(k),
        lanes(kd),
        lanes(1.0 / k),
        lanes(1.0 / kd),
        lanes(props.damping),
        lanes(props.e_s),
        lanes(wall.k),
        lanes(wall.damping),
        lanes(wall.gap),
        lanes(wall.covered.to(torch.float64)) > 0.5,
        lanes(wall.speed[:, None])[:, 0],
        sim.src.numpy(),
        sim.dst.numpy(),
        sim.is_gap.numpy(),
        sim.gap.to(torch.float64).numpy(),
        sim.mass.to(torch.float64).numpy(),
        sim.mass_ke.to(torch.float64).numpy(),
        sidx.numpy(),
        sim.comp,
        sim.dt,
        sim.config.substeps,
        n_out,
        mode,
        acc,
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

    def T(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(a.reshape(Bp, *a.shape[2:])[:B]).to(sim.dtype)

    plastic_t = T(plastic)
    s_t = T(s_o)
    return SimResult(
        time=torch.arange(n_out, dtype=sim.dtype) * sim.output_dt,
        sensor_names=names,
        acceleration=T(acc),
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
    )
