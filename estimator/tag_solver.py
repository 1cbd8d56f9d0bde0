"""The 3-D graph's Levenberg-Marquardt solve driven from numpy: every corner view linearised at
once, the damped normal equations solved by a sparse factorisation, GTSAM's own step rules.

GTSAM's optimiser calls a Python factor once per factor and copies the whole ``Values`` into
Python for each call, so a graph of n views over m poses costs O(n m) a linearisation (46 s of
test 2's 52 s in TagSLAM's suite). Here the corner residuals and Jacobians of all views come from
one vectorised call (:func:`~markergraph.estimator.corner_factor.residuals`), GTSAM's built-in
factors (priors, odometry) are linearised by GTSAM in C++, and the steps follow
``LevenbergMarquardtOptimizer`` (lambda from 1e-5, times 10 on a failed step and divided by 10 on
a good one, a step kept when the cost falls by more than 0.001 of what the linear model
promised, the relative and absolute decrease tests, ``Values.retract``): on the same graph it
lands on GTSAM's solution to within rounding (tests/test_rig3d_speed.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.corner_factor import adjoint_inverse, residuals
from markergraph.estimator.tags3d import tag_corners

if TYPE_CHECKING:
    import scipy.sparse

__all__ = [
    "CornerViews",
    "Covariances",
    "LmSettings",
    "corner_residuals",
    "covariances",
    "solve_lm",
]

POSE_DIM = 6
RIG_SYMBOL = "x"
"""The rig poses' key symbol (:func:`~markergraph.estimator.tag_graph.rig_key`): last in
key order, after the mounts' ``c`` and the tags' ``t``."""


@dataclass(frozen=True)
class LmSettings:
    """GTSAM's ``LevenbergMarquardtParams`` that the solve reads (their defaults but for the
    tolerances and iterations, which the caller sets)."""

    relative_tolerance: float
    absolute_tolerance: float
    max_iterations: int
    lambda_initial: float = 1e-5
    lambda_factor: float = 10.0
    lambda_upper: float = 1e5
    min_model_fidelity: float = 1e-3


@dataclass(frozen=True)
class CornerViews:
    """Every corner view of the graph, laid out for one vectorised evaluation.

    Attributes:
        rig_keys, tag_keys: (n,) each view's rig-pose and tag-pose keys.
        mount_keys: (n,) each view's estimated mount's key, 0 where the mount is fixed.
        mounts: (n, 4, 4) each view's fixed mount (unused where estimated).
        corners: (n, 4, 3) each view's tag corners in the tag's frame [m].
        rays: (n, 4, 2) the corners seen (normalised image coordinates).
        inverse_sigmas: (n, 8) one over each coordinate's noise.
        robust_k: the Cauchy kernel's width on each view [sigmas], None for none.
    """

    rig_keys: NDArray[np.uint64]
    tag_keys: NDArray[np.uint64]
    mount_keys: NDArray[np.uint64]
    mounts: NDArray[np.float64]
    corners: NDArray[np.float64]
    rays: NDArray[np.float64]
    inverse_sigmas: NDArray[np.float64]
    robust_k: float | None = None

    @staticmethod
    def of(views: list[tuple[int, int, int | None, NDArray[np.float64], float,
                             NDArray[np.float64], NDArray[np.float64]]],
           robust_k: float | None = None) -> CornerViews:  # fmt: skip
        """From ``(rig key, tag key, mount key or None, fixed mount (4, 4), tag side [m],
        rays (4, 2), sigmas (8,))`` per view."""
        return CornerViews(
            np.array([v[0] for v in views], dtype=np.uint64),
            np.array([v[1] for v in views], dtype=np.uint64),
            np.array([v[2] or 0 for v in views], dtype=np.uint64),
            np.array([v[3] for v in views]).reshape(-1, 4, 4),
            np.array([tag_corners(v[4]) for v in views]).reshape(-1, 4, 3),
            np.array([v[5] for v in views]).reshape(-1, 4, 2),
            1.0 / np.array([v[6] for v in views]).reshape(-1, 8),
            robust_k,
        )


@dataclass(frozen=True)
class _Linear:
    """The system linearised at a point: each view's whitened (n, 8, 6) Jacobians with respect
    to its rig pose, tag and camera (the last used only where the mount is estimated), b
    (n, 8), the built-in factors' sparse rows and b, and the normal equations."""

    J_rig: NDArray[np.float64]
    J_tag: NDArray[np.float64]
    J_camera: NDArray[np.float64]
    b: NDArray[np.float64]
    J_builtin: scipy.sparse.csr_matrix
    b_builtin: NDArray[np.float64]
    normal: _Normal

    def error_at_zero(self) -> float:
        """Half the squared norm of b."""
        return 0.5 * (float(np.sum(self.b * self.b)) + float(self.b_builtin @ self.b_builtin))


class _Problem:
    """The poses as arrays, indexed as the ``Values`` orders its keys."""

    def __init__(self, corners: CornerViews, builtin: gtsam.NonlinearFactorGraph,
                 values: gtsam.Values) -> None:  # fmt: skip
        self.corners, self.builtin = corners, builtin
        self.keys = np.array(list(values.keys()), dtype=np.uint64)
        index = {int(k): i for i, k in enumerate(self.keys)}
        self.rig = np.array([index[int(k)] for k in corners.rig_keys], dtype=np.int64)
        self.tag = np.array([index[int(k)] for k in corners.tag_keys], dtype=np.int64)
        self.estimated = corners.mount_keys != 0
        self.mount = np.array(
            [index[int(k)] if k else -1 for k in corners.mount_keys], dtype=np.int64
        )
        self.index = index
        rigs = [gtsam.Symbol(int(k)).chr() == ord(RIG_SYMBOL) for k in self.keys]
        self.frames = int(np.sum(rigs))
        if not all(rigs[len(rigs) - self.frames :]):
            raise ValueError("the rig poses must come last in key order")
        self.n = POSE_DIM * len(self.keys)

    def poses(self, values: gtsam.Values) -> NDArray[np.float64]:
        """(m, 4, 4) every pose, in key order."""
        rows = gtsam.utilities.extractPose3(values)
        T = np.zeros((len(rows), 4, 4))
        T[:, :3, :3] = rows[:, :9].reshape(-1, 3, 3)
        T[:, :3, 3] = rows[:, 9:]
        T[:, 3, 3] = 1.0
        return T

    def residuals(self, values: gtsam.Values, jacobians: bool) -> tuple[
        NDArray[np.float64],
        NDArray[np.float64] | None,
        NDArray[np.float64] | None,
        NDArray[np.float64],
    ]:  # fmt: skip
        """The residuals (n, 8), the Jacobians as :func:`residuals` gives them, and each
        view's mount now (all unwhitened)."""
        c = self.corners
        T = self.poses(values)
        mounts = c.mounts.copy()
        mounts[self.estimated] = T[self.mount[self.estimated]]
        residual, J_camera, J_tag = residuals(
            T[self.rig] @ mounts, T[self.tag], c.corners, c.rays, jacobians
        )
        return residual, J_camera, J_tag, mounts

    def error(self, values: gtsam.Values) -> float:
        """GTSAM's error: half the squared whitened residuals, or the Cauchy loss of each
        view's whitened norm, plus the built-in factors'."""
        e = self.residuals(values, False)[0] * self.corners.inverse_sigmas
        squared = np.sum(e * e, axis=1)
        k = self.corners.robust_k
        if k is None:
            corner = 0.5 * float(np.sum(squared))
        else:
            corner = float(np.sum(0.5 * k * k * np.log1p(squared / (k * k))))
        return corner + float(self.builtin.error(values))

    def linearise(self, values: gtsam.Values) -> _Linear:
        """The whitened Jacobians, right-hand side b (the negated whitened errors, reweighted
        by the kernel as GTSAM's ``Robust::WhitenSystem`` does) and the normal equations."""
        e, J_camera, J_tag, mounts = self.residuals(values, True)
        e = e * self.corners.inverse_sigmas
        assert J_camera is not None and J_tag is not None  # asked for
        w = self.corners.inverse_sigmas[:, :, None]
        J_rig = (J_camera @ adjoint_inverse(mounts)) * w
        J_camera, J_tag = J_camera * w, J_tag * w
        k = self.corners.robust_k
        if k is not None:
            weight = np.sqrt(k * k / (k * k + np.sum(e * e, axis=1)))[:, None]
            e = e * weight
            J_rig, J_camera, J_tag = (J * weight[:, :, None] for J in (J_rig, J_camera, J_tag))
        builtin_J, builtin_b = self._builtin(values)
        normal = self._normal(J_rig, J_tag, J_camera, -e, builtin_J, builtin_b)
        return _Linear(J_rig, J_tag, J_camera, -e, builtin_J, builtin_b, normal)

    def linear_error(self, linear: _Linear, delta: NDArray[np.float64]) -> float:
        """Half the squared norm of J delta - b: the linearised system's error at ``delta``."""
        step = delta.reshape(-1, POSE_DIM, 1)
        r = linear.J_rig @ step[self.rig] + linear.J_tag @ step[self.tag] - linear.b[:, :, None]
        m = self.estimated
        if m.any():
            r[m] += linear.J_camera[m] @ step[self.mount[m]]
        rest = linear.J_builtin @ delta - linear.b_builtin
        return 0.5 * (float(np.sum(r * r)) + float(rest @ rest))

    def _normal(
        self,
        J_rig: NDArray[np.float64],
        J_tag: NDArray[np.float64],
        J_camera: NDArray[np.float64],
        b: NDArray[np.float64],
        builtin_J: scipy.sparse.csr_matrix,
        builtin_b: NDArray[np.float64],
    ) -> _Normal:
        """J^T J and J^T b in blocks, each view's 6x6 products added where they belong (a
        sparse product of the whole Jacobian cost ten times as much)."""
        K, F = len(self.keys) - self.frames, self.frames
        f, t = self.rig - K, self.tag
        T = np.swapaxes
        diagonal = np.zeros((F, POSE_DIM, POSE_DIM))
        np.add.at(diagonal, f, T(J_rig, 1, 2) @ J_rig)
        C = np.zeros((K * K, POSE_DIM, POSE_DIM))
        np.add.at(C, t * K + t, T(J_tag, 1, 2) @ J_tag)
        B = np.zeros((F * K, POSE_DIM, POSE_DIM))
        np.add.at(B, f * K + t, T(J_rig, 1, 2) @ J_tag)
        g = np.zeros((K + F, POSE_DIM))
        np.add.at(g, self.rig, (T(J_rig, 1, 2) @ b[:, :, None])[..., 0])
        np.add.at(g, t, (T(J_tag, 1, 2) @ b[:, :, None])[..., 0])
        m = self.estimated
        if m.any():
            c, Jc = self.mount[m], J_camera[m]
            np.add.at(C, c * K + c, T(Jc, 1, 2) @ Jc)
            tc = T(J_tag[m], 1, 2) @ Jc
            np.add.at(C, t[m] * K + c, tc)
            np.add.at(C, c * K + t[m], T(tc, 1, 2))
            np.add.at(B, f[m] * K + c, T(J_rig[m], 1, 2) @ Jc)
            np.add.at(g, c, (T(Jc, 1, 2) @ b[m][:, :, None])[..., 0])
        normal = _Normal(
            diagonal,
            np.zeros((max(F - 1, 0), POSE_DIM, POSE_DIM)),
            B.reshape(F, K, POSE_DIM, POSE_DIM).transpose(0, 2, 1, 3).reshape(6 * F, 6 * K),
            C.reshape(K, K, POSE_DIM, POSE_DIM).transpose(0, 2, 1, 3).reshape(6 * K, 6 * K),
            g.ravel(),
        )
        normal.add_sparse(builtin_J.T.tocsr() @ builtin_J, builtin_J.T @ builtin_b)
        return normal

    def _builtin(self, values: gtsam.Values) -> tuple[scipy.sparse.csr_matrix, NDArray[np.float64]]:
        """GTSAM's linearisation of its own factors as a sparse (rows, n) block and its b."""
        import scipy.sparse

        linear = self.builtin.linearize(values)
        if linear.size() == 0:
            return scipy.sparse.csr_matrix((0, self.n)), np.zeros(0)
        keys = sorted(int(k) for k in linear.keyVector())
        # sparseJacobian_: 1-based (row, column, value) triplets over the graph's keys in
        # sorted order, its last column the right-hand side.
        triplets = linear.sparseJacobian_()
        i = triplets[0].astype(np.int64) - 1
        j = triplets[1].astype(np.int64) - 1
        rows = int(i.max()) + 1 if i.size else 0
        rhs = j == POSE_DIM * len(keys)
        b = np.zeros(rows)
        b[i[rhs]] = triplets[2][rhs]
        column = np.array([POSE_DIM * self.index[k] for k in keys])[j[~rhs] // POSE_DIM]
        J = scipy.sparse.csr_matrix(
            (triplets[2][~rhs], (i[~rhs], column + j[~rhs] % POSE_DIM)), shape=(rows, self.n)
        )
        return J, b

    def retract(self, values: gtsam.Values, delta: NDArray[np.float64]) -> gtsam.Values:
        update = gtsam.VectorValues()
        for i, key in enumerate(self.keys):
            update.insert(int(key), delta[POSE_DIM * i : POSE_DIM * i + POSE_DIM])
        return values.retract(update)


@dataclass
class _Normal:
    """The normal equations J^T J delta = J^T b, the rig poses (last in key order) apart.

    Attributes:
        diagonal: (F, 6, 6) each rig pose's block; below: (F - 1, 6, 6) the blocks joining
            frame f + 1 to frame f (odometry or the motion prior; nothing else joins frames).
        B: (6F, 6K) the rig poses against the K tags and mounts; C: (6K, 6K) those together.
        g: (6K + 6F,) J^T b in key order.
    """

    diagonal: NDArray[np.float64]
    below: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    g: NDArray[np.float64]

    def add_sparse(self, H: scipy.sparse.csr_matrix, g: NDArray[np.float64]) -> None:
        """Add the built-in factors' (sparse) share.

        Raises:
            ValueError: a factor joins two rig poses that are not neighbours in time.
        """
        k = self.C.shape[0]
        H = H.tocoo()
        i, j, v = H.row, H.col, H.data
        both = (i < k) & (j < k)
        np.add.at(self.C, (i[both], j[both]), v[both])
        rig = (i >= k) & (j < k)
        np.add.at(self.B, (i[rig] - k, j[rig]), v[rig])
        frames = (i >= k) & (j >= k)
        fi, fj = (i[frames] - k) // POSE_DIM, (j[frames] - k) // POSE_DIM
        a, b, w = (i[frames] - k) % POSE_DIM, (j[frames] - k) % POSE_DIM, v[frames]
        if np.any(np.abs(fi - fj) > 1):
            raise ValueError("a factor joins rig poses that are not neighbours in time")
        same, next_ = fi == fj, fi == fj + 1
        np.add.at(self.diagonal, (fi[same], a[same], b[same]), w[same])
        np.add.at(self.below, (fj[next_], a[next_], b[next_]), w[next_])
        self.g = self.g + g

    def banded(self, lam: float) -> NDArray[np.float64]:
        """The rig poses' block, damped by ``lam``, in ``cholesky_banded``'s lower form (11
        sub-diagonals)."""
        F = len(self.diagonal)
        ab = np.zeros((2 * POSE_DIM, POSE_DIM * F))
        a, b = np.tril_indices(POSE_DIM)
        start = POSE_DIM * np.arange(F)[:, None]
        ab[a - b, start + b] = self.diagonal[:, a, b]
        ab[0] += lam
        if F > 1:
            a, b = np.indices((POSE_DIM, POSE_DIM)).reshape(2, -1)
            ab[POSE_DIM + a - b, start[:-1] + b] = self.below[:, a, b]
        return ab


def _schur(
    normal: _Normal, lam: float, strict: bool = True
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The rig poses eliminated from the normal equations damped by ``lam``: the Schur
    complement S over the tags and mounts, its right-hand side, and ``A^-1 [B g_rig]`` (to
    recover the rig poses' step).

    The rig poses come last in key order (``x`` after ``c`` and ``t``) and join only their
    neighbours in time, so their block A is banded (a 6x6 block tridiagonal): a banded
    Cholesky eliminates them in linear time, leaving a dense system over the tags and mounts
    (a few hundred poses at most). A general sparse LU (SuperLU) took 0.4 s a solve on test
    16's 1,812 unknowns; this takes milliseconds.

    Without ``strict``, a block that is not numerically positive definite is solved by LU
    instead (as GTSAM's Marginals go on through a pivot that is barely positive).

    Raises:
        numpy.linalg.LinAlgError: A is not positive definite (``strict``), or singular.
    """
    import scipy.linalg

    k = normal.C.shape[0]
    ab = normal.banded(lam)
    right = np.column_stack([normal.B, normal.g[k:]])
    try:
        X = scipy.linalg.cho_solve_banded(
            (scipy.linalg.cholesky_banded(ab, lower=True), True), right
        )
    except np.linalg.LinAlgError:
        if strict:
            raise
        full = np.zeros((2 * ab.shape[0] - 1, ab.shape[1]))  # solve_banded's form: both halves
        full[ab.shape[0] - 1 :] = ab
        for u in range(1, ab.shape[0]):
            full[ab.shape[0] - 1 - u, u:] = ab[u, : ab.shape[1] - u]
        X = scipy.linalg.solve_banded((ab.shape[0] - 1, ab.shape[0] - 1), full, right)
    S = normal.C + lam * np.eye(k) - normal.B.T @ X[:, :k]
    return S, normal.g[:k] - normal.B.T @ X[:, k], X


def _solve(normal: _Normal, lam: float) -> NDArray[np.float64] | None:
    """The damped normal equations solved through the rig poses' Schur complement
    (:func:`_schur`), None where a factorisation fails (GTSAM's indeterminate system: the step
    is refused and lambda raised)."""
    import scipy.linalg

    try:
        S, rhs, X = _schur(normal, lam)
        delta_c = scipy.linalg.cho_solve(scipy.linalg.cho_factor(S), rhs)
    except np.linalg.LinAlgError:
        return None
    delta = np.concatenate([delta_c, X[:, -1] - X[:, :-1] @ delta_c])
    return delta if np.all(np.isfinite(delta)) else None


class Covariances:
    """The tags' and mounts' marginal covariances at a solution (GTSAM's ``Marginals``
    ``marginalCovariance`` for those keys): the inverse of the Schur complement that the rig
    poses leave, in the tangent space GTSAM uses (rotation first)."""

    def __init__(self, covariance: NDArray[np.float64], keys: list[int]) -> None:
        self.covariance = covariance
        self.at = {key: i for i, key in enumerate(keys)}

    def marginalCovariance(self, key: int) -> NDArray[np.float64]:
        """The (6, 6) covariance of a tag or mount.

        Raises:
            RuntimeError: a key that is not a tag's or a mount's (as GTSAM raises).
        """
        if key not in self.at:
            raise RuntimeError(f"no covariance kept for key {gtsam.DefaultKeyFormatter(key)}")
        i = POSE_DIM * self.at[key]
        return self.covariance[i : i + POSE_DIM, i : i + POSE_DIM].copy()


def covariances(
    corners: CornerViews, builtin: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> Covariances:
    """The tags' and mounts' marginal covariances at ``values``.

    Raises:
        numpy.linalg.LinAlgError: the system is indeterminate or barely determined (a pose the
            factors do not fix, or an eigenvalue at rounding's level: test 24's shallow tags).
    """
    import scipy.linalg

    problem = _Problem(corners, builtin, values)
    S, _, _ = _schur(problem.linearise(values).normal, 0.0, strict=False)
    inverse = scipy.linalg.cho_solve(scipy.linalg.cho_factor(S), np.eye(len(S)))
    if not np.all(np.isfinite(inverse)):
        raise np.linalg.LinAlgError("the marginal covariances are not finite")
    k = len(problem.keys) - problem.frames
    return Covariances(inverse, [int(key) for key in problem.keys[:k]])


def corner_residuals(corners: CornerViews, values: gtsam.Values) -> NDArray[np.float64]:
    """Each view's corner residuals (n, 8) at ``values`` (normalised image coordinates)."""
    problem = _Problem(corners, gtsam.NonlinearFactorGraph(), values)
    return problem.residuals(values, False)[0]


def solve_lm(
    corners: CornerViews,
    builtin: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    settings: LmSettings,
) -> tuple[gtsam.Values, int]:
    """Levenberg-Marquardt on the corner views and GTSAM's built-in factors, from ``values``:
    the solution and the iterations taken (as ``LevenbergMarquardtOptimizer.iterations()``).

    Raises:
        RuntimeError: GTSAM could not evaluate or linearise one of its built-in factors.
    """
    problem = _Problem(corners, builtin, values)
    error = problem.error(values)
    lam, iterations = settings.lambda_initial, 0
    if error <= 0.0:
        return values, 0
    new_error = error
    while True:
        current = new_error
        values, error, lam, stepped = _iterate(problem, values, error, lam, settings)
        iterations += stepped
        new_error = error
        if iterations >= settings.max_iterations or not np.isfinite(current):
            break
        decrease = current - new_error
        if (
            new_error <= 0.0
            or decrease <= settings.absolute_tolerance
            or (decrease / current <= settings.relative_tolerance)
        ):
            break
    return values, iterations


def _iterate(
    problem: _Problem, values: gtsam.Values, error: float, lam: float, settings: LmSettings
) -> tuple[gtsam.Values, float, float, int]:
    """One outer iteration (``LevenbergMarquardtOptimizer::iterate``): lambda raised until a
    step is good, or the search stops. Returns (values, error, lambda, 1 if a step was taken)."""
    linear = problem.linearise(values)
    old_linear = linear.error_at_zero()
    while True:
        delta = _solve(linear.normal, lam)
        successful, stop = False, False
        if delta is not None:
            linear_change = old_linear - problem.linear_error(linear, delta)
            if linear_change >= 0:
                new_values = problem.retract(values, delta)
                new_error = problem.error(new_values)
                change = error - new_error
                if linear_change > np.finfo(float).eps * old_linear:
                    successful = change / linear_change > settings.min_model_fidelity
                if abs(change) < settings.relative_tolerance * error:
                    stop = True
        if successful:
            return new_values, new_error, lam / settings.lambda_factor, 1
        if stop:
            return values, error, lam, 0
        lam *= settings.lambda_factor
        if lam >= settings.lambda_upper:
            return values, error, lam, 0
