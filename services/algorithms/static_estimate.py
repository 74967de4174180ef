"""Incremental estimate of a static relation from a stream of noisy samples.

A static relation computed from dynamic inputs (a camera-to-target pose from PnP composed with
tracker poses, say) arrives as one noisy sample per frame. :class:`StaticEstimator` turns the
stream into one estimate with an honest covariance, a converged flag the caller can stop on,
and a ``not_static`` verdict when the relation moves. One sample at a time, O(1) time and
memory per sample (about 0.45 ms for a pose, most of it the batch-means covariance). Kinds:
``"pose"`` (6D; 6x6 covariance over the left perturbation ``T = Exp(xi) T_mean``, ``xi = (phi,
rho)``), ``"position"`` (3D, 3x3) and ``"rotation"`` (3R, 3x3 over ``phi``, ``R = Exp(phi)
R_mean``); either every sample has a covariance or none has.

Estimate. The weighted mean on the manifold, ``T`` with ``sum_i W_i Log(T_i T^-1) = 0``,
``W_i = Sigma_i^-1`` (Barfoot & Furgale, "Associating uncertainty with three-dimensional poses
for use in estimation problems", IEEE T-RO 30(3), 2014; the batch form is
:func:`ubitrack_agent.services.algorithms.fuse_poses`); for rotations the geodesic counterpart of
the chordal quaternion mean of Markley et al. (2007), with which it agrees to second order in the
spread. Without covariances ``W_i = I``: the plain mean in the tangent space. Information form over
every accepted sample since the start: at a linearisation point ``T_lin`` the sums ``n``,
``Lambda = sum W_i``, ``eta = sum W_i xi_i``, ``c = sum xi_i^T W_i xi_i``, ``s = sum xi_i``,
``S = sum xi_i xi_i^T`` and, for poses and rotations, ``M = sum W_i (x) xi_i`` (d^3 numbers),
``xi_i = Log(T_i T_lin^-1)``. By the Baker-Campbell-Hausdorff series (Barfoot, "State
Estimation for Robotics", 2017, chapter 7) ``Log(T_i (Exp(delta) T_lin)^-1) =
xi_i - delta + ad(delta) xi_i / 2 + O(3)``, so ``sum W_i (xi_i - delta + ad(delta) xi_i / 2)
= eta - Lambda delta + M : ad(delta) / 2``; its root, by one fixed-point step from
``Lambda^-1 eta``, is the estimate ``Exp(delta) T_lin``. When ``delta`` exceeds half a standard
deviation of the estimate, ``T_lin`` moves there and the sums follow to the same order.
Approximation: third-order terms, which do not cancel between samples with different
covariances; measured 1e-3 of the estimate's standard deviation from the batch mean with
per-sample covariances at PnP-like noise (1 degree, 2 mm), 1e-4 with equal ones. A first-order
transport would leave 0.2 of a standard deviation after 300 samples there. Positions are exact.

Robust start. The first ``init_samples`` (K) samples are estimated together by concentration
steps (Rousseeuw & Van Driessen, "A fast algorithm for the minimum covariance determinant
estimator", Technometrics 41(3), 1999): from the sample nearest the coordinate-wise median of
their tangent vectors, keep the ``h = (K + d + 1) // 2`` of smallest Mahalanobis distance,
re-estimate the mean and the noise scale from them (with the trimming consistency factor of
Croux & Haesbroeck, J. Multivariate Analysis 71, 1999), repeat until the subset stays; then the
gate decides which of the K enter. Up to ``K - h`` outliers among the first K (7 of 20 for
poses, 8 for 3-dof kinds) cannot move the start.

Gate. Each later sample's residual ``r = Log(T_i T_hat^-1)`` enters only if
``r^T (S_k Sigma_i + P)^-1 r`` is below the ``gate_probability`` quantile (0.999) of its
distribution: ``d F(d, nu)`` when the scale ``S_k`` is a reduced chi-square with ``nu``
degrees of freedom, Hotelling's ``nu d / (nu - d + 1) F(d, nu - d + 1)`` when it is a whole
estimated covariance (Anderson, "An Introduction to Multivariate Statistical Analysis", 3rd
ed., 2003, section 5.2); ``P`` is the estimate's averaging covariance, d the degrees of freedom
(6 or 3). About 22.5 (4.7 sigma) for poses with covariances. The validation gate of Bar-Shalom,
Li, Kirubarajan, "Estimation with Applications to Tracking and Navigation", 2001, with the
scale's own uncertainty: a 6x6 noise covariance estimated from 20 samples needs a gate of 60,
not 22.5, or good samples are cut and the covariance comes out optimistic. Rejected samples are
counted and never enter: a PnP flip does not move the estimate at all.

Noise scale. With covariances: ``S_k = max(1, k^2) I``, ``k^2 = chi2 / (d (n - 1)) / kappa``
the reduced chi-square (Birge ratio squared) of the accepted residuals about the estimate,
``kappa`` the truncation of a chi-square at the gate (0.997): optimistic covariances are scaled
up, pessimistic ones kept. Without covariances: the noise covariance
``(S - s s^T / n) / (n - 1) / kappa``.

Covariance. ``P = c g Lambda^-1 V Lambda^-1 + common_covariance``, the first term the
averaging part, which more samples reduce. It does not trust the noise model: ``V`` is the
covariance of the score ``sum W_i (xi_i - delta)`` estimated by batch means, the sandwich
(Huber 1967; White, Econometrica 48(4), 1980) with the scores summed over batches of
consecutive samples so that errors correlated in time count as they are (the
heteroskedasticity- and autocorrelation-consistent covariance of Newey & West, Econometrica
55(3), 1987, in its batch-means form: Schmeiser, Operations Research 30(3), 1982; Flegal &
Jones, Annals of Statistics 38(2), 2010). Samples arrive at 30-90 Hz from PnP, whose errors
the stated covariances get wrong in size (the pixel noise estimated from five points' residuals,
four degrees of freedom), in shape (tracker errors a pixel-only covariance leaves out), and in
time: the live flow interpolates a 30 Hz PnP pose to the tracker's instants, so neighbouring
samples share an error (autocorrelation 0.78, 0.43, 0.14 at lags 1-3, measured live), and a
covariance for independent samples came out 3 times too small in variance (NEES 20-30; the
live estimate converged at 2.7 mm from the truth with a stated 1 mm). Batches: between
``BATCHES`` (64) and 128 of consecutive accepted samples, pairs merged when full (dynamic
batch means, Yeh & Schmeiser, Proc. Winter Simulation Conference 2000), O(1) memory; each
batch's score is whitened by its own information before the scatter is taken, so that a few
samples with tiny stated covariances cannot leave the estimate with few degrees of freedom
(:meth:`_Batches.score_covariance`). Batches shorter than the errors' correlation miss part
of it: ``g`` (:func:`batch_length_correction`) restores the share an AR(1) process with the
whitened residuals' lag-one autocorrelation would lose (exact for AR(1), conservative for
shorter-range correlation, 1 for independent samples and long batches). ``c = nu / (nu - d -
1)`` (``nu``, about the number of batches less one, 63 or more from 64 samples on) makes the
inverse unbiased (the inverse Wishart mean, Anderson 2003, chapter 7), so that the estimate's
NEES has the mean d. ``effective_samples`` is ``accepted`` over the variance inflation
against the noise model. The second term is the covariance of an error all samples share (e.g.
a static input composed into each), which no number of samples reduces.

Converged. ``accepted >= min_samples``; the averaging part's RMS translation error
``sqrt(trace(J P J^T))`` (``J = [-[t]x, I]``, the translation's change under ``xi``) at most
``translation_tolerance`` and its RMS rotation error ``sqrt(trace(P_phi))`` at most
``rotation_tolerance``; and stable: the estimate moved by less than those over the last
``stability_window`` accepted samples. The shared part does not count: waiting cannot reduce
it. Once reached, ``converged`` stays (the caller may stop) unless the motion check fires.

Motion check, over the last ``motion_window`` (M) samples, after every sample:

* more than half failed the gate (a jump, a fast motion). With an outlier rate p the false
  alarm per window is ``P(Binomial(M, p) > M/2)``: 1e-13 at p = 5 %, 5e-5 at 20 % (M = 30);
* or the information-weighted mean of the window's accepted samples differs from that of the
  accepted samples before it by more than their noise explains: ``D^T (f S_k (Lambda_w^-1 +
  Lambda_b^-1))^-1 D`` above the ``1 - motion_false_alarm`` quantile of ``d F(d, nu_f)``.
  ``f`` is the variance of the means of blocks of M/2 consecutive accepted samples against
  the noise model's, from the successive differences of the block means taken about their mean
  (:class:`_BlockMeans`, the batch-means control chart of Runger & Willemain, IIE Transactions
  28(6), 1996): errors correlated over fewer than M/2 samples widen it as much as they widen
  the window's mean, and a steady drift, which moves every block alike, does not; ``nu_f``
  counts its degrees of freedom (2/3 d per difference). The test waits for a few blocks: with
  the default window the first 60-90 samples (2-3 s at 30 Hz) can only be stopped by the
  rejections rule. A drift moves the window's mean away from the older samples' however much
  the noise scale grows. False alarm: at most ``motion_false_alarm`` (1e-6) per sample, at
  most 1 % over 10,000 samples by the union bound, far less in fact as overlapping windows are
  strongly correlated.

Either makes the status ``not_static``. The motion may have begun anywhere in the window, so
its samples leave the sums (exactly: they are linear in the samples) and the rest stays as the
last static estimate: no blend of before and after. ``motion`` holds the rule, its statistic
and how far the latest M/2 samples are from that estimate (median, translation in metres and
rotation in radians), updated with every later sample; nothing is averaged any more. Start a
new estimator to estimate again (a remounted target, say).

Limits: correlation over more than a few hundred samples (an error that follows the motion
over a 20 s walk, say) is counted in the covariance only once the batches are that long, and
by the motion check not at all: a static relation whose errors wander that slowly is reported
as moving.
"""

from __future__ import annotations

import math
from collections import deque
from enum import StrEnum
from typing import Any, NamedTuple

import numpy as np
from scipy import stats

from ubitrack_agent.core.measurements import (
    UNIT_QUATERNION_TOLERANCE,
    ErrorPose,
    Measurement,
    Position3D,
    Rotation3D,
)
from ubitrack_agent.services.algorithms._checks import as_array, positive
from ubitrack_agent.services.algorithms.estimate import symmetric
from ubitrack_agent.services.algorithms.tangent import SPACES, Vector

RELINEARISE = 0.5
"""Move the linearisation point when the estimate is this many standard deviations from it."""

NOISE_FLOOR = 1e-9
"""Standard deviation (m, rad) added to an estimated noise covariance, so that noise-free
samples still give an invertible one: far below any tracker's noise."""

CONVERGED_STEP = 1e-13
"""Gauss-Newton stops when the step is below this (m, rad): round-off of values of order 1."""

BATCHES = 64
"""Batch means: between ``BATCHES`` and ``2 BATCHES`` batches of consecutive accepted samples
(their length doubles when there are ``2 BATCHES``), so the covariance rests on at least 63
degrees of freedom once there are 64 samples."""

MAX_AUTOCORRELATION = 0.97
"""Largest lag-one autocorrelation used for the batch-length correction (Andrews & Monahan
1992 restrict their prewhitening filter likewise)."""

MAX_ITERATIONS = 20
"""Iterations of Gauss-Newton and of the concentration steps."""

_MAD_TO_SIGMA = 1.4826
"""Median absolute deviation to standard deviation of a normal distribution."""


class Status(StrEnum):
    """Where the estimator stands."""

    INITIALISING = "initialising"
    """Fewer than ``init_samples`` samples: no estimate yet."""
    AVERAGING = "averaging"
    """An estimate, not yet converged."""
    CONVERGED = "converged"
    """The convergence rule was met: the caller may stop (the estimate keeps improving)."""
    NOT_STATIC = "not_static"
    """The samples move more than their noise explains; nothing is averaged any more."""


class Motion(NamedTuple):
    """What the motion check measured."""

    rule: str
    """``"rejections"`` (most recent samples failed the gate) or ``"window_mean"``."""
    translation: float | None
    """How far the latest ``motion_window / 2`` samples are from the kept estimate (median, m),
    updated with every sample; ``None`` for rotations."""
    rotation: float | None
    """The same as an angle (rad); ``None`` for positions."""
    statistic: float
    """When it fired: the rejected fraction of the window, or the window-mean statistic."""


class StaticState(NamedTuple):
    """The estimator's state after a sample (see :class:`StaticEstimator`)."""

    kind: str
    """``"pose"``, ``"position"`` or ``"rotation"``."""
    status: Status
    rotation: np.ndarray | None
    """Unit quaternion (x, y, z, w) of the estimate (poses and rotations), else ``None``."""
    translation: np.ndarray | None
    """Translation of the pose, or the position (m); ``None`` for rotations."""
    covariance: np.ndarray | None
    """The published covariance (6x6 or 3x3): averaging part plus the common part."""
    accepted: int
    """Samples in the estimate."""
    rejected: int
    """Samples kept out of the estimate: by the robust start, the gate, or withdrawn with the
    motion window when the motion check fired."""
    last_accepted: bool | None
    """Whether the last sample entered; ``None`` while initialising or when not static."""
    noise_scale: float | None
    """Reduced chi-square of the accepted samples (``k^2``; > 1: their covariances are
    optimistic); ``None`` for samples without covariance."""
    effective_samples: float | None
    """How many independent samples of the noise model (the stated covariances times the
    noise scale, or the noise covariance) the estimate is worth: ``accepted`` over the
    batch means' variance inflation (below ``accepted`` when the samples' errors are
    correlated in time)."""
    std_translation: float | None
    """RMS translation error of the averaging part (m), ``sqrt(trace)`` of its translation
    covariance: what more samples reduce. ``None`` for rotations."""
    std_rotation: float | None
    """RMS rotation error of the averaging part (rad); ``None`` for positions."""
    spread_translation: float | None
    """RMS translation residual of the accepted samples about the estimate (m)."""
    spread_rotation: float | None
    """RMS rotation residual of the accepted samples about the estimate (rad)."""
    motion: Motion | None
    """Set when ``status`` is ``not_static``."""

    @property
    def converged(self) -> bool:
        """The convergence rule was met and the relation has not moved since."""
        return self.status is Status.CONVERGED

    @property
    def not_static(self) -> bool:
        """The motion check fired."""
        return self.status is Status.NOT_STATIC

    def to_measurement(self, timestamp_ns: int) -> Measurement:
        """The estimate as an ``ErrorPose``, ``Position3D`` (with covariance) or
        ``Rotation3D``; raises ``ValueError`` while there is none."""
        if self.covariance is None:
            raise ValueError(f"no estimate yet (status {self.status})")
        if self.kind == "pose":
            return ErrorPose(timestamp_ns, self.rotation, self.translation, self.covariance)
        if self.kind == "position":
            return Position3D(timestamp_ns, self.translation, self.covariance)
        return Rotation3D(timestamp_ns, self.rotation)


class _Sums:
    """Sums over samples at the current reference: ``n``, ``Lambda = sum W_i`` and
    ``eta = sum W_i xi_i`` (enough for a weighted mean and its information)."""

    __slots__ = ("information", "n", "weighted_sum")

    def __init__(self, dim: int) -> None:
        self.n = 0
        self.information = np.zeros((dim, dim))
        self.weighted_sum = np.zeros(dim)

    def add(self, xi: np.ndarray, weight: np.ndarray, sign: int = 1) -> None:
        """Add (``sign = 1``) or remove (``-1``) one sample."""
        self.n += sign
        self.information += sign * weight
        self.weighted_sum += sign * (weight @ xi)


class _Moments(_Sums):
    """:class:`_Sums` plus ``c = sum xi_i^T W_i xi_i``, ``s = sum xi_i`` and
    ``S = sum xi_i xi_i^T`` (noise scale, spread) and, on curved spaces, the tensor
    ``M = sum W_i (x) xi_i`` that carries ``eta`` to a new reference to second order."""

    __slots__ = ("chi2", "scatter", "tensor", "total")

    def __init__(self, dim: int, curved: bool) -> None:
        super().__init__(dim)
        self.chi2 = 0.0
        self.total = np.zeros(dim)
        self.scatter = np.zeros((dim, dim))
        self.tensor = np.zeros((dim, dim, dim)) if curved else None

    def add(self, xi: np.ndarray, weight: np.ndarray, sign: int = 1) -> None:
        super().add(xi, weight, sign)
        self.chi2 += sign * float(xi @ weight @ xi)
        self.total += sign * xi
        self.scatter += sign * np.outer(xi, xi)
        if self.tensor is not None:
            self.tensor += sign * np.multiply.outer(weight, xi)

    def bracket(self, adjoint: np.ndarray | None) -> np.ndarray:
        """``sum W_i ad(delta) xi_i / 2`` for ``adjoint = ad(delta)`` (0 on flat spaces)."""
        if adjoint is None:
            return np.zeros_like(self.weighted_sum)
        return 0.5 * np.einsum("abc,bc->a", self.tensor, adjoint)

    def shift(self, delta: np.ndarray, adjoint: np.ndarray | None) -> None:
        """Re-express at ``Exp(delta) T_ref``: each ``xi_i`` becomes
        ``xi_i - delta + ad(delta) xi_i / 2`` (second order) in ``eta`` and ``s``, and
        ``xi_i - delta`` in the rest, where the second-order term only adds zero-mean noise
        of relative size ``|delta| / sqrt(n)``."""
        bracket = self.bracket(adjoint)
        self.chi2 += float(delta @ self.information @ delta - 2.0 * delta @ self.weighted_sum)
        self.scatter += self.n * np.outer(delta, delta) - np.outer(self.total, delta)
        self.scatter -= np.outer(delta, self.total)
        moved_total = self.total - self.n * delta
        if adjoint is not None:
            moved_total += 0.5 * adjoint @ self.total
            self.tensor -= np.multiply.outer(self.information, delta)
        self.total = moved_total
        self.weighted_sum = self.weighted_sum - self.information @ delta + bracket


class _Entry(NamedTuple):
    """A sample in the motion window: whether it entered, ``W`` and ``xi`` at the current
    reference, and its place among the accepted samples (its batch), -1 if not accepted."""

    accepted: bool
    weight: np.ndarray
    xi: np.ndarray
    ordinal: int = -1


class _Batches:
    """Sums of ``W_i`` and ``W_i xi_i`` over batches of consecutive accepted samples, for the
    batch-means covariance (module docstring): dynamic batch means (Yeh & Schmeiser 2000), at
    most ``2 BATCHES`` batches of ``size`` samples each, adjacent pairs merged (``size``
    doubled) when the last one is full; O(1) memory. Sample ``ordinal`` (its place among the
    accepted samples) is in batch ``ordinal // size``. The Cholesky factors of the batches'
    information are kept for the batches that have not changed (all but the last, mostly)."""

    __slots__ = ("added", "counts", "factored", "information", "roots", "size", "weighted_sum")

    def __init__(self, dim: int) -> None:
        self.size = 1
        self.added = 0
        self.counts = np.zeros(2 * BATCHES, dtype=int)
        self.information = np.zeros((2 * BATCHES, dim, dim))
        self.weighted_sum = np.zeros((2 * BATCHES, dim))
        self.roots = np.zeros((2 * BATCHES, dim, dim))
        """``L_b`` (``Lambda_b = L_b L_b^T``) of the batches before ``factored``."""
        self.factored = 0

    @property
    def count(self) -> int:
        """Batches holding samples (the last one may be partly filled)."""
        return -(-self.added // self.size)

    def add(self, xi: np.ndarray, weight: np.ndarray) -> int:
        """Add the next accepted sample; returns its ordinal."""
        if self.added == 2 * BATCHES * self.size:
            for sums in (self.counts, self.information, self.weighted_sum):
                sums[:BATCHES] = sums[0::2] + sums[1::2]
                sums[BATCHES:] = 0
            self.size *= 2
            self.factored = 0
        ordinal = self.added
        batch = ordinal // self.size
        self.factored = min(self.factored, batch)
        self.counts[batch] += 1
        self.information[batch] += weight
        self.weighted_sum[batch] += weight @ xi
        self.added += 1
        return ordinal

    def remove(self, ordinal: int, xi: np.ndarray, weight: np.ndarray) -> None:
        """Take sample ``ordinal`` out of its batch (``xi`` at the current reference)."""
        batch = ordinal // self.size
        self.factored = min(self.factored, batch)
        self.counts[batch] -= 1
        self.information[batch] -= weight
        self.weighted_sum[batch] -= weight @ xi

    def shift(self, delta: np.ndarray) -> None:
        """Re-express at ``Exp(delta) T_ref`` to first order (``xi_i - delta``); the second
        order term changes a batch's score by a relative ``|delta| / 2``, a fraction of a
        standard deviation of the estimate, which a variance estimate does not notice."""
        count = self.count
        self.weighted_sum[:count] -= self.information[:count] @ delta

    def score_covariance(
        self, information_inverse: np.ndarray, weighted_sum: np.ndarray
    ) -> tuple[np.ndarray, int]:
        """``(V, nu)``: the covariance of the score ``sum W_i (xi_i - delta)``, whose
        covariance sandwiched in ``Lambda^-1`` is the estimate's, and its degrees of freedom.

        Each batch's score about the estimate, ``U_b = eta_b - Lambda_b Lambda^-1 eta``, is
        whitened by its own information, ``L_b^-1 U_b`` with ``Lambda_b = L_b L_b^T``
        (Cholesky), so that every batch counts alike however its samples are weighted (a few
        samples with very small stated covariances would otherwise leave a sandwich with few
        effective degrees of freedom). Their scatter, ``sum L_b^-1 U_b U_b^T L_b^-T``, has
        the expectation ``A^1/2 C A^1/2`` when the batches' scores have the covariances
        ``L_b A L_b^T``, with ``C = K I - sum L_b^T Lambda^-1 L_b`` (the scores are taken
        about the estimate, which the batches share; ``(K - 1) I`` for equal batches), so
        ``A = C^-1/2 (scatter) C^-1/2``: the inflation of the stated covariances, ``I`` when
        they are right and the samples independent. Then ``V = sum L_b A L_b^T`` and
        ``nu = tr(C) / d``."""
        count = self.count
        stale = np.arange(self.factored, count)
        stale = stale[self.counts[stale] > 0]
        self.roots[stale] = np.linalg.cholesky(self.information[stale])
        self.factored = count
        used = self.counts[:count] > 0
        information, roots = self.information[:count][used], self.roots[:count][used]
        scores = self.weighted_sum[:count][used] - information @ (
            information_inverse @ weighted_sum
        )
        whitened = np.linalg.solve(roots, scores[..., None])[..., 0]
        transposed = roots.transpose(0, 2, 1)
        shared = (transposed @ information_inverse @ roots).sum(axis=0)
        dim = len(weighted_sum)
        values, vectors = np.linalg.eigh(len(information) * np.eye(dim) - shared)
        values = np.maximum(values, 1.0)
        root = (vectors / np.sqrt(values)) @ vectors.T
        inflation = root @ (whitened.T @ whitened) @ root
        covariance = (roots @ inflation @ transposed).sum(axis=0)
        return covariance, max(round(float(values.sum()) / dim), 1)


class _BlockMeans:
    """The spread of the means of consecutive blocks of ``size`` accepted samples (half a
    motion window) that the noise alone causes, correlated or not: the batch-means control
    chart of Runger & Willemain ("Batch-means control charts for autocorrelated data", IIE
    Transactions 28(6), 1996), with the block means' variance from their successive
    differences (von Neumann, Kent, Bellinson & Hart, "The mean square successive difference",
    Annals of Mathematical Statistics 12(2), 1941). Each difference of the blocks'
    information-weighted means, ``z_j = m_j - m_(j-1)``, is whitened by its variance under the
    noise model, ``G_j G_j^T = S (Lambda_j^-1 + Lambda_(j-1)^-1)`` (``S`` the noise scale then);
    the scatter of the whitened differences about their mean, over ``d``, is the inflation of
    a block mean's variance over the model's. Taken about their mean, the differences do not
    see a steady drift, which moves every block by the same amount.

    Blocks shorter than the errors' correlation, and neighbouring blocks that share it, make
    that inflation fall short of the long-run one the window test needs; it is corrected for an
    AR(1) process (:func:`block_difference_correction`) whose lag-one autocorrelation comes from
    the whitened residuals within each block about the block's mean (a drift hardly moves
    them), with Kendall's correction for the mean's removal ("Note on bias in the estimation of
    autocorrelation", Biometrika 41, 1954: ``E r_1 = rho - (1 + 3 rho) / b``)."""

    __slots__ = (
        "_first",
        "_lag",
        "_last",
        "_size",
        "_square",
        "_sum",
        "block",
        "count",
        "lag",
        "previous",
        "spread",
        "square",
        "total",
    )

    def __init__(self, dim: int, size: int) -> None:
        self._size = size
        self.block = _Sums(dim)
        self.count = 0
        self.previous: tuple[np.ndarray, np.ndarray] | None = None
        self.total = np.zeros(dim)
        self.square = 0.0
        self.lag = 0.0
        """Sum over closed blocks of the lag-one products of residuals about the block mean."""
        self.spread = 0.0
        """Sum over closed blocks of the squared residuals about the block mean."""
        self._sum = np.zeros(dim)
        self._first: np.ndarray | None = None
        self._last: np.ndarray | None = None
        self._lag = 0.0
        self._square = 0.0

    def add(
        self, xi: np.ndarray, weight: np.ndarray, scale: np.ndarray, residual: np.ndarray
    ) -> None:
        """Add an accepted sample (``residual``: whitened, from the estimate before it); when
        the block is full, close it (``scale``: the noise scale now)."""
        block = self.block
        block.add(xi, weight)
        if self._last is None:
            self._first = residual
        else:
            self._lag += float(residual @ self._last)
        self._last = residual
        self._sum += residual
        self._square += float(residual @ residual)
        if block.n < self._size:
            return
        self._close_lag()
        spread = np.linalg.inv(block.information)
        mean = spread @ block.weighted_sum
        if self.previous is not None:
            previous_mean, previous_spread = self.previous
            root = np.linalg.cholesky(symmetric(scale @ (spread + previous_spread)))
            whitened = np.linalg.solve(root, mean - previous_mean)
            self.total += whitened
            self.square += float(whitened @ whitened)
            self.count += 1
        self.previous = mean, spread
        self.block = _Sums(len(xi))

    def _close_lag(self) -> None:
        """Add the closed block's lag-one products and squares about its mean."""
        size, total = self._size, self._sum
        mean = total / size
        self.lag += (
            self._lag
            - float(mean @ (2.0 * total - self._first - self._last))
            + (size - 1) * float(mean @ mean)
        )
        self.spread += self._square - size * float(mean @ mean)
        self._sum = np.zeros_like(total)
        self._first = self._last = None
        self._lag = self._square = 0.0

    def autocorrelation(self) -> float:
        """Lag-one autocorrelation of the residuals within blocks, bias-corrected (Kendall
        1954); 0 before a block has closed."""
        size = self._size
        if self.spread <= 0.0:
            return 0.0
        within = (self.lag / (size - 1)) / (self.spread / size)
        return (within + 1.0 / size) / (1.0 - 3.0 / size)

    def shift(self, delta: np.ndarray) -> None:
        """Re-express at ``Exp(delta) T_ref`` (to first order: differences do not change)."""
        self.block.weighted_sum -= self.block.information @ delta
        if self.previous is not None:
            self.previous = self.previous[0] - delta, self.previous[1]

    def inflation(self, dim: int) -> tuple[float, int]:
        """``(f, nu)``: the long-run inflation and its degrees of freedom, ``2/3 d`` per
        difference beyond the first (neighbouring differences share a block: von Neumann et al.
        1941); ``(1, 1)`` before there are two differences."""
        if self.count < 2:
            return 1.0, 1
        scatter = self.square - float(self.total @ self.total) / self.count
        correction = block_difference_correction(self.autocorrelation(), self._size)
        inflation = correction * scatter / (dim * (self.count - 1))
        return inflation, max(round(2 * dim * (self.count - 1) / 3), 1)


class _Noise(NamedTuple):
    """The noise model estimated from residuals (see :meth:`StaticEstimator._noise`)."""

    scale: np.ndarray
    reduced_chi2: float | None


class _Quantile:
    """The ``probability`` quantile of ``r^T C^-1 r`` for a d-dimensional normal ``r`` whose
    covariance ``C`` has a scale estimated with ``nu`` degrees of freedom: ``d F(d, nu)`` for a
    scalar scale, Hotelling's ``nu d / (nu - d + 1) F(d, nu - d + 1)`` for a whole covariance
    matrix (Anderson, "An Introduction to Multivariate Statistical Analysis", 3rd ed., 2003,
    section 5.2). Recomputed when ``nu`` leaves [cached, 1.25 cached]: the quantile falls as
    ``nu`` grows, so the value used is at most 25 % of ``nu`` stale and the larger (by at most
    4 % at ``nu`` = 100, 1 % at 300). ``matrix`` is fixed for an estimator by its first
    sample."""

    def __init__(self, dim: int, probability: float) -> None:
        self._dim, self._probability = dim, probability
        self._nu = 0
        self._value = math.inf

    def __call__(self, nu: int, matrix: bool) -> float:
        if not self._nu <= nu <= 1.25 * self._nu:
            dim = self._dim
            if matrix:
                denominator = max(nu - dim + 1, 1)
                value = nu * dim / denominator * stats.f.ppf(self._probability, dim, denominator)
            else:
                value = dim * stats.f.ppf(self._probability, dim, nu)
            self._nu, self._value = nu, float(value)
        return self._value


def batch_length_correction(rho: float, size: int) -> float:
    """How much longer-range correlation batches of ``size`` samples miss, for AR(1) samples
    with lag-one autocorrelation ``rho``: the long-run variance ``(1 + rho) / (1 - rho)``
    (Bayley & Hammersley, "The effective number of independent observations in an
    autocorrelated time series", J. Royal Statistical Society Suppl. 8(2), 1946) over the
    variance of a batch sum, ``(1 + rho) / (1 - rho) - 2 rho (1 - rho^b) / (b (1 - rho)^2)``
    per sample. 1 for ``rho <= 0`` (negatively correlated samples make batch means
    conservative) and for long batches; ``rho`` is capped at :data:`MAX_AUTOCORRELATION`."""
    rho = min(rho, MAX_AUTOCORRELATION)
    if rho <= 0.0:
        return 1.0
    long_run = (1.0 + rho) / (1.0 - rho)
    return long_run / (long_run - 2.0 * rho * (1.0 - rho**size) / (size * (1.0 - rho) ** 2))


def block_difference_correction(rho: float, size: int) -> float:
    """The long-run variance over what successive differences of means of ``size`` AR(1)
    samples (lag-one autocorrelation ``rho``) show: ``E (m_j - m_(j-1))^2 / 2`` is the block
    mean's variance less the covariance of neighbouring blocks, per sample ``(1 + rho) / (1 -
    rho) - rho (1 - rho^b) (3 - rho^b) / (b (1 - rho)^2)``. 1 for ``rho <= 0``; ``rho`` is
    capped at :data:`MAX_AUTOCORRELATION`."""
    rho = min(rho, MAX_AUTOCORRELATION)
    if rho <= 0.0:
        return 1.0
    long_run = (1.0 + rho) / (1.0 - rho)
    power = rho**size
    shown = long_run - rho * (1.0 - power) * (3.0 - power) / (size * (1.0 - rho) ** 2)
    return long_run / shown


def _trimmed_consistency(alpha: float, dim: int) -> float:
    """``E[chi2_d | chi2_d <= q_alpha] / d``: the mean of a chi-square kept below its
    ``alpha`` quantile, over d (Croux & Haesbroeck 1999; the MCD consistency factor)."""
    return float(stats.chi2.cdf(stats.chi2.ppf(alpha, dim), dim + 2) / alpha)


DEFAULT_INIT_SAMPLES = 20
"""The robust start's batch by default: the samples before the first estimate."""

DEFAULT_MOTION_WINDOW = 30
"""The motion check's window by default, samples (1 s at a camera's 30 Hz)."""


class StaticEstimator:
    """Estimate a static pose, position or rotation from a stream of noisy samples.

    ``kind``: ``"pose"``, ``"position"`` or ``"rotation"``. Feed samples with :meth:`add`; the
    rules (robust start, gate, noise scale, covariance, convergence, motion check) are in the
    module docstring. Parameters:

    * ``translation_tolerance`` (m, default 1 mm), ``rotation_tolerance`` (rad, default 0.1
      degree): the RMS errors of the averaging part at which the estimate counts as converged.
      0.1 degree at a 0.57 m lever arm moves a point by 1 mm, so the two balance at the working
      distance of camera and tracker set-ups; the figure-1 calibration's samples (PnP at 1.5-2.5
      m, a few centimetres and about a degree per frame) reach them in about 10 s, and tighter
      values would wait for errors that correlated effects (PnP bias, tracker calibration)
      dominate anyway.
    * ``min_samples`` (50): accepted samples before convergence; the batch-means covariance
      then rests on 49 degrees of freedom (batches of one sample until there are 128).
    * ``stability_window`` (20): accepted samples over which the estimate must have moved less
      than one standard deviation.
    * ``init_samples`` (20, at least ``2 d + 1``): the robust start's batch.
    * ``gate_probability`` (0.999): probability that a good sample passes the gate.
    * ``motion_window`` (30) and ``motion_false_alarm`` (1e-6 per sample): the motion check;
      the window should span about a second (the averaging service sets it from the rate).
    * ``common_covariance``: covariance (d x d, positive semi-definite) of an error all samples
      share; added to the published covariance, also settable later.
    """

    def __init__(
        self,
        kind: str = "pose",
        *,
        translation_tolerance: float = 1e-3,
        rotation_tolerance: float = math.radians(0.1),
        min_samples: int = 50,
        stability_window: int = 20,
        init_samples: int = DEFAULT_INIT_SAMPLES,
        gate_probability: float = 0.999,
        motion_window: int = DEFAULT_MOTION_WINDOW,
        motion_false_alarm: float = 1e-6,
        common_covariance: Any = None,
    ) -> None:
        if kind not in SPACES:
            raise ValueError(f"kind: must be one of {sorted(SPACES)}, got {kind!r}")
        self._space = SPACES[kind]
        dim = self._space.dim
        self._translation_tolerance = positive("translation_tolerance", translation_tolerance)
        self._rotation_tolerance = positive("rotation_tolerance", rotation_tolerance)
        self._min_samples = _count("min_samples", min_samples, 1)
        self._init_samples = _count("init_samples", init_samples, 2 * dim + 1)
        window = _count("stability_window", stability_window, 1)
        self._motion_window = _count("motion_window", motion_window, 10)
        false_alarm = _probability("motion_false_alarm", motion_false_alarm)
        self._motion_threshold = _Quantile(dim, 1.0 - false_alarm)
        gate_probability = _probability("gate_probability", gate_probability)
        self._gate = _Quantile(dim, gate_probability)
        self._truncation = _trimmed_consistency(gate_probability, dim)
        self.common_covariance = common_covariance

        self._weighted: bool | None = None
        self._pending: list[tuple[Vector, np.ndarray, np.ndarray]] = []
        self._reference: Vector = ()
        self._value: Vector = ()
        self._moments = _Moments(dim, curved=self._space.adjoint(np.zeros(dim)) is not None)
        self._delta = np.zeros(dim)
        self._noise_model = _Noise(np.eye(dim), None)
        self._batches = _Batches(dim)
        self._lag_sums = np.zeros(2)
        self._last_whitened: np.ndarray | None = None
        self._blocks = _BlockMeans(dim, self._motion_window // 2)
        self._averaging_raw = np.eye(dim)
        self._std: tuple[float | None, float | None] = (None, None)
        self._averaging = np.zeros((dim, dim))
        self._window: deque[_Entry] = deque(maxlen=self._motion_window)
        self._window_sums = _Sums(dim)
        self._history: deque[Vector] = deque(maxlen=window + 1)
        self._status = Status.INITIALISING
        self._rejected = 0
        self._last_accepted: bool | None = None
        self._motion: Motion | None = None

    # ----------------------------------------------------------------------------------- API

    @property
    def state(self) -> StaticState:
        """The state after the last sample."""
        return self._make_state()

    @property
    def common_covariance(self) -> np.ndarray | None:
        """Covariance of the error shared by all samples (``None``: none)."""
        return self._common

    @common_covariance.setter
    def common_covariance(self, value: Any) -> None:
        dim = self._space.dim
        if value is None:
            self._common = None
        else:
            cov = as_array("common_covariance", value, (dim, dim))
            if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-15):
                raise ValueError("common_covariance: must be symmetric")
            if np.linalg.eigvalsh(cov)[0] < -1e-9 * np.abs(cov).max():
                raise ValueError("common_covariance: must be positive semi-definite")
            self._common = symmetric(cov)

    def add(
        self, rotation: Any = None, translation: Any = None, covariance: Any = None
    ) -> StaticState:
        """Feed one sample and return the new :class:`StaticState`.

        ``rotation``: unit quaternion (x, y, z, w) (kinds pose, rotation); ``translation``: the
        pose's translation or the position (m) (kinds pose, position); ``covariance``: d x d
        positive definite (6x6 left perturbation for poses, 3x3 over ``phi`` for rotations,
        3x3 for positions) or ``None``. Either every sample has a covariance or none has.
        Raises ``ValueError`` naming the argument on bad input.
        """
        value = self._sample_value(rotation, translation)
        sigma, weight = self._sample_weight(covariance)
        if self._status is Status.INITIALISING:
            self._pending.append((value, sigma, weight))
            if len(self._pending) == self._init_samples:
                self._initialise()
        elif self._status is Status.NOT_STATIC:
            self._watch(value)
        else:
            self._update(value, sigma, weight)
        return self._make_state()

    # ----------------------------------------------------------------------- input checking

    def _sample_value(self, rotation: Any, translation: Any) -> Vector:
        kind = self._space.name
        parts: list[float] = []
        if kind in ("pose", "rotation"):
            q = as_array("rotation", rotation, (4,))
            norm = float(np.linalg.norm(q))
            if abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE:
                raise ValueError(f"rotation: not a unit quaternion (norm {norm})")
            parts.extend(q.tolist())
        elif rotation is not None:
            raise ValueError(f"rotation: a {kind} sample has no rotation")
        if kind in ("pose", "position"):
            parts.extend(as_array("translation", translation, (3,)).tolist())
        elif translation is not None:
            raise ValueError(f"translation: a {kind} sample has no translation")
        return tuple(parts)

    def _sample_weight(self, covariance: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(Sigma_i, W_i)``; ``(I, I)`` for samples without covariance."""
        weighted = covariance is not None
        if self._weighted is None:
            self._weighted = weighted
        elif weighted != self._weighted:
            have = "have" if self._weighted else "have no"
            raise ValueError(f"covariance: this estimator's samples {have} covariances")
        dim = self._space.dim
        if not weighted:
            return np.eye(dim), np.eye(dim)
        sigma = as_array("covariance", covariance, (dim, dim))
        if np.abs(sigma - sigma.T).max() > 1e-9 * np.abs(sigma).max():
            raise ValueError("covariance: must be symmetric")
        try:
            np.linalg.cholesky(sigma)
        except np.linalg.LinAlgError:
            raise ValueError("covariance: not positive definite") from None
        return sigma, np.linalg.inv(sigma)

    # -------------------------------------------------------------------------- robust start

    def _initialise(self) -> None:
        """Concentration steps on the first K samples, then the gate on all of them."""
        space, dim = self._space, self._space.dim
        values = np.array([value for value, _, _ in self._pending])
        sigmas = np.array([sigma for _, sigma, _ in self._pending])
        weights = np.array([weight for _, _, weight in self._pending])
        count = len(values)
        keep = (count + dim + 1) // 2
        consistency = _trimmed_consistency(keep / count, dim)

        start = space.logs(values, tuple(values[0].tolist()))
        median = np.median(start, axis=0)
        spread = _MAD_TO_SIGMA * np.median(np.abs(start - median), axis=0) + NOISE_FLOOR
        subset = np.argsort((((start - median) / spread) ** 2).sum(axis=1))[:keep]
        center: Vector = tuple(values[subset[0]].tolist())
        for _ in range(MAX_ITERATIONS):
            center = self._mean(values[subset], weights[subset], center)
            xi = space.logs(values, center)
            kept, weights_kept = xi[subset], weights[subset]
            chi2 = float(np.einsum("ki,kij,kj->", kept, weights_kept, kept))
            centred = kept - kept.mean(axis=0)
            scale = self._noise(chi2, centred.T @ centred, keep, consistency).scale
            distances = _mahalanobis(xi, scale @ sigmas)
            new_subset = np.argsort(distances)[:keep]
            if set(new_subset.tolist()) == set(subset.tolist()):
                break
            subset = new_subset

        spread_of_mean = scale @ np.linalg.inv(weights[subset].sum(axis=0))
        gate = self._gate(self._dof(keep), not self._weighted)
        accepted = _mahalanobis(xi, scale @ sigmas + spread_of_mean) <= gate
        self._reference = self._mean(values[accepted], weights[accepted], center)
        xi = space.logs(values, self._reference)
        self._status = Status.AVERAGING
        self._noise_model = self._noise(chi2, centred.T @ centred, keep, consistency)
        for k, ok in enumerate(accepted.tolist()):
            ordinal = -1
            if ok:
                ordinal = self._accept(xi[k], weights[k], xi[k])
            else:
                self._rejected += 1
            self._push(_Entry(ok, weights[k], xi[k], ordinal))
        self._pending = []
        self._last_accepted = bool(accepted[-1])
        self._refresh()
        self._history.append(self._value)
        self._check_motion()

    def _mean(self, values: np.ndarray, weights: np.ndarray, start: Vector) -> Vector:
        """Weighted mean on the manifold by Gauss-Newton from ``start`` (Barfoot 2017)."""
        information = weights.sum(axis=0)
        reference = start
        for _ in range(MAX_ITERATIONS):
            xi = self._space.logs(values, reference)
            step = np.linalg.solve(information, np.einsum("kij,kj->i", weights, xi))
            reference = self._space.exp(step.tolist(), reference)
            if np.abs(step).max() < CONVERGED_STEP:
                break
        return reference

    def _dof(self, count: int) -> int:
        """Degrees of freedom of the noise scale from ``count`` residuals about their mean."""
        return self._space.dim * (count - 1) if self._weighted else count - 1

    def _noise(self, chi2: float, scatter: np.ndarray, count: int, consistency: float) -> _Noise:
        """The noise model from ``count`` residuals about their mean.

        ``scale`` multiplies the samples' covariances (``I`` without) in the gate and the
        motion check: with covariances ``max(1, k^2) I``, ``k^2 = chi2 / nu / consistency``
        the reduced chi-square; without, the noise covariance ``scatter / nu / consistency``.
        """
        dim, nu = self._space.dim, self._dof(count)
        if self._weighted:
            k2 = chi2 / nu / consistency
            return _Noise(max(1.0, k2) * np.eye(dim), k2)
        return _Noise(scatter / nu / consistency + NOISE_FLOOR**2 * np.eye(dim), None)

    # ------------------------------------------------------------------------------ averaging

    def _update(self, value: Vector, sigma: np.ndarray, weight: np.ndarray) -> None:
        xi = np.array(self._space.log(value, self._reference))
        residual = xi - self._delta
        innovation = self._noise_model.scale @ sigma + self._averaging
        distance2 = float(residual @ np.linalg.solve(innovation, residual))
        accepted = distance2 <= self._gate(self._dof(self._moments.n), not self._weighted)
        self._last_accepted = accepted
        ordinal = -1
        if accepted:
            ordinal = self._accept(xi, weight, residual)
        else:
            self._rejected += 1
        self._push(_Entry(accepted, weight, xi, ordinal))
        if accepted:
            self._refresh()
            self._history.append(self._value)
        self._check_motion()
        if accepted and self._status is Status.AVERAGING and self._is_converged():
            self._status = Status.CONVERGED

    def _accept(self, xi: np.ndarray, weight: np.ndarray, residual: np.ndarray) -> int:
        """Enter an accepted sample (``xi`` at the reference, ``residual`` from the estimate
        before it) into the sums, its batch, its block and the lag-one autocorrelation of the
        whitened residuals ``L_i^T r_i`` (``W_i = L_i L_i^T``); returns its ordinal."""
        self._moments.add(xi, weight)
        whitened = np.linalg.cholesky(weight).T @ residual
        self._blocks.add(xi, weight, self._noise_model.scale, whitened)
        if self._last_whitened is not None:
            self._lag_sums += (float(whitened @ self._last_whitened), float(whitened @ whitened))
        self._last_whitened = whitened
        return self._batches.add(xi, weight)

    def _refresh(self) -> None:
        """Estimate, noise scale and averaging covariance from the sums; re-linearise."""
        moments, space = self._moments, self._space
        self._information_inverse = information_inverse = np.linalg.inv(moments.information)
        # The second-order expansion sum W_i (xi_i - delta + ad(delta) xi_i / 2) = 0, solved by
        # one fixed-point step from the first-order delta.
        first_order = information_inverse @ moments.weighted_sum
        bracket = moments.bracket(space.adjoint(first_order.tolist()))
        self._delta = information_inverse @ (moments.weighted_sum + bracket)
        if moments.n > 1:
            chi2 = moments.chi2 - float(moments.weighted_sum @ self._delta)
            scatter = moments.scatter - np.outer(moments.total, moments.total) / moments.n
            self._noise_model = self._noise(chi2, scatter, moments.n, self._truncation)
        dim = space.dim
        score_covariance, nu = self._batches.score_covariance(
            information_inverse, moments.weighted_sum
        )
        cross, square = self._lag_sums
        correction = batch_length_correction(
            cross / square if square > 0.0 else 0.0, self._batches.size
        )
        raw = correction * information_inverse @ score_covariance @ information_inverse
        self._averaging_raw = symmetric(raw) + NOISE_FLOOR**2 * np.eye(dim)
        self._averaging = self._averaging_raw * (nu / max(nu - dim - 1, 1))
        distance2 = float(self._delta @ np.linalg.solve(self._averaging, self._delta))
        if distance2 > RELINEARISE**2:
            delta = self._delta.tolist()
            adjoint = space.adjoint(delta)
            self._reference = space.exp(delta, self._reference)
            moments.shift(self._delta, adjoint)
            self._batches.shift(self._delta)
            self._blocks.shift(self._delta)
            self._shift_window(self._delta, adjoint)
            self._delta = np.zeros(space.dim)
        self._value = space.exp(self._delta.tolist(), self._reference)
        self._std = self._standard_deviations(self._averaging)

    def _push(self, entry: _Entry) -> None:
        """Append a sample to the motion window, dropping the oldest."""
        if len(self._window) == self._motion_window:
            oldest = self._window[0]
            if oldest.accepted:
                self._window_sums.add(oldest.xi, oldest.weight, -1)
        self._window.append(entry)
        if entry.accepted:
            self._window_sums.add(entry.xi, entry.weight)

    def _shift_window(self, delta: np.ndarray, adjoint: np.ndarray | None) -> None:
        """The window's ``xi`` at ``Exp(delta) T_ref`` to second order, as the sums'."""
        entries = list(self._window)
        xi = np.array([entry.xi for entry in entries]) - delta
        if adjoint is not None:
            xi += 0.5 * (xi + delta) @ adjoint.T
        self._window.clear()
        self._window_sums = _Sums(self._space.dim)
        for entry, moved in zip(entries, xi, strict=True):
            self._push(entry._replace(xi=moved))

    # ---------------------------------------------------------------------------- the rules

    def _standard_deviations(self, covariance: np.ndarray) -> tuple[float | None, float | None]:
        """RMS translation and rotation errors (``sqrt(trace)``) of a d x d covariance."""
        space = self._space
        jacobian = space.translation_jacobian(self._value)
        translation = None
        if jacobian is not None:
            variance = float(np.einsum("ij,jk,ik->", jacobian, covariance, jacobian))
            translation = math.sqrt(max(0.0, variance))
        rotation = None
        if space.rotation_part is not None:
            block = covariance[space.rotation_part, space.rotation_part]
            rotation = math.sqrt(max(0.0, float(np.trace(block))))
        return translation, rotation

    def _displacement(self, moved: Vector, base: Vector) -> tuple[float | None, float | None]:
        """Translation distance (m) and rotation angle (rad) from ``base`` to ``moved``."""
        space = self._space
        translation = rotation = None
        if space.name != "rotation":
            translation = math.dist(moved[-3:], base[-3:])
        if space.rotation_part is not None:
            rotation = math.hypot(*space.log(moved, base)[space.rotation_part])
        return translation, rotation

    def _is_converged(self) -> bool:
        if self._moments.n < self._min_samples or len(self._history) < self._history.maxlen:
            return False
        std_t, std_r = self._std
        moved_t, moved_r = self._displacement(self._value, self._history[0])
        if std_t is not None and (std_t > self._translation_tolerance or moved_t >= std_t):
            return False
        return std_r is None or (std_r <= self._rotation_tolerance and moved_r < std_r)

    def _check_motion(self) -> None:
        window = self._window
        rejected = sum(not entry.accepted for entry in window)
        if len(window) == self._motion_window and 2 * rejected > len(window):
            self._stop("rejections", rejected / len(window))
            return
        inside, moments = self._window_sums, self._moments
        if inside.n < self._motion_window // 2 or moments.n - inside.n < self._motion_window:
            return
        before = moments.information - inside.information
        delta_inside = np.linalg.solve(inside.information, inside.weighted_sum)
        delta_before = np.linalg.solve(before, moments.weighted_sum - inside.weighted_sum)
        difference = delta_inside - delta_before
        # (S (A^-1 + B^-1))^-1 = A (A + B)^-1 B S^-1, S commuting with the informations (it is
        # a multiple of I with covariances, and they are multiples of I without).
        precision = inside.information @ self._information_inverse @ before
        scaled = np.linalg.solve(self._noise_model.scale, difference)
        inflation, nu = self._blocks.inflation(self._space.dim)
        statistic = float(difference @ precision @ scaled) / max(inflation, 1e-12)
        if statistic > self._motion_threshold(nu, False):
            self._stop("window_mean", statistic)

    def _stop(self, rule: str, statistic: float) -> None:
        """Not static. The motion may have begun anywhere in the window, so its samples leave
        the sums (which are linear in them: exactly) and the rest is kept as the last static
        estimate, if at least two samples remain."""
        inside = self._window_sums
        if self._moments.n - inside.n >= 2:
            for entry in self._window:
                if entry.accepted:
                    self._moments.add(entry.xi, entry.weight, -1)
                    self._batches.remove(entry.ordinal, entry.xi, entry.weight)
            self._rejected += inside.n
            self._window_sums = _Sums(self._space.dim)
            entries = [entry._replace(accepted=False) for entry in self._window]
            self._window = deque(entries, maxlen=self._motion_window)
            self._refresh()
        self._status = Status.NOT_STATIC
        self._last_accepted = None
        self._motion = Motion(rule, *self._moving_offset(), statistic)

    def _inflation(self) -> float:
        """The batch means' variance over the noise model's, ``tr(Lambda S^-1 P_raw) / d``
        (``S`` the noise scale): 1 for independent samples that fit the model."""
        model_inverse = self._moments.information @ np.linalg.inv(self._noise_model.scale)
        return float(np.trace(model_inverse @ self._averaging_raw)) / self._space.dim

    def _moving_offset(self) -> tuple[float | None, float | None]:
        """Displacement from the estimate of the median ``xi`` of the latest M/2 samples."""
        latest = list(self._window)[-(self._motion_window // 2) :]
        offset = np.median([entry.xi for entry in latest], axis=0)
        return self._displacement(self._space.exp(offset.tolist(), self._reference), self._value)

    def _watch(self, value: Vector) -> None:
        """Not static: keep measuring how far the recent samples are, average nothing."""
        xi = np.array(self._space.log(value, self._reference))
        self._push(_Entry(False, np.eye(self._space.dim), xi))
        translation, rotation = self._moving_offset()
        self._motion = self._motion._replace(translation=translation, rotation=rotation)

    # ---------------------------------------------------------------------------------- state

    def _make_state(self) -> StaticState:
        kind = self._space.name
        empty = StaticState(
            kind, self._status, None, None, None, 0, self._rejected, None, None, None, None,
            None, None, None, None,
        )  # fmt: skip
        if not self._value:
            return empty
        moments, value = self._moments, self._value
        covariance = self._averaging if self._common is None else self._averaging + self._common
        std_t, std_r = self._std
        spread = moments.scatter - np.outer(moments.total, self._delta)
        spread += moments.n * np.outer(self._delta, self._delta) - np.outer(
            self._delta, moments.total
        )
        spread_t, spread_r = self._standard_deviations(spread / moments.n)
        return empty._replace(
            rotation=np.array(value[:4]) if kind != "position" else None,
            translation=np.array(value[-3:]) if kind != "rotation" else None,
            covariance=covariance.copy(),
            accepted=moments.n,
            last_accepted=self._last_accepted,
            noise_scale=self._noise_model.reduced_chi2,
            effective_samples=moments.n / self._inflation(),
            std_translation=std_t,
            std_rotation=std_r,
            spread_translation=spread_t,
            spread_rotation=spread_r,
            motion=self._motion,
        )


def _mahalanobis(xi: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """``xi_k^T C_k^-1 xi_k`` for rows ``xi`` (K x d) and covariances (K x d x d)."""
    return np.einsum("ki,ki->k", xi, np.linalg.solve(covariances, xi[..., None])[..., 0])


def _count(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{name}: must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _probability(name: str, value: Any) -> float:
    number = float(value)
    if not 0.0 < number < 1.0:
        raise ValueError(f"{name}: must be a probability in (0, 1), got {value!r}")
    return number
