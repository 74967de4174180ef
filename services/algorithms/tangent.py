"""The three sample spaces of a static relation (poses, positions, rotations) and their maps.

A value is a flat tuple of floats (pose: quaternion (x, y, z, w) then translation, 7;
position: 3; rotation: quaternion, 4). Each space maps values to and from the tangent space at
a reference value with the left perturbation of the project's covariances
(``docs/architecture.md``):

* pose, SE(3):     ``T = Exp(xi) T_ref``, ``xi = (phi, rho)``, rotation first (6 dof);
* rotation, SO(3): ``R = Exp(phi) R_ref`` (3 dof);
* position, R^3:   ``p = p_ref + x`` (3 dof).

``log(value, reference)`` is ``xi`` with ``value = Exp(xi) reference``; ``exp(xi, reference)``
is ``Exp(xi) reference``; ``logs`` maps a batch (N x size array) to an N x dim array.

Why by hand, on plain floats: the static estimator maps one sample at a time. A single-pose
``RigidTransform`` costs 140 us to build and 150-200 us per ``as_exp_coords`` /
``from_exp_coords`` here (scipy 1.17.1); numpy closed forms on one pose still cost about
50 us (a microsecond per array operation); these float closed forms cost about 4 us. Batches
are small (tens of summaries) and loop. The tests check every map against scipy's
``as_exp_coords`` / ``from_exp_coords`` / ``as_rotvec``. Closed forms: quaternion product and
rotation on floats, :func:`ubitrack_agent.core.quaternions.multiply_floats` and
``rotate_floats`` (Sola, "Quaternion kinematics for the error-state Kalman filter",
arXiv:1711.02508); left Jacobian ``J_l`` of SO(3), ``rho = J_l(phi)^-1 t`` and the adjoint:
Barfoot, "State Estimation for Robotics", 2017, chapter 7.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from ubitrack_agent.core.quaternions import multiply_floats, rotate_floats

Vector = tuple[float, ...]


def _jacobian_times(phi: Sequence[float], v: Sequence[float], a: float, b: float) -> Vector:
    """``(I + a [phi]x + b [phi]x^2) v`` with ``[phi]x^2 v = phi (phi . v) - |phi|^2 v``."""
    px, py, pz = phi
    vx, vy, vz = v
    cx, cy, cz = py * vz - pz * vy, pz * vx - px * vz, px * vy - py * vx
    dot = px * vx + py * vy + pz * vz
    theta2 = px * px + py * py + pz * pz
    return (
        vx + a * cx + b * (px * dot - theta2 * vx),
        vy + a * cy + b * (py * dot - theta2 * vy),
        vz + a * cz + b * (pz * dot - theta2 * vz),
    )


def _rotation_log(q: Sequence[float]) -> tuple[Vector, float]:
    """``(phi, c)``: the rotation vector of ``q`` (``q`` and ``-q`` agree) and the ``[phi]x^2``
    coefficient of ``J_l(phi)^-1``, ``(1 - (theta/2) cot(theta/2)) / theta^2``.

    ``theta = 2 atan2(|v|, |w|)`` is exact to rounding for tiny ``|v|``, so ``theta / |v|``
    needs no series. The coefficient cancels near 0, but it multiplies ``[phi]x^2 x`` of size
    ``theta^2 |x|``, so the product's error stays at the rounding of ``x``; 1/12 at 0.
    """
    x, y, z, w = q
    s = math.sqrt(x * x + y * y + z * z)
    if s == 0.0:
        return (0.0, 0.0, 0.0), 1.0 / 12.0
    c = abs(w)
    theta = 2.0 * math.atan2(s, c)
    ratio = math.copysign(theta / s, w)
    return (x * ratio, y * ratio, z * ratio), (1.0 - 0.5 * theta * c / s) / (theta * theta)


def _rotation_exp(phi: Sequence[float]) -> tuple[Vector, float, float]:
    """``(q, a, b)``: the quaternion of ``phi`` and the ``J_l(phi)`` coefficients
    ``a = (1 - cos theta) / theta^2``, ``b = (theta - sin theta) / theta^3``."""
    theta2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    if theta2 == 0.0:
        return (0.0, 0.0, 0.0, 1.0), 0.5, 1.0 / 6.0
    theta = math.sqrt(theta2)
    half_sin = math.sin(0.5 * theta)
    factor = half_sin / theta
    q = (phi[0] * factor, phi[1] * factor, phi[2] * factor, math.cos(0.5 * theta))
    return q, 2.0 * half_sin * half_sin / theta2, (theta - math.sin(theta)) / (theta2 * theta)


def _conjugate(q: Sequence[float]) -> Vector:
    return (-q[0], -q[1], -q[2], q[3])


def _skew(v: Sequence[float]) -> np.ndarray:
    """``[v]x`` with ``[v]x w = v x w``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


class Space:
    """A sample space: the flat value layout, the tangent dimension and the two maps."""

    name: ClassVar[str]
    size: ClassVar[int]
    """Length of a flat value."""
    dim: ClassVar[int]
    """Tangent dimension (degrees of freedom)."""
    rotation_part: ClassVar[slice | None]
    """Where the rotation vector ``phi`` sits in ``xi`` (``None``: no rotation)."""

    def log(self, value: Sequence[float], reference: Sequence[float]) -> Vector:
        """``xi`` (dim) with ``value = Exp(xi) reference``."""
        raise NotImplementedError

    def exp(self, xi: Sequence[float], reference: Sequence[float]) -> Vector:
        """``Exp(xi) reference`` (size)."""
        raise NotImplementedError

    def translation_jacobian(self, reference: Sequence[float]) -> np.ndarray | None:
        """``d t / d xi`` (3 x dim) at ``reference``: the first-order change of the translation
        (pose) or position under ``xi``; ``None`` for rotations."""
        raise NotImplementedError

    def adjoint(self, xi: Sequence[float]) -> np.ndarray | None:
        """``ad(xi)`` (dim x dim), the Lie bracket ``[xi, y] = ad(xi) y``, so that
        ``Log(Exp(y) Exp(-xi)) = y - xi + ad(xi) y / 2 + O(|xi| |y| (|xi| + |y|))`` (the
        Baker-Campbell-Hausdorff series; Barfoot 2017, chapter 7); ``None`` where the space
        is flat (positions)."""
        raise NotImplementedError

    def logs(self, values: np.ndarray, reference: Sequence[float]) -> np.ndarray:
        """``log`` of each row of ``values`` (N x size): N x dim."""
        rows = [self.log(value, reference) for value in np.asarray(values).tolist()]
        return np.array(rows, dtype=float).reshape(len(rows), self.dim)


class PoseSpace(Space):
    """SE(3): ``(q, t)``, ``T = Exp(xi) T_ref``, ``xi = (phi, rho)``."""

    name = "pose"
    size = 7
    dim = 6
    rotation_part = slice(0, 3)

    def log(self, value: Sequence[float], reference: Sequence[float]) -> Vector:
        # T T_ref^-1 = (q q_ref^*, t - R(q q_ref^*) t_ref); rho = J_l(phi)^-1 t_rel.
        q_rel = multiply_floats(value[:4], _conjugate(reference[:4]))
        moved = rotate_floats(q_rel, reference[4:])
        t_rel = (value[4] - moved[0], value[5] - moved[1], value[6] - moved[2])
        phi, coefficient = _rotation_log(q_rel)
        return phi + _jacobian_times(phi, t_rel, -0.5, coefficient)

    def exp(self, xi: Sequence[float], reference: Sequence[float]) -> Vector:
        # Exp(xi) = (Exp(phi), J_l(phi) rho); Exp(xi) T_ref = (q q_ref, R(q) t_ref + J_l rho).
        phi = xi[:3]
        q, a, b = _rotation_exp(phi)
        moved = rotate_floats(q, reference[4:])
        shift = _jacobian_times(phi, xi[3:], a, b)
        return multiply_floats(q, reference[:4]) + tuple(
            m + s for m, s in zip(moved, shift, strict=True)
        )

    def translation_jacobian(self, reference: Sequence[float]) -> np.ndarray:
        # t' = Exp(phi) t + J_l(phi) rho = t + phi x t + rho + O(|xi|^2): [-[t]x, I].
        tx, ty, tz = reference[4:]
        return np.array(
            [
                [0.0, tz, -ty, 1.0, 0.0, 0.0],
                [-tz, 0.0, tx, 0.0, 1.0, 0.0],
                [ty, -tx, 0.0, 0.0, 0.0, 1.0],
            ]
        )

    def adjoint(self, xi: Sequence[float]) -> np.ndarray:
        # [[phi]x, 0], [[rho]x, [phi]x]] for xi = (phi, rho).
        result = np.zeros((6, 6))
        result[:3, :3] = result[3:, 3:] = _skew(xi[:3])
        result[3:, :3] = _skew(xi[3:])
        return result


class PositionSpace(Space):
    """R^3: ``p = p_ref + x``."""

    name = "position"
    size = 3
    dim = 3
    rotation_part = None

    def log(self, value: Sequence[float], reference: Sequence[float]) -> Vector:
        return (value[0] - reference[0], value[1] - reference[1], value[2] - reference[2])

    def exp(self, xi: Sequence[float], reference: Sequence[float]) -> Vector:
        return (reference[0] + xi[0], reference[1] + xi[1], reference[2] + xi[2])

    def translation_jacobian(self, reference: Sequence[float]) -> np.ndarray:
        return np.eye(3)

    def adjoint(self, xi: Sequence[float]) -> None:
        return None


class RotationSpace(Space):
    """SO(3): ``q``, ``R = Exp(phi) R_ref``."""

    name = "rotation"
    size = 4
    dim = 3
    rotation_part = slice(0, 3)

    def log(self, value: Sequence[float], reference: Sequence[float]) -> Vector:
        return _rotation_log(multiply_floats(value, _conjugate(reference)))[0]

    def exp(self, xi: Sequence[float], reference: Sequence[float]) -> Vector:
        return multiply_floats(_rotation_exp(xi)[0], reference)

    def translation_jacobian(self, reference: Sequence[float]) -> None:
        return None

    def adjoint(self, xi: Sequence[float]) -> np.ndarray:
        return _skew(xi)


SPACES: dict[str, Space] = {
    space.name: space for space in (PoseSpace(), PositionSpace(), RotationSpace())
}
"""The spaces by kind: ``"pose"`` (6D), ``"position"`` (3D), ``"rotation"`` (3R)."""
