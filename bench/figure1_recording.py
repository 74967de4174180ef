"""A seeded recording of the figure-1 calibration set-up (Pustka et al., ISMAR 2006, 4.2).

Runs the simulator models of ``sim_trackers`` offline (no zenoh, no clocks): the world of the
scenario (default ``sim_trackers/scenarios/paper_figure1.yaml``), the simulated camera
(:class:`ubitrack_agent.sim_trackers.sim_camera.CameraSimulator`, 30 Hz) and the simulated A.R.T.
tracker (:class:`ubitrack_agent.sim_trackers.sim_art.ArtSimulator`, 60 Hz, at a seeded phase to the
camera, as two unsynchronised devices), each with its own seeded generator. It records the measured
inputs of the three section 4.2 solutions that ``ubitrack plan examples/paper_calibration.yaml
--from C
--to HT --type 6D --static --all`` lists:

* ``IP -> F1..F5`` (2D, pixels; NaN where the feature is occluded or out of view) per camera
  frame,
* ``ART -> HT`` and ``ART -> WT`` (6D) per tracker frame, with the DTrack adapter's covariance
  (the scenario's noise about each body's origin,
  :func:`ubitrack_agent.core.uncertainty.in_place_covariance`); a frame where the tracker lost
  a body repeats its last pose,
* the static database edges ``WT -> F1..F5`` (3D) and the camera matrix (``C -> IP``),
* and the truth of ``C -> HT`` for scoring.

The functions below derive the per-sample inputs of each solution as the live components
compute them: PnP with the pixel noise estimated from each frame's residuals (the 2D-3D pose
estimation's default ``pixel_sigma: 0``), inversion and concatenation with first-order
covariance propagation (``ubitrack_agent.core.poses``), and the synchronisation's
interpolation (``ubitrack_agent.core.timeline``: SLERP and linear, covariances blended
linearly; a static input gives its latest value). Two streams of the direct computation:

* :func:`direct_samples` - one ``C -> HT`` per camera frame (the tracker interpolated at the
  camera's instants);
* :func:`live_direct_samples` - what the live flow feeds its averaging: the last
  concatenation is triggered by both of its inputs, so it computes at the camera's instants
  and at the tracker's (90 Hz), at the latter with the PnP pose interpolated between two
  camera frames. Consecutive samples then share a PnP error: the stream is correlated in time
  (autocorrelation about 0.7, 0.3, 0.1 at lags 1 to 3; measured live, 86 Hz: 0.78, 0.43,
  0.14), though every device's noise is independent from frame to frame.

Run ``python -m bench.figure1_recording [--seed S] [--duration SECONDS] [--out FILE.npz]``
to write one recording to a file (``numpy.savez``); the benchmarks and tests record in memory.
"""

from __future__ import annotations

import argparse
import zlib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ubitrack_agent.core import ErrorPose, quaternions, se3
from ubitrack_agent.core.poses import compose_poses, interpolate_pose, invert_pose
from ubitrack_agent.core.uncertainty import in_place_covariance, isotropic_pose_covariance
from ubitrack_agent.services.algorithms.pnp import solve_pnp
from ubitrack_agent.sim_trackers.scenario import Scenario, load_scenario
from ubitrack_agent.sim_trackers.sim_art import ArtSimulator
from ubitrack_agent.sim_trackers.sim_camera import CameraSimulator

SEED = 20240601
"""The bench's seed base (``bench.synthetic.SEED``); a recording's seed is combined with it."""

WALK_PERIOD_S = 20.0
"""Period of the default scenario's Lissajous walk (0.05 and 0.1 Hz)."""


@dataclass(frozen=True)
class Recording:
    """Camera frames (``F``, ``N`` features each) and tracker frames (``T``) of one run.

    Poses are the pose of the second frame in the first (``x_A = R x_B + t``); quaternions
    ``(x, y, z, w)``; covariances 6x6 over the left perturbation, rotation first."""

    seed: int
    camera_ns: np.ndarray
    """(F,) camera frame timestamps."""
    pixels: np.ndarray
    """(F, N, 2) ``IP -> Fi`` in pixels; NaN where not seen."""
    tracker_ns: np.ndarray
    """(T,) tracker frame timestamps, covering the camera frames."""
    art_ht_q: np.ndarray
    art_ht_t: np.ndarray
    art_ht_cov: np.ndarray
    """(T, 4), (T, 3), (T, 6, 6): ``ART -> HT`` as the DTrack adapter publishes it."""
    art_wt_q: np.ndarray
    art_wt_t: np.ndarray
    art_wt_cov: np.ndarray
    """(T, 4), (T, 3), (T, 6, 6): ``ART -> WT`` (static, but a new noisy sample each frame)."""
    features_wt: np.ndarray
    """(N, 3) ``WT -> Fi`` (database, exact)."""
    camera_matrix: np.ndarray
    """(3, 3) the intrinsics of ``C -> IP`` (database, exact; no distortion)."""
    pixel_sigma: float
    """The camera's pixel noise (px per axis)."""
    truth_q: np.ndarray
    truth_t: np.ndarray
    """The true ``C -> HT``."""

    def save(self, path: str | Path) -> None:
        """Write to ``path`` with ``numpy.savez``."""
        np.savez(path, **{field.name: getattr(self, field.name) for field in fields(self)})


def _rng(seed: int, part: str) -> np.random.Generator:
    return np.random.default_rng([SEED, seed, zlib.crc32(part.encode())])


def record(
    seed: int = 0,
    duration_s: float = 60.0,
    scenario: Scenario | None = None,
    start_s: float | None = None,
) -> Recording:
    """Record ``duration_s`` of the scenario's camera and tracker frames.

    ``start_s`` (scenario time, seconds) defaults to a seeded point of the walk, so repeated
    seeds see different stretches of it as well as different noise; the tracker's phase to
    the camera is seeded too."""
    scenario = scenario or load_scenario()
    world, art, camera = scenario.world, scenario.art, scenario.camera
    plane = world.image_planes[camera.image_plane]
    if np.any(plane.distortion):
        raise ValueError("the recording's PnP assumes an undistorted camera")
    if start_s is None:
        start_s = 1_000.0 + _rng(seed, "start").uniform(0.0, WALK_PERIOD_S)
    start_ns = round(start_s * 1e6) * 1000
    frames = int(duration_s * camera.rate)
    camera_ns = start_ns + np.round(np.arange(frames) * 1e9 / camera.rate).astype(np.int64)
    # Tracker frames from one before the first camera frame to one after the last one, at a
    # seeded phase; whole microseconds, as DTrack's timestamps.
    phase_ns = _rng(seed, "phase").uniform(0.0, 1e9 / art.rate)
    count = int((camera_ns[-1] - camera_ns[0]) * 1e-9 * art.rate) + 3
    tracker_ns = start_ns - round(phase_ns) + np.round(np.arange(count) * 1e9 / art.rate)
    tracker_ns = (tracker_ns.astype(np.int64) // 1000) * 1000

    cameras = CameraSimulator(world, camera, _rng(seed, "camera"))
    pixels = np.full((frames, len(camera.features), 2), np.nan)
    for k, time_ns in enumerate(camera_ns.tolist()):
        seen = cameras.measure(time_ns)
        for i, feature in enumerate(camera.features):
            measurement = seen.get(f"{camera.image_plane}_{feature}")
            if measurement is not None:
                pixels[k, i] = measurement.position

    tracker = ArtSimulator(world, art, _rng(seed, "art"))
    bodies = {name: body_id for body_id, name in art.bodies.items()}
    poses: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {"HT": [], "WT": []}
    for time_ns in tracker_ns.tolist():
        tracked = {body.id: body for body in tracker.frame(time_ns).bodies}
        for name, track in poses.items():
            body = tracked.get(bodies[name])
            if body is not None:
                track.append((quaternions.from_matrix(body.rotation), body.position_mm / 1e3))
            else:  # lost: the last pose, or the truth for a body lost in the very first frame
                track.append(track[-1] if track else world.pose(art.frame, name, time_ns))
    noise = isotropic_pose_covariance(
        np.radians(art.noise.rotation_deg), art.noise.position_mm / 1e3
    )

    def stack(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        q = np.array([pose[0] for pose in poses[name]])
        t = np.array([pose[1] for pose in poses[name]])
        return q, t, np.array([in_place_covariance(x, noise) for x in t])

    ht_q, ht_t, ht_cov = stack("HT")
    wt_q, wt_t, wt_cov = stack("WT")
    truth_q, truth_t = world.pose(plane.camera, "HT", int(camera_ns[0]))
    return Recording(
        seed=seed,
        camera_ns=camera_ns,
        pixels=pixels,
        tracker_ns=tracker_ns,
        art_ht_q=ht_q,
        art_ht_t=ht_t,
        art_ht_cov=ht_cov,
        art_wt_q=wt_q,
        art_wt_t=wt_t,
        art_wt_cov=wt_cov,
        features_wt=np.array([world.pose("WT", f, int(camera_ns[0]))[1] for f in camera.features]),
        camera_matrix=plane.matrix.copy(),
        pixel_sigma=camera.noise_px,
        truth_q=truth_q,
        truth_t=truth_t,
    )


class PoseSamples(NamedTuple):
    """Pose samples: quaternions (K, 4), translations (K, 3), covariances (K, 6, 6),
    timestamps (K,), and which samples exist (K,) (a PnP needs four features)."""

    q: np.ndarray
    t: np.ndarray
    cov: np.ndarray
    times_ns: np.ndarray
    valid: np.ndarray

    def pose(self, k: int) -> ErrorPose:
        """Sample ``k`` as an :class:`ErrorPose`."""
        return ErrorPose(int(self.times_ns[k]), self.q[k], self.t[k], self.cov[k])

    @classmethod
    def of(cls, poses: list[ErrorPose | None]) -> PoseSamples:
        """From a list of poses (``None``: no sample)."""
        identity = ErrorPose(0, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.eye(6))
        filled = [identity if pose is None else pose for pose in poses]
        return cls(
            np.array([pose.rotation for pose in filled]),
            np.array([pose.translation for pose in filled]),
            np.array([pose.covariance for pose in filled]),
            np.array([pose.timestamp_ns for pose in filled], dtype=np.int64),
            np.array([pose is not None for pose in poses]),
        )


def tracker_at(recording: Recording, body: str, times_ns: np.ndarray) -> list[ErrorPose]:
    """``ART -> body`` at ``times_ns`` as the synchronisation gives it: ``HT`` (dynamic)
    interpolated between the tracker frames around each instant, ``WT`` (static) the latest
    frame at or before it."""
    q, t, cov = (getattr(recording, f"art_{body.lower()}_{part}") for part in ("q", "t", "cov"))
    times = recording.tracker_ns
    after = np.searchsorted(times, times_ns, "left")
    poses = []
    for time_ns, k in zip(times_ns.tolist(), after.tolist(), strict=True):
        exact = times[k] == time_ns
        if body == "WT" or exact:
            j = k if exact else k - 1
            poses.append(ErrorPose(time_ns, q[j], t[j], cov[j]))
        else:
            before = ErrorPose(int(times[k - 1]), q[k - 1], t[k - 1], cov[k - 1])
            following = ErrorPose(int(times[k]), q[k], t[k], cov[k])
            poses.append(interpolate_pose(before, following, time_ns))
    return poses


def _pnp(recording: Recording, frame: int, points: np.ndarray) -> ErrorPose | None:
    """PnP on frame ``frame`` if it has four or more features (the pattern's multiplicity)."""
    seen = ~np.isnan(recording.pixels[frame, :, 0])
    if seen.sum() < 4:
        return None
    pose = solve_pnp(points[seen], recording.pixels[frame, seen], recording.camera_matrix)
    return ErrorPose(
        int(recording.camera_ns[frame]), pose.rotation, pose.translation, pose.covariance
    )


def camera_to_world_target(recording: Recording) -> PoseSamples:
    """``C -> WT`` per camera frame: 2D-3D pose estimation (space) on ``IP -> Fi`` and
    ``WT -> Fi``."""
    frames = range(len(recording.camera_ns))
    return PoseSamples.of([_pnp(recording, k, recording.features_wt) for k in frames])


def head_target_to_world_target(recording: Recording, times_ns: np.ndarray) -> list[ErrorPose]:
    """``HT -> WT = (ART -> HT)^-1 (ART -> WT)`` at ``times_ns``."""
    return [
        compose_poses(invert_pose(head), target)
        for head, target in zip(
            tracker_at(recording, "HT", times_ns),
            tracker_at(recording, "WT", times_ns),
            strict=True,
        )
    ]


def direct_samples(recording: Recording) -> PoseSamples:
    """Solution "direct computation" at the camera's instants: ``C -> HT = (C -> WT)
    (WT -> ART)(ART -> HT)``, the tracker interpolated to each camera frame."""
    camera = camera_to_world_target(recording)
    ht_wt = head_target_to_world_target(recording, recording.camera_ns)
    return PoseSamples.of(
        [
            compose_poses(camera.pose(k), invert_pose(ht_wt[k])) if camera.valid[k] else None
            for k in range(len(ht_wt))
        ]
    )


def live_direct_samples(recording: Recording) -> PoseSamples:
    """Solution "direct computation" as the live flow computes it: at every tracker frame
    between two camera frames with a PnP pose, ``C -> WT`` interpolated between them."""
    camera = camera_to_world_target(recording)
    inside = (recording.tracker_ns > recording.camera_ns[0]) & (
        recording.tracker_ns < recording.camera_ns[-1]
    )
    times = np.union1d(recording.camera_ns, recording.tracker_ns[inside])
    ht_wt = head_target_to_world_target(recording, times)
    after = np.searchsorted(recording.camera_ns, times, "left")
    poses: list[ErrorPose | None] = []
    for k, frame in enumerate(after.tolist()):
        if recording.camera_ns[frame] == times[k]:  # a camera frame: its own PnP pose
            c_wt = camera.pose(frame) if camera.valid[frame] else None
        elif camera.valid[frame - 1] and camera.valid[frame]:
            c_wt = interpolate_pose(camera.pose(frame - 1), camera.pose(frame), int(times[k]))
        else:
            c_wt = None
        poses.append(None if c_wt is None else compose_poses(c_wt, invert_pose(ht_wt[k])))
    return PoseSamples.of(poses)


def features_in_head_target(recording: Recording) -> np.ndarray:
    """``HT -> Fi = (HT -> WT)(WT -> Fi)`` at each camera frame, (F, N, 3)."""
    return np.array(
        [
            se3.transform_points(pose.rotation, pose.translation, recording.features_wt)
            for pose in head_target_to_world_target(recording, recording.camera_ns)
        ]
    )


def head_target_pnp_samples(recording: Recording) -> PoseSamples:
    """Solution "2D-3D pose estimation through HT -> Fi": PnP per camera frame on ``IP ->
    Fi`` and ``HT -> Fi``, giving ``C -> HT`` directly (covariance from the pixels only, as
    the live component: it takes no covariance of 3D points)."""
    points = features_in_head_target(recording)
    return PoseSamples.of([_pnp(recording, k, points[k]) for k in range(len(points))])


def hand_eye_inputs(recording: Recording) -> tuple[PoseSamples, PoseSamples]:
    """Solution "hand-eye calibration": ``ART -> HT`` (hand in base) and ``C -> WT`` (target
    in eye) at each camera frame with a PnP pose."""
    camera = camera_to_world_target(recording)
    head = PoseSamples.of(tracker_at(recording, "HT", recording.camera_ns))
    return head, camera


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds")
    parser.add_argument("--out", default="figure1_recording.npz")
    args = parser.parse_args(argv)
    recording = record(args.seed, args.duration)
    recording.save(args.out)
    print(
        f"{len(recording.camera_ns)} camera and {len(recording.tracker_ns)} tracker frames "
        f"written to {args.out}"
    )


if __name__ == "__main__":
    main()
