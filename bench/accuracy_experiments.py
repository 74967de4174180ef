"""The experiments of the accuracy benchmark (field-notes sections 2 and 11).

Every experiment draws its data from ``rng_for(name)`` and runs our algorithm and the library
methods on the very same inputs. Results are plain dicts: per noise level and method the
per-trial errors and call times, summarised by :mod:`bench.accuracy_bench`.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable
from functools import partial
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from bench.synthetic import (
    CAMERA_MATRIX,
    camera_ring,
    hand_eye_scene,
    observe_points,
    perturb_poses,
    project,
    random_quaternion,
    rng_for,
    rotation_error,
    sample_poses,
)
from ubitrack_agent.core.uncertainty import skew
from ubitrack_agent.services.algorithms import (
    PoseEstimate,
    PoseKalmanFilter,
    absolute_orientation,
    decompose_projection,
    fuse_poses,
    hand_eye_daniilidis,
    hand_eye_park_martin,
    projection_dlt,
    solve_pnp,
    solve_pnp_ransac,
    triangulate_points,
)
from ubitrack_agent.services.algorithms.dlt import homogeneous
from ubitrack_agent.services.algorithms.pnp import OPENCV_METHODS

Errors = dict[str, dict[str, list[float]]]
"""method -> {"rot_deg": [...], "trans_mm": [...], "time_us": [...], ...}"""

NO_DISTORTION = np.zeros(5)
GROSS_ROTATION_DEG = 5.0
"""A pose whose rotation error exceeds this counts as a gross failure."""


def timed(function: Callable[[], Any]) -> tuple[Any, float]:
    """``function()`` and its wall time in microseconds."""
    start = time.perf_counter()
    result = function()
    return result, (time.perf_counter() - start) * 1e6


def from_opencv(rvec: np.ndarray, tvec: np.ndarray) -> PoseEstimate:
    return PoseEstimate(Rotation.from_rotvec(np.ravel(rvec)).as_quat(), np.ravel(tvec))


def opencv_pnp(flag_name: str, refine: bool = False) -> Callable[..., PoseEstimate]:
    """A solver calling ``cv2.solvePnP`` with the named flag (optionally + RefineLM)."""

    def solve(obj: np.ndarray, img: np.ndarray) -> PoseEstimate:
        _, rvec, tvec = cv2.solvePnP(
            obj, img, CAMERA_MATRIX, NO_DISTORTION, flags=OPENCV_METHODS[flag_name]
        )
        if refine:
            rvec, tvec = cv2.solvePnPRefineLM(obj, img, CAMERA_MATRIX, NO_DISTORTION, rvec, tvec)
        return from_opencv(rvec, tvec)

    return solve


def pose_experiment(
    name: str,
    trials: int,
    noise_levels: list[float],
    make_trial: Callable[[np.random.Generator, float], tuple[PoseEstimate, tuple]],
    methods: dict[str, Callable[..., PoseEstimate]],
) -> dict[float, Errors]:
    """Rotation (deg) and translation (mm) errors of pose solvers on shared random trials."""
    rng = rng_for(name)
    results: dict[float, Errors] = {}
    for noise in noise_levels:
        errors: Errors = defaultdict(lambda: defaultdict(list))
        for _ in range(trials):
            truth, inputs = make_trial(rng, noise)
            for method, solve in methods.items():
                estimate, micros = timed(partial(solve, *inputs))
                errors[method]["rot_deg"].append(
                    float(np.degrees(rotation_error(estimate.rotation, truth.rotation)))
                )
                errors[method]["trans_mm"].append(
                    1e3 * float(np.linalg.norm(estimate.translation - truth.translation))
                )
                errors[method]["time_us"].append(micros)
        results[noise] = errors
    return results


# --- 3D-3D -------------------------------------------------------------------------------


def absolute_orientation_trial(n_points: int) -> Callable:
    def trial(rng: np.random.Generator, sigma_mm: float) -> tuple[PoseEstimate, tuple]:
        truth = PoseEstimate(random_quaternion(rng), rng.uniform(-1, 1, 3))
        b = rng.uniform(-0.25, 0.25, (n_points, 3))
        a = Rotation.from_quat(truth.rotation).apply(b) + truth.translation
        return truth, (a + rng.normal(0, sigma_mm * 1e-3, a.shape), b)

    return trial


def opencv_umeyama(a: np.ndarray, b: np.ndarray) -> PoseEstimate:
    transform, _ = cv2.estimateAffine3D(b, a, force_rotation=True)
    return PoseEstimate(Rotation.from_matrix(transform[:, :3]).as_quat(), transform[:, 3])


def scipy_align_vectors(a: np.ndarray, b: np.ndarray) -> PoseEstimate:
    rotation, _ = Rotation.align_vectors(a - a.mean(axis=0), b - b.mean(axis=0))
    return PoseEstimate(rotation.as_quat(), a.mean(axis=0) - rotation.apply(b.mean(axis=0)))


ABSOLUTE_ORIENTATION_METHODS = {
    "ours absolute_orientation": absolute_orientation,
    "cv2.estimateAffine3D(force_rotation)": opencv_umeyama,
    "scipy align_vectors": scipy_align_vectors,
}


# --- 2D-3D pose ----------------------------------------------------------------------------


def _observed(rng, truth, object_points, sigma_px) -> tuple[PoseEstimate, tuple]:
    camera_points = Rotation.from_quat(truth.rotation).apply(object_points) + truth.translation
    pixels = project(camera_points) + rng.normal(0, sigma_px, (len(object_points), 2))
    return truth, (object_points, pixels)


def epnp_protocol_trial(n_points: int) -> Callable:
    """Lepetit et al. (EPnP, IJCV 2009): points uniform in [-2, 2]^2 x [4, 8] (camera frame)."""

    def trial(rng: np.random.Generator, sigma_px: float) -> tuple[PoseEstimate, tuple]:
        camera_points = rng.uniform([-2, -2, 4], [2, 2, 8], (n_points, 3))
        truth = PoseEstimate(random_quaternion(rng), camera_points.mean(axis=0))
        rotation = Rotation.from_quat(truth.rotation)
        return _observed(
            rng, truth, rotation.inv().apply(camera_points - truth.translation), sigma_px
        )

    return trial


def _tilted_pose(rng: np.random.Generator, max_tilt_deg: float, distance: float) -> PoseEstimate:
    """A target facing the camera, tilted up to ``max_tilt_deg``, spun freely in its plane."""
    axis = np.array([*rng.normal(size=2), 0.0])
    tilt = Rotation.from_rotvec(
        axis / np.linalg.norm(axis) * np.radians(rng.uniform(0, max_tilt_deg))
    )
    spin = Rotation.from_rotvec([0, 0, rng.uniform(-np.pi, np.pi)])
    facing = Rotation.from_rotvec([np.pi, 0, 0])  # target z axis towards the camera
    position = np.array([*rng.uniform(-0.05, 0.05, 2) * distance, distance])
    return PoseEstimate((tilt * facing * spin).as_quat(), position)


def body_trial(rng: np.random.Generator, sigma_px: float) -> tuple[PoseEstimate, tuple]:
    """6 points in a 200 mm cube at 1 m, random orientation."""
    truth = PoseEstimate(random_quaternion(rng), np.array([*rng.uniform(-0.1, 0.1, 2), 1.0]))
    return _observed(rng, truth, rng.uniform(-0.1, 0.1, (6, 3)), sigma_px)


def grid_points(columns: int = 7, rows: int = 5, spacing: float = 0.03) -> np.ndarray:
    x, y = np.meshgrid(np.arange(columns) * spacing, np.arange(rows) * spacing)
    points = np.column_stack((x.ravel(), y.ravel(), np.zeros(x.size)))
    return points - points.mean(axis=0)


def grid_trial(rng: np.random.Generator, sigma_px: float) -> tuple[PoseEstimate, tuple]:
    """7 x 5 planar grid, 30 mm pitch, at 0.5 m, tilted up to 45 degrees."""
    return _observed(rng, _tilted_pose(rng, 45.0, 0.5), grid_points(), sigma_px)


MARKER = 0.05 * np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0.0]])


def marker_trial(rng: np.random.Generator, sigma_px: float) -> tuple[PoseEstimate, tuple]:
    """100 mm square marker at 0.5 m, tilted up to 45 degrees."""
    return _observed(rng, _tilted_pose(rng, 45.0, 0.5), MARKER, sigma_px)


def ours_pnp(obj: np.ndarray, img: np.ndarray) -> PoseEstimate:
    return solve_pnp(obj, img, CAMERA_MATRIX)


GENERAL_PNP_METHODS = {
    "ours solve_pnp (SQPnP+LM)": ours_pnp,
    "cv2 ITERATIVE": opencv_pnp("iterative"),
    "cv2 SQPNP": opencv_pnp("sqpnp"),
    "cv2 EPNP": opencv_pnp("epnp"),
    "cv2 EPNP+RefineLM": opencv_pnp("epnp", refine=True),
}
PLANAR_PNP_METHODS = {
    "ours solve_pnp (IPPE+LM)": ours_pnp,
    "cv2 ITERATIVE": opencv_pnp("iterative"),
    "cv2 IPPE": opencv_pnp("ippe"),
    "cv2 SQPNP": opencv_pnp("sqpnp"),
}
MARKER_PNP_METHODS = {
    "ours solve_pnp (IPPE_SQUARE+LM)": ours_pnp,
    "cv2 IPPE_SQUARE": opencv_pnp("ippe_square"),
    "cv2 IPPE": opencv_pnp("ippe"),
}


def ransac_trial(rng: np.random.Generator, sigma_px: float) -> tuple[PoseEstimate, tuple]:
    """EPnP protocol, N = 100, 20 % of the pixels replaced by uniform outliers."""
    truth, (obj, img) = epnp_protocol_trial(100)(rng, sigma_px)
    outliers = rng.choice(100, 20, replace=False)
    img = img.copy()
    img[outliers] = rng.uniform([0, 0], [640, 480], (20, 2))
    inliers = np.setdiff1d(np.arange(100), outliers)
    return truth, (obj, img, inliers)


def ours_ransac(obj, img, _inliers) -> PoseEstimate:
    return solve_pnp_ransac(obj, img, CAMERA_MATRIX)[0]


def opencv_ransac(obj, img, _inliers) -> PoseEstimate:
    _, rvec, tvec, _ = cv2.solvePnPRansac(obj, img, CAMERA_MATRIX, NO_DISTORTION)
    return from_opencv(rvec, tvec)


def oracle_inliers(obj, img, inliers) -> PoseEstimate:
    return opencv_pnp("iterative")(obj[inliers], img[inliers])


RANSAC_METHODS = {
    "ours solve_pnp_ransac (+LM)": ours_ransac,
    "cv2.solvePnPRansac": opencv_ransac,
    "oracle: ITERATIVE on true inliers": oracle_inliers,
}


# --- hand-eye ------------------------------------------------------------------------------

HAND_EYE_NOISE = {1: (0.1, 0.01), 2: (1.0, 0.1)}
"""Noise level -> (mm, degrees) per axis on every hand and eye pose."""


def hand_eye_trial(rng: np.random.Generator, level: float) -> tuple[PoseEstimate, tuple]:
    sigma_mm, sigma_deg = HAND_EYE_NOISE[int(level)]
    truth, (qg, tg, qc, tc) = hand_eye_scene(rng, 10)
    hand = perturb_poses(rng, qg, tg, np.radians(sigma_deg), sigma_mm * 1e-3)
    eye = perturb_poses(rng, qc, tc, np.radians(sigma_deg), sigma_mm * 1e-3)
    return truth, (*hand, *eye)


HAND_EYE_METHODS = {
    "ours Park-Martin": hand_eye_park_martin,
    "ours Daniilidis": hand_eye_daniilidis,
}


# --- fusion --------------------------------------------------------------------------------


def fusion_trial(rng: np.random.Generator, _noise: float) -> tuple[PoseEstimate, tuple]:
    """Two equal trackers, 0.1 degree and 1 mm per axis, of a pose about 1 m away."""
    covariance = np.diag([np.radians(0.1) ** 2] * 3 + [1e-6] * 3)
    truth = PoseEstimate(random_quaternion(rng), rng.uniform(-1, 1, 3))
    q, t = sample_poses(rng, truth, [covariance, covariance])
    return truth, (q, t, np.stack((covariance, covariance)))


def single_tracker(q, t, _covs) -> PoseEstimate:
    return PoseEstimate(q[0], t[0])


def pytransform3d_fusion(q, t, covs) -> PoseEstimate:
    from pytransform3d.uncertainty import pose_fusion

    matrices = np.array([np.eye(4)] * 2)
    matrices[:, :3, :3] = Rotation.from_quat(q).as_matrix()
    matrices[:, :3, 3] = t
    mean, _, _ = pose_fusion(matrices, covs)
    return PoseEstimate(Rotation.from_matrix(mean[:3, :3]).as_quat(), mean[:3, 3])


FUSION_METHODS = {
    "single tracker": single_tracker,
    "ours fuse_poses": fuse_poses,
    "pytransform3d pose_fusion": pytransform3d_fusion,
}


# --- DLT -----------------------------------------------------------------------------------


def dlt_experiment(name: str, trials: int, n_points: int, noise_levels: list[float]) -> dict:
    """Held-out reprojection RMS (px, vs noise-free) of P estimated from a non-planar rig."""
    rng = rng_for(name)
    results = {}
    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS
        | cv2.CALIB_ZERO_TANGENT_DIST
        | cv2.CALIB_FIX_K1
        | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3
    )
    for sigma in noise_levels:
        errors: Errors = defaultdict(lambda: defaultdict(list))
        for _ in range(trials):
            pose = PoseEstimate(random_quaternion(rng), np.array([0.0, 0.0, 3.0]))
            rotation = Rotation.from_quat(pose.rotation)
            rig = rng.uniform(-0.5, 0.5, (n_points, 3))
            held_out = rng.uniform(-0.5, 0.5, (200, 3))
            pixels = project(rotation.apply(rig) + pose.translation)
            noisy = pixels + rng.normal(0, sigma, pixels.shape)
            truth = project(rotation.apply(held_out) + pose.translation)

            def opencv(rig: np.ndarray, noisy: np.ndarray) -> np.ndarray:
                guess, _ = decompose_projection(projection_dlt(rig, noisy, refine=False))
                guess[0, 1] = 0.0  # OpenCV's camera model has no skew
                _, k, _, rvecs, tvecs = cv2.calibrateCamera(
                    [rig.astype(np.float32)],
                    [noisy.astype(np.float32)],
                    (640, 480),
                    guess,
                    np.zeros(5),
                    flags=flags,
                )
                rotation = Rotation.from_rotvec(rvecs[0].ravel()).as_matrix()
                return k @ np.column_stack((rotation, tvecs[0].ravel()))

            methods = {
                "ours DLT + gold standard (11 dof)": partial(projection_dlt),
                "ours DLT + gold standard, zero skew": partial(projection_dlt, zero_skew=True),
                "ours DLT (linear)": partial(projection_dlt, refine=False),
                "cv2.calibrateCamera (rig, DLT init)": opencv,
            }
            for method, solve in methods.items():
                projection, micros = timed(partial(solve, rig, noisy))
                image = homogeneous(held_out) @ projection.T
                residual = image[:, :2] / image[:, 2:] - truth
                errors[method]["msq_px2"].append(float(np.mean(np.sum(residual**2, axis=1))))
                errors[method]["time_us"].append(micros)
        results[sigma] = errors
    return results


# --- triangulation -------------------------------------------------------------------------


def triangulation_experiment(name: str, trials: int, n_views: int, noise_levels: list[float]):
    """3D error (mm) of one point near the centre of a ring of cameras (r = 2 m, 1 m high)."""
    rng = rng_for(name)
    projections = camera_ring(n_views, arc=np.pi if n_views == 2 else 2 * np.pi)
    results = {}
    for sigma in noise_levels:
        errors: Errors = defaultdict(lambda: defaultdict(list))
        for _ in range(trials):
            point = rng.uniform(-0.1, 0.1, (1, 3))
            exact = observe_points(projections, point)
            pixels = exact + rng.normal(0, sigma, exact.shape)
            bound = triangulate_points(projections, exact, pixel_sigma=sigma).covariances[0]
            errors["CRLB"]["sq_mm2"].append(1e6 * float(np.trace(bound)))
            methods = {
                "ours triangulate_points (+LM)": lambda p=pixels: (
                    triangulate_points(projections, p).points
                ),
                "ours linear (DLT)": lambda p=pixels: (
                    triangulate_points(projections, p, refine=False).points
                ),
            }
            if n_views == 2:
                methods["cv2.triangulatePoints"] = lambda p=pixels: _opencv_triangulate(
                    projections, p
                )
            for method, solve in methods.items():
                estimate, micros = timed(solve)
                errors[method]["sq_mm2"].append(1e6 * float(np.sum((estimate - point) ** 2)))
                errors[method]["time_us"].append(micros)
        results[sigma] = errors
    return results


def _opencv_triangulate(projections: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    homogeneous_points = cv2.triangulatePoints(
        projections[0], projections[1], pixels[0].T, pixels[1].T
    )
    return (homogeneous_points[:3] / homogeneous_points[3]).T


# --- Kalman ---


def _left_covariance(rotation_position_covariance: np.ndarray, translation: np.ndarray):
    """Covariance of ``xi = (phi, rho)`` for independent rotation and position noise:
    ``rho = dp + [t]x phi`` to first order."""
    jacobian = np.eye(6)
    jacobian[3:, :3] = skew(translation)
    return jacobian @ rotation_position_covariance @ jacobian.T


def _filter_step(kalman: PoseKalmanFilter, stamp: int, q, t, covariance) -> np.ndarray:
    for i in range(len(q)):
        kalman.update(stamp, q[i], t[i], covariance)
    return kalman.predict(stamp).translation


def kalman_experiment(name: str, sequences: int, seconds: float = 5.0) -> dict:
    """Two synchronous 60 Hz trackers (1 mm per axis, independent 0.1 degree) of a target on a
    0.3 m Lissajous loop at 0.25 Hz (peak acceleration about 1 m/s^2); 3D position error (mm)
    of one tracker, of the average of both, and of the Kalman filter, after 1 s of warm-up."""
    rng = rng_for(name)
    omega = 2 * np.pi * 0.25
    sigma_rot = np.radians(0.1)
    noise = np.diag([sigma_rot**2] * 3 + [1e-6] * 3)  # rotation vector, position
    rate = 60.0
    peak_acceleration = 0.3 * (2 * omega) ** 2
    errors: Errors = defaultdict(lambda: defaultdict(list))
    for _ in range(sequences):
        start = random_quaternion(rng)
        kalman = PoseKalmanFilter(
            angular_noise=(2 * omega * 0.5) ** 2 / rate,
            linear_noise=peak_acceleration**2 / rate,
        )
        for k in range(int(seconds * rate)):
            time_s = k / rate
            position = 0.3 * np.array(
                [np.cos(omega * time_s), np.sin(omega * time_s), 0.5 * np.sin(2 * omega * time_s)]
            )
            spin = Rotation.from_rotvec([0.0, 0.0, 0.5 * np.sin(omega * time_s)])
            truth = PoseEstimate((spin * Rotation.from_quat(start)).as_quat(), position)
            q, t = perturb_poses(
                rng, np.tile(truth.rotation, (2, 1)), np.tile(position, (2, 1)), sigma_rot, 1e-3
            )
            covariance = _left_covariance(noise, position)
            stamp = int(time_s * 1e9)

            estimate, micros = timed(partial(_filter_step, kalman, stamp, q, t, covariance))
            if time_s < 1.0:
                continue
            for method, value in (
                ("one tracker (raw)", t[0]),
                ("average of both (raw)", t.mean(axis=0)),
                ("ours PoseKalmanFilter", estimate),
            ):
                errors[method]["sq_mm2"].append(1e6 * float(np.sum((value - position) ** 2)))
            errors["ours PoseKalmanFilter"]["time_us"].append(micros / 2)
    return {1.0: errors}
