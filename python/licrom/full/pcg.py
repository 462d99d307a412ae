"""Block-Jacobi preconditioned conjugate gradients on the block-sparse (3x3) Hessian."""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np
import warp as wp

from .device import Assembly, f64, mat33d, vec3d

__all__ = [
    "BlockHessian", "CGVectors",
    'add_residual_sums', 'diag_kernel', 'partial_sum', 'pcg_direction_kernel', 'pcg_init_kernel', 'pcg_matvec_kernel', 'pcg_update_kernel',
    'stats_kernel']


@wp.kernel
def diag_kernel(out: Assembly, inv_diag: wp.array(dtype=mat33d), partials: wp.array(dtype=f64)):
    # Inverse diagonal blocks (block-Jacobi preconditioner) and |grad|^2.
    i = wp.tid()
    inv_diag[i] = wp.inverse(out.values[out.diag_slots[i]])
    gi = out.grad[i]
    wp.atomic_add(partials, i % partials.shape[0], wp.dot(gi, gi))


# Preconditioned conjugate gradients on the BSR Hessian, block-Jacobi preconditioner.
# scal[row, q, part]: partial sums of q = 0: p.Ap, 1: r.z, 2: r.r, in a ring of three rows
# (iteration k reads row k % 3, writes row (k + 1) % 3, clears row (k + 2) % 3).
@wp.struct
class CGVectors:
    """The preconditioner (inverse diagonal blocks) and the work vectors of the conjugate gradients, with the ring of partial sums ``scal``."""

    inv_diag: wp.array(dtype=mat33d)
    r: wp.array(dtype=vec3d)
    z: wp.array(dtype=vec3d)
    p: wp.array(dtype=vec3d)
    ap: wp.array(dtype=vec3d)
    scal: wp.array3d(dtype=f64)


@wp.func
def partial_sum(scal: wp.array3d(dtype=f64), row: int, q: int):
    s = f64(0.0)
    for j in range(scal.shape[2]):
        s += scal[row, q, j]
    return s


@wp.func
def add_residual_sums(scal: wp.array3d(dtype=f64), row: int, i: int, r: vec3d, z: vec3d):
    """Add ``r.z`` and ``r.r`` of vertex ``i`` to the partial sums of ring row ``row``."""
    part = i % scal.shape[2]
    wp.atomic_add(scal, row, 1, part, wp.dot(r, z))
    wp.atomic_add(scal, row, 2, part, wp.dot(r, r))


@wp.kernel
def pcg_init_kernel(b: wp.array(dtype=vec3d), x: wp.array(dtype=vec3d), cg: CGVectors):
    i = wp.tid()
    bi = b[i]
    zi = cg.inv_diag[i] * bi
    x[i] = vec3d()
    cg.r[i] = bi
    cg.p[i] = zi
    add_residual_sums(cg.scal, 0, i, bi, zi)


@wp.kernel
def pcg_matvec_kernel(offsets: wp.array(dtype=wp.int32), columns: wp.array(dtype=wp.int32), values: wp.array(dtype=mat33d), cg: CGVectors, k: int):
    i = wp.tid()
    s = vec3d()
    for blk in range(offsets[i], offsets[i + 1]):
        s += values[blk] * cg.p[columns[blk]]
    cg.ap[i] = s
    wp.atomic_add(cg.scal, k % 3, 0, i % cg.scal.shape[2], wp.dot(cg.p[i], s))


@wp.kernel
def pcg_update_kernel(x: wp.array(dtype=vec3d), cg: CGVectors, k: int):
    i = wp.tid()
    row = k % 3
    pap = partial_sum(cg.scal, row, 0)
    alpha = f64(0.0)
    if pap > f64(0.0):
        alpha = partial_sum(cg.scal, row, 1) / pap
    x[i] = x[i] + alpha * cg.p[i]
    ri = cg.r[i] - alpha * cg.ap[i]
    cg.r[i] = ri
    zi = cg.inv_diag[i] * ri
    cg.z[i] = zi
    add_residual_sums(cg.scal, (k + 1) % 3, i, ri, zi)


@wp.kernel
def pcg_direction_kernel(cg: CGVectors, k: int):
    i = wp.tid()
    rz_old = partial_sum(cg.scal, k % 3, 1)
    beta = f64(0.0)
    if rz_old > f64(0.0):
        beta = partial_sum(cg.scal, (k + 1) % 3, 1) / rz_old
    cg.p[i] = cg.z[i] + beta * cg.p[i]
    if i < cg.scal.shape[2]:
        clear = (k + 2) % 3
        cg.scal[clear, 0, i] = f64(0.0)
        cg.scal[clear, 1, i] = f64(0.0)
        cg.scal[clear, 2, i] = f64(0.0)


@wp.kernel
def stats_kernel(grad: wp.array(dtype=vec3d), y: wp.array(dtype=vec3d), mass: wp.array(dtype=f64), partials: wp.array2d(dtype=f64)):
    # partials[0]: grad . y, partials[1]: y^T M y
    i = wp.tid()
    yi = y[i]
    slot = i % partials.shape[1]
    wp.atomic_add(partials, 0, slot, wp.dot(grad[i], yi))
    wp.atomic_add(partials, 1, slot, mass[i] * wp.dot(yi, yi))


_CPU_CAPTURE = tuple(int(v) for v in re.findall(r"\d+", wp.config.version)[:2]) >= (1, 13)
"""Whether warp records graphs on the CPU (``wp.ScopedCapture`` on ``"cpu"``, new in warp 1.13)."""
_CG_CHUNK = 12  # CG iterations per CUDA graph launch on a GPU (a multiple of 3: the ring of partial sums)


class BlockHessian:
    """Block-sparse (3x3) Hessian of a tet mesh and its block-Jacobi PCG solve.

    The pattern is fixed for the mesh: a block per vertex pair sharing a tet, rows sorted
    and columns sorted within a row (block CSR). Each tet knows the slots of its 16 blocks
    (``slots``) and each vertex the slot of its diagonal block (``diag_slots``), so the
    evaluation kernels assemble straight into ``values``; the pattern is reused by every
    Newton iteration of every step.

    Args:
        tets: (m, 4) vertex indices.
        n: number of vertices.
        device: warp device name.
        parts: number of partial sums of the reductions.
    """

    def __init__(self, tets: np.ndarray, n: int, device: str, parts: int) -> None:
        rows = np.repeat(tets, 4, axis=1).ravel()  # pairs (a, b) in the order a-major, b-minor
        cols = np.tile(tets, (1, 4)).ravel()
        keys = rows * n + cols
        unique, slot = np.unique(keys, return_inverse=True)
        r = unique // n
        c = (unique % n).astype(np.int32)
        diag = np.searchsorted(unique, np.arange(n, dtype=np.int64) * (n + 1))
        offsets = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))]).astype(np.int32)
        self.n = n
        self.device = device
        self.nnz = len(unique)
        self.pattern = (offsets, c)
        self.values = wp.zeros(self.nnz, dtype=wp.mat33d, device=device)
        self.slots = wp.array(slot.reshape(-1, 16).astype(np.int32), dtype=wp.int32, device=device)
        self.diag_slots = wp.array(diag.astype(np.int32), dtype=wp.int32, device=device)
        self.inv_diag = wp.zeros(n, dtype=wp.mat33d, device=device)
        self._offsets = wp.array(offsets, dtype=wp.int32, device=device)
        self._columns = wp.array(c, dtype=wp.int32, device=device)
        self._scal = wp.zeros((3, 3, parts), dtype=f64, device=device)
        self._cg = CGVectors()
        self._cg.inv_diag, self._cg.scal = self.inv_diag, self._scal
        self._cg.r, self._cg.z, self._cg.p, self._cg.ap = (wp.zeros(n, dtype=wp.vec3d, device=device) for _ in range(4))
        self._graphs: dict[int, Any] = {}  # by the solution array: the graph writes into it

    def _launch_iteration(self, y: Any, it: int) -> None:
        dev, n, cg = self.device, self.n, self._cg
        wp.launch(pcg_matvec_kernel, dim=n, device=dev, inputs=[self._offsets, self._columns, self.values, cg, it])
        wp.launch(pcg_update_kernel, dim=n, device=dev, inputs=[y, cg, it])
        wp.launch(pcg_direction_kernel, dim=n, device=dev, inputs=[cg, it])

    def solve(self, b: Any, y: Any, tol: float, maxiter: int) -> int:
        """Solve ``H y = b`` to relative residual ``tol`` (``inv_diag`` must be current).

        Returns the number of iterations. ``y`` starts from zero, so every iterate is a
        descent direction of the incremental potential (along ``-y`` when ``b`` is the gradient).
        """
        scal = self._scal
        scal.zero_()
        wp.launch(pcg_init_kernel, dim=self.n, device=self.device, inputs=[b, y, self._cg])
        bb = float(scal.numpy()[0, 2].sum())
        if not (bb > 0.0) or not math.isfinite(bb):
            return 0
        threshold = tol * tol * bb
        if self.device != "cpu":
            return self._solve_graphed(y, threshold, maxiter)
        graphs = self._cpu_graphs(y)
        sums = scal.numpy()  # a view of the CPU array: read after each iteration
        it = 0
        while it < maxiter:
            if graphs:
                wp.capture_launch(graphs[it % 3])
            else:
                self._launch_iteration(y, it)
            it += 1
            rr = float(sums[it % 3, 2].sum())
            if not rr > threshold:  # also stops on NaN
                break
        return it

    def _cpu_graphs(self, y: Any) -> list[Any] | None:
        """One iteration on the CPU as three recorded graphs, one per turn of the ring of partial sums.

        Replaying a recorded graph (warp >= 1.13 records CPU graphs) skips the Python packing of
        the three launches' arguments, which took about a third of a full step's time on the
        demo's 864-tet mesh; the iterations and the results are the same, bit for bit. None
        where warp cannot record CPU graphs (the plain launches are used).
        """
        if y.ptr in self._graphs:
            return self._graphs[y.ptr]
        graphs = None
        if _CPU_CAPTURE:
            try:
                graphs = []
                for k in range(3):  # recording launches nothing
                    with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                        self._launch_iteration(y, k)
                    graphs.append(capture.graph)
            except Exception:  # an older or unusual warp: fall back to plain launches
                graphs = None
        self._graphs[y.ptr] = graphs
        return graphs

    def _solve_graphed(self, y: Any, threshold: float, maxiter: int) -> int:
        """The PCG iterations on a GPU: chunks of iterations replayed as one CUDA graph.

        One graph serves every chunk (a chunk is a whole number of turns of the ring of
        partial sums); the residual is read back between chunks. Iterating a little past
        the tolerance only makes the solve more accurate.
        """
        graph = self._graphs.get(y.ptr)
        if graph is None:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                for it in range(_CG_CHUNK):
                    self._launch_iteration(y, it)
            graph = self._graphs[y.ptr] = capture.graph
        it = 0
        while it < maxiter:
            wp.capture_launch(graph)
            it += _CG_CHUNK
            rr = float(self._scal.numpy()[0, 2].sum())  # _CG_CHUNK % 3 == 0: the next iteration reads row 0
            if not rr > threshold:
                break
        return it
