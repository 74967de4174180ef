"""A real camera: ArUco markers detected with OpenCV (:mod:`.aruco`, pure), the sensor adapter
publishing their corners as 2D edges and, optionally, their poses as 6D edges (:mod:`.adapter`),
and the frame loop reading a video device or file (:mod:`.capture`). The paper's "camera
segmentation" component of figure 6; ``docs/camera.md`` explains its use. The package itself
loads no OpenCV: the command reads its defaults here."""

DEFAULT_SIGMA_PX = 0.5
"""Corner noise per axis (px): a conservative figure for sub-pixel refined corners of a
printed marker under office light; measure yours (the spread of a marker at rest)."""

DEFAULT_DEPTH_M = 0.5
"""Working distance (m) at which the announced metric sigma is computed."""
