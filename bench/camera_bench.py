"""Corner error of the real camera's ArUco detection (:mod:`ubitrack_agent.io.camera.aruco`)
on images rendered from the simulated world (:mod:`bench.marker_images`).

Run: ``python -m bench.camera_bench [--frames N]`` (default 8 frames per cell). For each
distance and tilt, N frames of a 10 cm ``4X4_50`` marker at a random spin and sideways offset,
without noise and with Gaussian grey-level noise (``sigma`` 3 of 255, clipped), are rendered,
detected with the command's detector (sub-pixel refinement) and compared corner by corner with
the simulated camera's projection of the true corners. Prints one row per cell (frames with
the whole marker in view, the fraction of them detected, RMS and largest corner error in
pixels) and writes ``bench/results/camera.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from bench.marker_images import marker_world, render, true_corners
from bench.synthetic import rng_for
from ubitrack_agent.io.camera.aruco import detect_markers, make_detector

RESULTS = Path(__file__).parent / "results" / "camera.json"

LENGTH = 0.1
DISTANCES_M = (0.3, 0.6, 1.0, 1.5, 2.0)
TILTS_DEG = (0.0, 30.0, 50.0, 65.0)
NOISE_LEVELS = (0.0, 3.0)
"""Grey-level noise (standard deviation, of 255) added to the rendered image."""


def cell(
    distance: float, tilt: float, noise: float, frames: int, rng: np.random.Generator
) -> dict[str, float]:
    """Detection rate and corner errors (px) over the frames, of ``frames`` rendered ones of a
    cell, that show all four corners."""
    detector = make_detector()
    errors: list[np.ndarray] = []
    in_view = 0
    for _ in range(frames):
        offset = tuple(rng.uniform(-0.15, 0.15, 2) * distance)
        world = marker_world(distance, tilt, rng.uniform(0.0, 360.0), offset)
        truth, visible = true_corners(world, "IP", "M", LENGTH, 0)
        if not visible:  # a corner out of the image: not a fair test of the detector
            continue
        in_view += 1
        image = render(world, "IP", {"M": 7}, LENGTH, 0).astype(float)
        image = np.clip(image + rng.normal(0.0, noise, image.shape), 0, 255).astype(np.uint8)
        found = [m for m in detect_markers(image, detector) if m.id == 7]
        if found:
            errors.append(np.linalg.norm(found[0].corners - truth, axis=1))
    flat = np.concatenate(errors) if errors else np.zeros(0)
    return {
        "distance_m": distance,
        "tilt_deg": tilt,
        "noise_grey": noise,
        "in_view": in_view,
        "detected": len(errors) / in_view if in_view else float("nan"),
        "rms_px": float(np.sqrt(np.mean(flat**2))) if len(flat) else float("nan"),
        "max_px": float(flat.max()) if len(flat) else float("nan"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8, help="frames per cell")
    frames = parser.parse_args().frames
    rng = rng_for("camera_bench")
    start = time.perf_counter()
    cells = []
    print("dist m  tilt noise in view  found  RMS px  max px")
    for noise in NOISE_LEVELS:
        for distance in DISTANCES_M:
            for tilt in TILTS_DEG:
                row = cell(distance, tilt, noise, frames, rng)
                cells.append(row)
                print(
                    f"{distance:6.1f} {tilt:5.0f} {noise:5.0f} {row['in_view']:7d} "
                    f"{row['detected']:6.0%} {row['rms_px']:7.3f} {row['max_px']:7.3f}"
                )
    results = {
        "command": f"python -m bench.camera_bench --frames {frames}",
        "date": time.strftime("%Y-%m-%d"),
        "machine": f"{os.cpu_count()} CPU, Python {platform.python_version()}, "
        f"OpenCV {cv2.__version__}",
        "marker": {"dictionary": "4X4_50", "length_m": LENGTH, "focal_px": 800},
        "seconds": round(time.perf_counter() - start, 1),
        "cells": cells,
    }
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"written to {RESULTS}")


if __name__ == "__main__":
    main()
