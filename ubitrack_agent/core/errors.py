"""The one exception raised for an invalid measurement, built or decoded."""


class MeasurementError(ValueError):
    """A measurement failed validation.

    The message always names the offending field and what was wrong with it, e.g.
    ``"Pose.rotation: not a unit quaternion (norm 1.2)"``. Decoders raise nothing else, whatever
    the bytes they are given, so a caller can count and log rejects with one ``except``.
    """


class ExtrapolationError(ValueError):
    """A value was asked for at a time outside the samples available to interpolate it."""


class NoMotionModel(ExtrapolationError):
    """A value was asked for after the samples of a flow that has no motion model to predict
    it (only measured edges and interpolation on the way)."""


class NoDataError(LookupError):
    """A value was asked for before any sample arrived."""


class TooFewCorrespondences(ValueError):
    """An instant carries fewer complete correspondences than the algorithm needs (a feature
    hidden in a frame): expected in normal operation, so a worker counts and summarises it
    rather than warning each time."""
