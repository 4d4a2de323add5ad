"""The loop kernels write the table lookup out inline (a ``table_eval`` call per spring costs numba
reference counting it cannot prune): they must give exactly what the per-spring reference
``spring_eval`` (which calls ``table_eval``) gives, on multi-point tables with and without
compression, across breakpoints, below strain 0, beyond the last point and at zero length."""

import numpy as np

from clothsim.kernels import forces_and_energy, node_force, spring_eval, table_eval


def _pack(rng, n_tables):
    xs, ys, cums, start, comp = [], [], [], [0], []
    for _ in range(n_tables):
        npts = int(rng.integers(2, 7))
        x = np.concatenate([[0.0], np.sort(rng.uniform(0.01, 0.5, npts - 1))])
        y = np.concatenate([[0.0], np.cumsum(rng.uniform(1.0, 500.0, npts - 1))])
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(x))])
        xs.append(x)
        ys.append(y)
        cums.append(cum)
        start.append(start[-1] + npts)
        comp.append(int(rng.integers(0, 2)))
    return (np.concatenate(xs), np.concatenate(ys), np.concatenate(cums), np.array(start, np.int64),
            np.array(comp, np.uint8))


def _scene(seed):
    rng = np.random.default_rng(seed)
    n, s = 60, 400
    pos = rng.normal(size=(n, 3)) * 0.05
    sn = rng.integers(0, n, size=(s, 2)).astype(np.int64)
    sn[:3, 1] = sn[:3, 0]  # zero-length springs
    rest = np.linalg.norm(pos[sn[:, 1]] - pos[sn[:, 0]], axis=1) * rng.uniform(0.5, 1.8, s) + 1e-3
    width = rng.uniform(0.001, 0.01, s)
    x, y, cum, start, comp = _pack(rng, 4)
    table = rng.integers(0, 4, s).astype(np.int64)
    ext = rng.normal(size=(n, 3)) * (seed % 2)
    return pos, sn, rest, width, table, x, y, cum, start, comp, ext


def test_forces_and_energy_equal_spring_eval_sum():
    for seed in range(6):
        pos, sn, rest, width, table, x, y, cum, start, comp, ext = _scene(seed)
        F = np.empty_like(pos)
        e = forces_and_energy(pos, sn, rest, width, table, x, y, cum, start, comp, ext, F)
        Fr = ext.copy()
        er = 0.0
        for k in range(pos.shape[0]):
            er -= ext[k, 0] * pos[k, 0] + ext[k, 1] * pos[k, 1] + ext[k, 2] * pos[k, 2]
        for s in range(sn.shape[0]):
            a, b = sn[s]
            fx, fy, fz, en, T, dT, length = spring_eval(pos[a], pos[b], rest[s], width[s], x, y, cum, start,
                                                        comp, table[s])
            er += en
            Fr[a] += (fx, fy, fz)
            Fr[b] -= (fx, fy, fz)
        assert e == er
        assert np.array_equal(F, Fr)


def test_node_force_equals_table_eval():
    for seed in range(4):
        pos, sn, rest, width, table, x, y, cum, start, comp, ext = _scene(seed)
        n, s = pos.shape[0], sn.shape[0]
        node = np.concatenate([sn[:, 0], sn[:, 1]])
        order = np.argsort(node, kind="stable")
        nbr = np.concatenate([sn[:, 1], sn[:, 0]])[order].astype(np.int64)
        sid = np.concatenate([np.arange(s), np.arange(s)])[order].astype(np.int64)
        ptr = np.searchsorted(node[order], np.arange(n + 1)).astype(np.int64)
        out = np.empty(3)
        for k in range(n):
            dpos, dabs = node_force(k, pos, ptr, nbr, sid, rest, width, table, x, y, cum, start, comp, ext, out)
            r = ext[k].copy()
            dp = da = 0.0
            for q in range(ptr[k], ptr[k + 1]):
                sp = sid[q]
                d = pos[nbr[q]] - pos[k]
                length = float(np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))
                T = table_eval(x, y, cum, start, comp, table[sp], length / rest[sp] - 1.0)[0]
                if length >= 1e-14:
                    r += T * width[sp] / length * d
                el = length - rest[sp]
                dp += max(el, 0.0)
                da += abs(el)
            np.testing.assert_allclose(out, r, rtol=1e-15, atol=1e-300)
            assert dpos == dp and dabs == da


def test_bench_reference_pass_does_the_same_work_on_taut_springs():
    """The benchmark's work unit (bench.reference_pass, independent of clothsim.kernels) computes
    the same forces and energy as forces_and_energy when no spring is slack."""
    from clothsim.bench import reference_pass

    pos, sn, rest, width, table, x, y, cum, start, comp, ext = _scene(0)
    length = np.linalg.norm(pos[sn[:, 1]] - pos[sn[:, 0]], axis=1)
    rest = np.where(length > 0, length / np.random.default_rng(1).uniform(1.01, 1.6, len(rest)), rest)
    taut = length > 0
    sn, rest, width, table = sn[taut], rest[taut], width[taut], table[taut]
    F = np.empty_like(pos)
    Fr = np.empty_like(pos)
    e = forces_and_energy(pos, sn, rest, width, table, x, y, cum, start, comp, np.zeros_like(pos), F)
    er = reference_pass(pos, sn, rest, width, table, x, y, start, Fr)
    np.testing.assert_allclose(Fr, F, rtol=0, atol=1e-12 * np.abs(F).max())
    assert abs(er - e) <= 1e-12 * abs(e)


def test_node_spring_block_equals_table_eval():
    """settle.node_spring_block (the sequencing's node-wise Gauss-Seidel; its lookup inline): its
    resultant is node_force's and its block the sum of the springs' spring_hessian_block (a slack
    spring at its kink stiffness), to rounding; its shortest rest length exact."""
    from clothsim.kernels import spring_hessian_block
    from clothsim.solvers.newton.settle import node_spring_block

    for seed in range(4):
        pos, sn, rest, width, table, x, y, cum, start, comp, ext = _scene(seed)
        n, s = pos.shape[0], sn.shape[0]
        kink = np.random.default_rng(seed).uniform(0.0, 50.0, s) * (seed % 2)
        # springs at exactly strain 0 (rest length = length): the slack branch's boundary
        d = pos[sn[3:9, 1]] - pos[sn[3:9, 0]]
        rest[3:9] = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])
        node = np.concatenate([sn[:, 0], sn[:, 1]])
        order = np.argsort(node, kind="stable")
        nbr = np.concatenate([sn[:, 1], sn[:, 0]])[order].astype(np.int64)
        sid = np.concatenate([np.arange(s), np.arange(s)])[order].astype(np.int64)
        ptr = np.searchsorted(node[order], np.arange(n + 1)).astype(np.int64)
        f, H, Kb, ref = np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
        checked = 0
        for k in range(n):
            if ptr[k + 1] == ptr[k]:
                continue
            lmin = node_spring_block(k, pos, ptr, sid, nbr, rest, width, table, x, y, cum, start, comp, kink, ext,
                                     f, H)
            node_force(k, pos, ptr, nbr, sid, rest, width, table, x, y, cum, start, comp, ext, ref)
            Href = np.zeros((3, 3))
            for q in range(ptr[k], ptr[k + 1]):
                sp = sid[q]
                if np.linalg.norm(pos[nbr[q]] - pos[k]) < 1e-14:
                    continue
                spring_hessian_block(pos[k], pos[nbr[q]], rest[sp], width[sp], x, y, cum, start, comp, table[sp],
                                     kink[sp], Kb)
                Href += Kb
            scale = np.abs(Href).max() + 1e-300
            np.testing.assert_allclose(f, ref, rtol=1e-12, atol=1e-12 * (np.abs(ref).max() + 1e-300))
            np.testing.assert_allclose(H, Href, rtol=1e-12, atol=1e-12 * scale)
            assert lmin == rest[sid[ptr[k]:ptr[k + 1]]].min()
            checked += 1
        assert checked > 40


def test_assemble_equals_spring_hessian_block():
    """linalg._assemble (the Newton matrix; its lookup inline): each block is the sum, in spring
    order, of the springs' spring_hessian_block (+ on the diagonal blocks, - off it; a slack
    spring at its kink stiffness), to rounding."""
    from clothsim.kernels import spring_hessian_block
    from clothsim.solvers.newton.linalg import _assemble, _bsr_pattern

    for seed in range(4):
        pos, sn, rest, width, table, x, y, cum, start, comp, ext = _scene(seed)
        n, s = pos.shape[0], sn.shape[0]
        kink = np.random.default_rng(seed).uniform(0.0, 50.0, s) * (seed % 2)
        d = pos[sn[3:9, 1]] - pos[sn[3:9, 0]]
        rest[3:9] = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])  # strain 0
        indptr, indices, slot, diag = _bsr_pattern(n, sn)
        data = np.full((indices.shape[0], 3, 3), np.nan)
        _assemble(pos, sn, rest, width, table, x, y, cum, start, comp, kink, slot, data)
        ref = np.zeros_like(data)
        Kb = np.empty((3, 3))
        for sp in range(s):
            spring_hessian_block(pos[sn[sp, 0]], pos[sn[sp, 1]], rest[sp], width[sp], x, y, cum, start, comp,
                                 table[sp], kink[sp], Kb)
            if np.linalg.norm(pos[sn[sp, 1]] - pos[sn[sp, 0]]) < 1e-14:
                continue
            for q, sg in zip(slot[sp], (1.0, 1.0, -1.0, -1.0)):
                ref[q] += sg * Kb
        scale = np.abs(ref).max()
        assert scale > 0
        np.testing.assert_allclose(data, ref, rtol=1e-12, atol=1e-12 * scale)
