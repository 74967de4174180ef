"""Correspondence-based estimation patterns (sections 3.3-3.4): 3D-3D and 2D-3D pose
estimation, projective calibration, triangulation and hand-eye calibration.

Each takes aligned correspondence lists (space expansion: one binding per copy; time
expansion: samples accumulated by :mod:`ubitrack_agent.services.expansion`) and uses only the rows
where every correspondence edge has a value.
"""

from __future__ import annotations

import numpy as np

from ubitrack_agent.core import (
    ErrorPose,
    Measurement,
    Pose,
    Position2D,
    Position3D,
    Projection,
    se3,
)
from ubitrack_agent.core.errors import TooFewCorrespondences
from ubitrack_agent.core.uncertainty import compose_covariance
from ubitrack_agent.services.algorithms import (
    absolute_orientation,
    decompose_projection,
    hand_eye_calibration,
    projection_dlt,
    solve_pnp,
    solve_pnp_ransac,
    triangulate_points,
)
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.services.registry import (
    Inputs,
    Port,
    Service,
    complete_correspondences,
    register,
)

POSES = (Pose, ErrorPose)


def _rows(values: Inputs, ports: tuple[str, ...], minimum: int) -> list[tuple]:
    rows = complete_correspondences(values, ports)
    if len(rows) < minimum:
        raise TooFewCorrespondences(f"{len(rows)} complete correspondences, need {minimum}")
    return rows


def _points(values: list[Measurement]) -> np.ndarray:
    return np.array([v.position for v in values])


@register
class PoseEstimation3D3D(Service):
    """Pose of B in A from points F known in both frames (absolute orientation)."""

    NAME = "pose_estimation_3d3d"
    INPUTS = {"AF": Port((Position3D,)), "BF": Port((Position3D,))}
    OUTPUTS = ("AB",)
    CORRESPONDENCE = ("AF", "BF")
    MIN_CORRESPONDENCES = 3
    TIME_MIN_MOTION = 0.005

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        rows = _rows(values, self.CORRESPONDENCE, self.MIN_CORRESPONDENCES)
        a, b = zip(*rows, strict=True)
        estimate = absolute_orientation(_points(list(a)), _points(list(b)))
        return {"AB": estimate.to_measurement(timestamp_ns)}


@register
class PoseEstimation2D3D(Service):
    """Pose of object O in camera frame C from features F seen in image I (OpenCV PnP).

    ``CI`` is the camera's projection (3x4) from C to the image. The PnP solution is the pose of
    O in the optical frame; the result is re-expressed in C. Parameters: ``method`` (``auto``
    chooses by geometry; or an OpenCV method name), ``ransac`` for outlier-robust estimation,
    ``pixel_sigma`` for the covariance (if 0: the image points' own covariances when each
    carries one, as a camera announces them, else estimated from the residuals, which from a few
    points is often far too small: :mod:`ubitrack_agent.services.algorithms.pnp`).
    """

    NAME = "pose_estimation_2d3d"
    INPUTS = {"CI": Port((Projection,)), "IF": Port((Position2D,)), "OF": Port((Position3D,))}
    OUTPUTS = ("CO",)
    CORRESPONDENCE = ("IF", "OF")
    MIN_CORRESPONDENCES = 4
    TIME_MIN_MOTION = 2.0  # pixels
    PARAMETERS = {"method": "auto", "ransac": False, "pixel_sigma": 0.0}

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        rows = _rows(values, self.CORRESPONDENCE, self.MIN_CORRESPONDENCES)
        image, model = zip(*rows, strict=True)
        k, camera = decompose_projection(values["CI"].matrix)  # camera: C in the optical frame
        sigma = float(self.parameters["pixel_sigma"]) or None
        announced = None
        if sigma is None and all(p.covariance is not None for p in image):
            announced = np.array([p.covariance for p in image])
        noise = {"pixel_sigma": sigma, "pixel_covariances": announced}
        if self.parameters["ransac"]:
            pnp, _ = solve_pnp_ransac(_points(list(model)), _points(list(image)), k, **noise)
        else:
            pnp = solve_pnp(
                _points(list(model)),
                _points(list(image)),
                k,
                method=self.parameters["method"],
                **noise,
            )
        optical_to_c = se3.invert(camera.rotation, camera.translation)
        q, t = se3.compose(*optical_to_c, pnp.rotation, pnp.translation)
        covariance = None
        if pnp.covariance is not None:
            covariance = compose_covariance(*optical_to_c, np.zeros((6, 6)), pnp.covariance)
        return {"CO": PoseEstimate(q, t, covariance).to_measurement(timestamp_ns)}


@register
class ProjectiveCalibration(Service):
    """Projection C -> I (3x4) from features with known positions in C (normalised DLT plus
    gold-standard refinement). ``zero_skew`` uses OpenCV's 10-parameter camera model."""

    NAME = "projective_calibration"
    INPUTS = {"IF": Port((Position2D,)), "CF": Port((Position3D,))}
    OUTPUTS = ("CI",)
    CORRESPONDENCE = ("IF", "CF")
    MIN_CORRESPONDENCES = 6
    TIME_MIN_MOTION = 2.0  # pixels
    PARAMETERS = {"zero_skew": False}

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        rows = _rows(values, self.CORRESPONDENCE, self.MIN_CORRESPONDENCES)
        image, model = zip(*rows, strict=True)
        p = projection_dlt(
            _points(list(model)), _points(list(image)), zero_skew=bool(self.parameters["zero_skew"])
        )
        return {"CI": Projection(timestamp_ns, p)}


@register
class Triangulation(Service):
    """Position of F in C from its images in two or more views with projections C -> I_k."""

    NAME = "triangulation"
    INPUTS = {"CI": Port((Projection,)), "IF": Port((Position2D,))}
    OUTPUTS = ("CF",)
    CORRESPONDENCE = ("CI", "IF")
    MIN_CORRESPONDENCES = 2
    PARAMETERS = {"pixel_sigma": 0.0}

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        rows = _rows(values, self.CORRESPONDENCE, self.MIN_CORRESPONDENCES)
        projections = np.array([p.matrix for p, _ in rows])
        pixels = np.array([[x.position] for _, x in rows])
        sigma = float(self.parameters["pixel_sigma"]) or None
        result = triangulate_points(projections, pixels, pixel_sigma=sigma)
        return {"CF": Position3D(timestamp_ns, result.points[0], result.covariances[0])}


@register
class HandEyeCalibration(Service):
    """``AX = XB`` from simultaneous poses of a hand H in R and of an object O in the eye C:
    the eye in the hand (``HC``) and the object in R (``RO``), each with its covariance.

    :func:`ubitrack_agent.services.algorithms.hand_eye_calibration`: Park & Martin's closed form
    over all motion pairs, then a joint Gauss-Newton refinement of both poses over the absolute
    poses (Dornaika & Horaud 1998), so ``RO``'s covariance includes the uncertainty of ``HC``. The
    samples' covariances weight it when every ``RH`` and ``CO`` sample carries one
    (``ErrorPose``); otherwise the noise is estimated from the residuals. Time expansion;
    motions must rotate about two or more axes.
    """

    NAME = "hand_eye_calibration"
    INPUTS = {"RH": Port(POSES), "CO": Port(POSES)}
    OUTPUTS = ("HC", "RO")
    CORRESPONDENCE = ("RH", "CO")
    MIN_CORRESPONDENCES = 3
    TIME_MIN_ROTATION_DEG = 5.0

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        rows = _rows(values, self.CORRESPONDENCE, self.MIN_CORRESPONDENCES)
        hands, eyes = zip(*rows, strict=True)
        covariances = None
        if all(isinstance(sample, ErrorPose) for sample in (*hands, *eyes)):
            covariances = (
                np.array([h.covariance for h in hands]),
                np.array([e.covariance for e in eyes]),
            )
        solution = hand_eye_calibration(
            np.array([h.rotation for h in hands]),
            np.array([h.translation for h in hands]),
            np.array([e.rotation for e in eyes]),
            np.array([e.translation for e in eyes]),
            *(covariances or (None, None)),
        )
        return {
            "HC": solution.eye_in_hand.to_measurement(timestamp_ns),
            "RO": solution.target_in_base.to_measurement(timestamp_ns),
        }
