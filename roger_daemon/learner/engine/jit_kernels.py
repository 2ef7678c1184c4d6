"""Compiled inner loops of the learner (numba), for the per-expert hot path.

Imported through :mod:`.jit`, which loads this module (and numba, ~1 s) on first use only.

Every learner step evaluates each unique expert once (kernel vector, ``C k``, ``k^T C k``, mean)
and updates the chosen ones; with small experts (the AIBO experiment's broad kernel keeps ~15
basis vectors) the cost was numpy's per-call overhead, not arithmetic.  These kernels do one
expert's work in one call:

``C`` and ``Q`` are stored packed (their upper triangles, :mod:`.packed`): every pass over
them streams half the bytes of a full matrix.

* :func:`kernel_values`: the kernel's values ``exp(-gamma |b_i - x|^2)``, four basis vectors
  at a time, the one code of every kernel vector (:func:`kernel_vector`, :func:`expert_terms`)
  and of :func:`gram_matrix`'s rows;
* :func:`expert_terms`: ``k``, ``C k``, ``k^T C k`` and ``k^T A`` in one pass, at every size;
* :func:`sym_matvec`: ``S v`` of a packed matrix (:func:`sym_matvec_into`), and
  :func:`sym_row`, one row of it; :func:`projection`: ``Q k`` and ``k^T Q k`` for the novelty
  test, whose rule is :func:`novelty_test`;
* :func:`packed_add_lowrank`: the low-rank updates of the steps other than the fused one;
* :func:`gram_matrix`: ``K_B`` recomputed from the basis for a re-inversion of ``Q``;
* :func:`min_argmax`: numpy's ``min`` and first ``argmax`` of a vector, NaN rules included;
* the fused add-then-delete step is in :mod:`.jit_fused`, the compiled Cholesky inverse in
  :mod:`.jit_cholesky`, the gates' and the segmentation history's kernels in
  :mod:`.jit_particles`; several experts' kernels per call, over the cores, in
  :mod:`.jit_batch`.

Reductions may be reassociated (``fastmath={"reassoc", "contract"}``: no NaN/inf assumptions), so
the floats differ from numpy's in the last bits, like another BLAS kernel's; the compiled code
is fixed, so one machine gives the same floats every run (docs/reproducibility.md).  Each
routine is tested against a numpy oracle (tests/learner/test_jit.py).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_compile import compiled as _compiled

__all__ = ["expert_terms", "gram_matrix", "keeps_basis_vectors", "kernel_vector", "min_argmax",
           "novelty_margin", "novelty_test", "packed_add_lowrank", "projection", "sym_matvec",
           "sym_matvec_into", "sym_row"]

FloatArray = npt.NDArray[np.float64]
_FM = {"reassoc", "contract"}

#: ``exp(a)`` is +0.0 for every ``a`` below this: the true value is under 2**-1082, far below
#: half the smallest subnormal (2**-1075, ``a = -745.13``), so any libm accurate to one ulp
#: rounds it to zero (tested over the range on the running machine)
EXP_ZERO_BELOW = -750.0


@_compiled(nogil=True, inline="always")
def rbf(gamma: float, sq_dist: float) -> float:
    """``exp(-gamma * sq_dist)``, the RBF kernel's value at squared distance ``sq_dist``: the
    very float of ``math.exp``, without calling it where it underflows to zero.  With a narrow
    kernel most basis vectors of an expert are far from the point (at the paper's parameters
    ~85 % of them, ``-gamma * d^2`` near -1,000), and libm's underflow path costs ~25 ns a
    call: three times the distance itself (docs/performance.md, *Underflowing kernel
    values*).  The one owner of the kernel's value in the compiled code."""
    a = -gamma * sq_dist
    if a < EXP_ZERO_BELOW:
        return 0.0
    return math.exp(a)


@_compiled(fastmath=_FM, nogil=True, inline="always")
def _four_values(basis: FloatArray, i0: int, i1: int, i2: int, i3: int, x: FloatArray,
                 gamma: float, out: FloatArray) -> None:
    """``out[i_r] = exp(-gamma |basis[i_r] - x|^2)`` for four rows (:func:`kernel_values`)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    for j in range(basis.shape[1]):
        xj = x[j]
        t0 = basis[i0, j] - xj
        t1 = basis[i1, j] - xj
        t2 = basis[i2, j] - xj
        t3 = basis[i3, j] - xj
        s0 += t0 * t0
        s1 += t1 * t1
        s2 += t2 * t2
        s3 += t3 * t3
    out[i0] = rbf(gamma, s0)
    out[i1] = rbf(gamma, s1)
    out[i2] = rbf(gamma, s2)
    out[i3] = rbf(gamma, s3)


@_compiled(fastmath=_FM, nogil=True, inline="always")
def kernel_values(basis: FloatArray, x: FloatArray, gamma: float, n: int,
                  out: FloatArray) -> None:
    """``out[i] = exp(-gamma |b_i - x|^2)`` for the first ``n`` rows of ``basis`` (explicit
    differences; :func:`rbf`), four rows at a time (:func:`_four_values`): four independent
    sums side by side instead of one row's dependent additions at a time (1.5x on the 20
    experts of a step, docs/performance.md, *Four kernel values at a time*).

    LLVM may reassociate each row's sum (``_FM``, as in the one-row loop before), so a row
    computed by other code could differ in its last bit.  Every row therefore goes through
    the same four-row code, whatever its place: the last rows in a block that overlaps the
    one before (computed twice, the same floats), fewer than four rows with the last one
    repeated, from one call site.  So the value of a basis vector does not depend on where
    it sits, and :func:`gram_matrix`, made of these rows, holds the very floats of the
    kernel vectors (both tested)."""
    last = n - 1
    for block in range((n + 3) // 4):  # one call site: one compiled body for every row
        i = max(min(4 * block, n - 4), 0)
        _four_values(basis, i, min(i + 1, last), min(i + 2, last), min(i + 3, last), x, gamma,
                     out)


@_compiled(fastmath=_FM, nogil=True)
def kernel_vector(basis: FloatArray, x: FloatArray, gamma: float, n: int) -> FloatArray:
    """``exp(-gamma |b_i - x|^2)`` for the first ``n`` rows of ``basis``
    (:func:`kernel_values`)."""
    k = np.empty(n)
    kernel_values(basis, x, gamma, n, k)
    return k


@_compiled(fastmath=_FM, nogil=True)
def gram_matrix(basis: FloatArray, gamma: float, n: int) -> FloatArray:
    """``K[i, m] = exp(-gamma |b_i - b_m|^2)`` over the first ``n`` rows of ``basis``, full
    (n, n), exactly symmetric.  Row ``m`` is :func:`kernel_values` at ``b_m``, the code of
    every kernel vector (``(a - b)^2`` equals ``(b - a)^2`` exactly, and a row's value does
    not depend on its place), so the re-inversion of ``Q`` sees the very floats of the
    kernel vectors computed when each basis vector entered (tested); the diagonal is
    ``exp(0) = 1 = k*``."""
    out = np.empty((n, n))
    for m in range(n):
        kernel_values(basis, basis[m], gamma, n, out[m])
    return out


@_compiled(fastmath=_FM, nogil=True)
def sym_matvec_into(buf: FloatArray, v: FloatArray, n: int, alloc: int, out: FloatArray) -> None:
    """``out[:n] = S v`` for the symmetric ``S`` packed in ``buf`` (:mod:`.packed`): one
    streaming pass over the upper triangle of the live block, each stored ``S_ij`` used for
    row ``i`` (a dot product) and row ``j`` (an axpy).  Four rows at a time
    (:func:`_four_rows`), so that each load and store of the axpy's accumulator serves four
    rows (1.2x against two rows at a time, which was 1.2x cache-cold and 1.5x cached against
    one: docs/performance.md, *One parallel region for the evaluation; four rows per pass*);
    the last rows two and one at a time.

    A ``v`` that is exactly zero (an expert far from the point: with a narrow kernel every
    ``exp`` underflows) gives ``out = 0`` without reading ``S``: the same floats, since every
    product would be a signed zero added to ``+0.0`` (docs/performance.md, *Zero kernel
    vectors*)."""
    nonzero = False
    for i in range(n):
        out[i] = 0.0
        if v[i] != 0.0:
            nonzero = True
    if not nonzero:
        return
    off = 0
    i = 0
    while i + 3 < n:
        off = _four_rows(buf, v, n, alloc, out, i, off)
        i += 4
    if i + 1 < n:
        r0 = buf[off: off + n - i]  # S[i, i:n]
        off1 = off + alloc - i
        r1 = buf[off1: off1 + n - i - 1]  # S[i+1, i+1:n]
        v0 = v[i]
        v1 = v[i + 1]
        s0 = r0[0] * v0 + r0[1] * v1
        s1 = r1[0] * v1
        out[i + 1] += r0[1] * v0
        if i + 2 < n:  # one row below: S[i, n-1] and S[i+1, n-1]
            a = r0[2]
            b = r1[1]
            t = v[i + 2]
            s0 += a * t
            s1 += b * t
            out[i + 2] += a * v0 + b * v1
        out[i] += s0
        out[i + 1] += s1
        off = off1 + alloc - i - 1
        i += 2
    if i < n:  # the last row of an odd n: its diagonal entry only
        out[i] += buf[off] * v[i]


@_compiled(fastmath=_FM, nogil=True, inline="always")
def _four_rows(buf: FloatArray, v: FloatArray, n: int, alloc: int, out: FloatArray, i: int,
               off: int) -> int:
    """Rows ``i`` to ``i + 3`` of :func:`sym_matvec_into` (row ``i`` packed at ``off``):
    their 4 x 4 diagonal block, then one pass over their columns ``j >= i + 4`` that adds
    ``S_rj v_j`` to each row's dot product and ``sum_r S_rj v_r`` to ``out[j]``; returns
    where row ``i + 4`` starts."""
    off1 = off + alloc - i
    off2 = off1 + alloc - i - 1
    off3 = off2 + alloc - i - 2
    r0 = buf[off: off + n - i]  # S[i, i:n]
    r1 = buf[off1: off1 + n - i - 1]  # S[i+1, i+1:n]
    r2 = buf[off2: off2 + n - i - 2]
    r3 = buf[off3: off3 + n - i - 3]
    v0 = v[i]
    v1 = v[i + 1]
    v2 = v[i + 2]
    v3 = v[i + 3]
    s0 = r0[0] * v0 + r0[1] * v1 + r0[2] * v2 + r0[3] * v3
    s1 = r0[1] * v0 + r1[0] * v1 + r1[1] * v2 + r1[2] * v3
    s2 = r0[2] * v0 + r1[1] * v1 + r2[0] * v2 + r2[1] * v3
    s3 = r0[3] * v0 + r1[2] * v1 + r2[1] * v2 + r3[0] * v3
    t0 = r0[4:]
    t1 = r1[3:]
    t2 = r2[2:]
    t3 = r3[1:]
    tail = v[i + 4:n]
    acc = out[i + 4:n]
    for j in range(n - i - 4):
        a = t0[j]
        b = t1[j]
        c = t2[j]
        d = t3[j]
        t = tail[j]
        s0 += a * t
        s1 += b * t
        s2 += c * t
        s3 += d * t
        acc[j] += a * v0 + b * v1 + c * v2 + d * v3
    out[i] += s0
    out[i + 1] += s1
    out[i + 2] += s2
    out[i + 3] += s3
    return off3 + alloc - i - 3


@_compiled(fastmath=_FM, nogil=True)
def sym_matvec(buf: FloatArray, v: FloatArray, n: int, alloc: int) -> FloatArray:
    """``S v`` over the live ``n x n`` block of the packed symmetric ``S`` (``Q k``)."""
    out = np.empty(n)
    sym_matvec_into(buf, v, n, alloc, out)
    return out


@_compiled(fastmath=_FM, nogil=True)
def projection(buf: FloatArray, k: FloatArray, n: int, alloc: int) -> tuple[FloatArray, float]:
    """``(Q k, k^T Q k)`` for the packed ``Q`` (docs/learner-math.md §2.5 step 3): the
    novelty test's projection of the kernel vector ``k`` onto the basis."""
    e_hat = sym_matvec(buf, k, n, alloc)
    kqk = 0.0
    for i in range(n):
        kqk += k[i] * e_hat[i]
    return e_hat, kqk


@_compiled(nogil=True)
def novelty_test(kqk: float, kstar: float, threshold: float, floor: float,
                 drift_tol: float) -> tuple[float, bool, bool]:
    """Step 3's decision (docs/learner-math.md §2.5): ``(gamma, drifted, novel)`` for the
    projection residual ``gamma = k* - k^T Q k``.  ``drifted``: ``gamma < -drift_tol k*``,
    impossible in exact arithmetic (``Q`` must be re-inverted and the test redone);
    ``gamma`` is 0 below ``floor``; ``novel`` (a full update) iff ``gamma >= threshold k*``
    and ``gamma > 0``.  The one owner of the rule, for one expert at a time
    (:meth:`.sogp_steps.SOGPSteps.novelty`) or in a full expert's batched step
    (:func:`.jit_batch.learn_full_expert`)."""
    gamma = kstar - kqk
    drifted = gamma < -drift_tol * kstar
    if gamma < floor:
        gamma = 0.0
    novel = not (gamma < threshold * kstar or gamma <= 0.0)
    return gamma, drifted, novel


@_compiled(nogil=True)
def novelty_margin(gamma: float, kstar: float, threshold: float) -> float:
    """How close the novelty test (:func:`novelty_test`) that gave ``gamma`` was to flipping,
    in units of ``k*``: ``|gamma - threshold k*| / k*`` (a diagnostic, docs/reproducibility.md).
    The one owner of the formula, for one expert
    (:meth:`.sogp_steps.SOGPSteps.record_novelty_margin`) or in a full expert's batched step
    (:func:`.jit_batch.learn_full_expert`)."""
    return abs(gamma - threshold * kstar) / kstar


@_compiled(nogil=True, error_model="numpy")
def keeps_basis_vectors(q_max: float, floor: float) -> bool:
    """Step 6, the geometric clean-up (Csató; docs/learner-math.md §2.7): the basis vector
    with the largest ``Q_ii`` (``q_max``), and with it every other, stays while
    ``1 / Q_ii >= floor``; ``floor <= 0`` turns the clean-up off.  The one owner of the test,
    for :meth:`.sogp_steps.SOGPSteps._clean_up` and a full expert's batched step
    (:func:`.jit_batch.learn_full_expert`)."""
    return floor <= 0.0 or 1.0 / q_max >= floor


@_compiled(nogil=True)
def sym_row(buf: FloatArray, alloc: int, n: int, i: int) -> FloatArray:
    """Row (= column) ``i`` of the live block of the packed symmetric ``S``."""
    out = np.empty(n)
    off = 0
    for a in range(i):
        out[a] = buf[off + i - a]
        off += alloc - a
    for a in range(i, n):
        out[a] = buf[off + a - i]
    return out


@_compiled(fastmath={"contract"}, nogil=True)
def packed_add_lowrank(buf: FloatArray, alloc: int, n: int, cols: FloatArray,
                       coefs: FloatArray) -> None:
    """``S += cols^T diag(coefs) cols`` on the live ``n x n`` block of the packed ``S``, in
    place; ``cols`` is (m, n), the update's vectors as rows (one pass per vector)."""
    for r in range(cols.shape[0]):
        u = cols[r]
        c = coefs[r]
        off = 0
        for a in range(n):
            row = buf[off: off + n - a]
            tail = u[a:n]
            va = c * u[a]
            for b in range(n - a):
                row[b] += va * tail[b]
            off += alloc - a


@_compiled(fastmath=_FM, nogil=True)
def expert_terms(basis: FloatArray, cov: FloatArray, coef: FloatArray, x: FloatArray,
                 gamma: float, n: int, alloc: int) -> FloatArray:
    """``[k, C k, k^T C k, k^T A]`` over the live ``n`` rows (every column of ``A``; ``C``
    packed for ``alloc`` basis vectors), packed in one array of length ``2 n + 1 + cols``
    (one boxed result: each costs a numba unpickle).

    ``k^T A`` skips the rows whose kernel value is exactly zero (at the paper's parameters
    about half of all entries: docs/performance.md, *Zero kernel vectors*): the same floats,
    since such a row adds a signed zero to an accumulator that starts at ``+0.0`` and so is
    never ``-0.0``."""
    cols = coef.shape[1]
    out = np.zeros(2 * n + 1 + cols)
    k = out[:n]
    kernel_values(basis, x, gamma, n, k)
    ck = out[n: 2 * n]
    sym_matvec_into(cov, k, n, alloc, ck)
    kck = 0.0
    for i in range(n):
        kck += k[i] * ck[i]
    out[2 * n] = kck
    base = 2 * n + 1
    for i in range(n):
        ki = out[i]
        if ki != 0.0:
            for c in range(cols):
                out[base + c] += ki * coef[i, c]
    return out


@_compiled(nogil=True)
def min_argmax(v: FloatArray) -> tuple[float, int]:
    """``(np.min(v), np.argmax(v))`` of a non-empty vector, NaN included: a NaN makes the
    minimum NaN and is the argmax (the first one); otherwise the first maximum."""
    mn = v[0]
    mx = v[0]
    arg = 0
    if v[0] != v[0]:
        return math.nan, 0
    for a in range(1, v.shape[0]):
        x = v[a]
        if x != x:
            return math.nan, a
        if x < mn:
            mn = x
        if x > mx:
            mx = x
            arg = a
    return mn, arg
