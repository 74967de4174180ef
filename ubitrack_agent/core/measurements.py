"""Measurement types: the values that flow along the edges of a spatial relationship graph.

Conventions (also in ``docs/architecture.md``):

* **Direction.** A measurement on the SRG edge ``A -> B`` is the pose (or position, ...) of
  ``B`` expressed in ``A``: a point with coordinates ``x_B`` in frame B has coordinates
  ``x_A = R x_B + t`` in frame A. This is the paper's and Ubitrack's convention (section 2).
* **Units.** Metres and radians. Adapters convert from millimetres (A.R.T. DTrack) on entry.
* **Quaternions** are ``(x, y, z, w)``, scalar last, as in scipy's ``Rotation.from_quat``.
  They are validated to be of unit norm within :data:`UNIT_QUATERNION_TOLERANCE` and are kept
  exactly as given (not renormalised), so that encode/decode round-trips are exact. Readers of
  files typed by hand (static-edges files, scenarios) first pass a quaternion through
  :func:`normalise_typed_quaternion`, which normalises one whose norm is within
  :data:`TYPED_QUATERNION_TOLERANCE` of 1 (four decimals) but not a unit quaternion.
* **Pose covariance** is 6x6 over the left ("global") perturbation ``T = Exp(xi) T_mean`` with
  ``xi = (phi, rho)``, rotation first, expressed in the coordinates of the edge's source frame A;
  this is the ordering of scipy's ``RigidTransform.as_exp_coords`` and of pytransform3d. See
  :mod:`ubitrack_agent.core.uncertainty` for propagation and
  ``../shared/reference/field-notes.md`` section 9 for the derivation.
* **Position covariance** is the plain covariance of the coordinates (3x3 or 2x2).
* **Timestamps** are integer nanoseconds (``0 <= t < 2**63``), in the clock of the sensor's
  host (normally ``time.time_ns()``).
* **Camera model** follows OpenCV: the camera looks along +z, image y points down, the
  intrinsic matrix is ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` and distortion coefficients
  are OpenCV's ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tx, ty]]]])``.

Every type validates its fields on construction and raises
:class:`~ubitrack_agent.core.errors.MeasurementError` naming the field; values are stored as
read-only float64 arrays, so a measurement that exists is a valid one. The data path validates
less where the checks would be repeated (:data:`FULL`, :data:`WORKER`, :data:`DERIVED`): a
known worker's sample, and the results of this package's own maths, whose numbers the encoder
checks before they leave the process.
"""

from __future__ import annotations

import functools
import math
import numbers
import sys
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, ClassVar, NamedTuple, Self

import numpy as np

from ubitrack_agent.core.errors import MeasurementError

UNIT_QUATERNION_TOLERANCE = 1e-6
"""Largest accepted deviation of a quaternion's norm from 1."""

TYPED_QUATERNION_TOLERANCE = 1e-3
"""Largest deviation from 1 of the norm of a quaternion read from a file, which
:func:`normalise_typed_quaternion` normalises: a unit quaternion typed with four decimals is
off by up to about 1e-4. The wire codec keeps :data:`UNIT_QUATERNION_TOLERANCE`."""

MAX_TIMESTAMP_NS = 2**63 - 1
"""Timestamps are non-negative signed 64-bit nanoseconds (until the year 2262)."""

MAX_FUTURE_NS = 10 * 10**9
"""How far ahead of the receiving host's clock a sample's timestamp may be (10 s: clocks kept
by NTP agree within milliseconds; an unsynchronised host seconds off still works). A sample
accepted just within it can hold back newer instants by at most this long
(``core.timeline.ahead_of_clock``; defined here, as the agent, which has no SciPy, reads it
too: ``agent.clocks``)."""

MAX_LIST_LENGTH = 1_000_000
"""Largest accepted number of points in a position list."""

OPENCV_DISTORTION_LENGTHS = (0, 4, 5, 8, 12, 14)
"""Numbers of distortion coefficients OpenCV's camera model accepts."""

_SYMMETRY_TOLERANCE = 1e-9
_PSD_TOLERANCE = 1e-9


FULL, WORKER, DERIVED = "full", "worker", "derived"
"""Validation levels (``Measurement.checked``). ``FULL``: a value from outside (a provider, a
file, an unknown publisher, an application): every property. ``WORKER``: a sample from a known
worker of this system, computed by this package's maths: shapes, finiteness and positive
semi-definite covariances (by Cholesky), not the properties that hold by construction (unit
quaternions, symmetric covariances, an intrinsic matrix's form). ``DERIVED``: a result of
this process's own maths: shapes only, its arrays kept (not copied) and made read-only; its
numbers are checked where it leaves the process, by the encoder
(``ubitrack_agent.core.codec.encode``), so degenerate maths never passes NaN on. Each numpy
call costs a microsecond, and ten to twenty on a CPU woken for the sample, so a pattern hop
pays for every check it repeats (``docs/performance.md``, "Data path")."""


@dataclass(frozen=True)
class ArrayField:
    """Describes one float64 array field of a measurement type.

    ``shape`` uses ``None`` for a free dimension (the number of points of a list). ``check``
    validates the array's properties at level ``FULL``, ``worker_check`` (if any) at level
    ``WORKER``.
    """

    name: str
    shape: tuple[int | None, ...]
    optional: bool = False
    allowed_lengths: tuple[int, ...] | None = None
    check: Callable[[str, np.ndarray], None] | None = None
    worker_check: Callable[[str, np.ndarray], None] | None = None

    def check_at(self, level: str) -> Callable[[str, np.ndarray], None] | None:
        """The check of an array of this field at validation ``level`` (none at ``DERIVED``)."""
        return self.check if level == FULL else self.worker_check if level == WORKER else None

    @functools.cached_property
    def fixed_bytes(self) -> int | None:
        """The size in bytes of an array of a fixed shape (float64), None for a list."""
        return None if None in self.shape else 8 * math.prod(self.shape)  # type: ignore[misc]


def _fail(where: str, what: str) -> MeasurementError:
    return MeasurementError(f"{where}: {what}")


def is_timestamp(value: Any) -> bool:
    """Whether ``value`` already is a timestamp as stored: a Python int in ``[0, 2**63)`` (the
    common case, decided at once; :func:`check_timestamp` converts or names anything else)."""
    return type(value) is int and 0 <= value <= MAX_TIMESTAMP_NS


def check_timestamp(where: str, value: Any) -> int:
    """Return ``value`` as an int nanosecond timestamp, or raise naming ``where``."""
    if is_timestamp(value):
        return value
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise _fail(where, f"must be an integer number of nanoseconds, got {type(value).__name__}")
    value = int(value)
    if not 0 <= value <= MAX_TIMESTAMP_NS:
        raise _fail(where, f"out of range [0, 2**63): {value}")
    return value


_FLOAT64 = np.dtype(np.float64)


def _is_float_array(value: Any, spec: ArrayField) -> bool:
    """Whether ``value`` already is a float64 array of ``spec``'s (fixed) shape."""
    return type(value) is np.ndarray and value.dtype == _FLOAT64 and value.shape == spec.shape


def _as_array(where: str, value: Any, spec: ArrayField) -> np.ndarray:
    """``value`` as a float64 array of ``spec``'s shape: itself if it already is one that
    cannot change, else a copy (never aliasing a caller's array)."""
    if _is_float_array(value, spec):
        return value.copy() if value.flags.writeable else value
    return _shaped(where, value, spec)


def _check_finite(name: str, specs: list[ArrayField], arrays: list[np.ndarray]) -> None:
    """Reject NaN or infinity in any of ``arrays``: one reduction over them all (a numpy call
    costs a microsecond whatever its size), then, only on failure, the field at fault."""
    if len(arrays) == 1:
        if np.isfinite(arrays[0]).all():
            return
    elif np.isfinite(np.concatenate([array.ravel() for array in arrays])).all():
        return
    for spec, array in zip(specs, arrays, strict=True):
        if not np.isfinite(array).all():
            raise _fail(f"{name}.{spec.name}", "contains NaN or infinity")


def _shaped(where: str, value: Any, spec: ArrayField) -> np.ndarray:
    """``value`` as a float64 array (a copy if it could change) of ``spec``'s shape, or the
    error naming what is wrong."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _fail(where, f"not an array of numbers ({exc})") from None
    if array is value and array.flags.writeable:
        array = array.copy()
    if array.ndim != len(spec.shape) or not all(
        want is None or got == want for got, want in zip(array.shape, spec.shape, strict=True)
    ):
        shape = "x".join("N" if d is None else str(d) for d in spec.shape)
        raise _fail(where, f"shape must be {shape}, got {'x'.join(map(str, array.shape))}")
    if spec.allowed_lengths is not None and array.shape[0] not in spec.allowed_lengths:
        raise _fail(where, f"length must be one of {spec.allowed_lengths}, got {array.shape[0]}")
    if array.ndim and array.shape[0] > MAX_LIST_LENGTH:
        raise _fail(where, f"more than {MAX_LIST_LENGTH} entries")
    return array


def check_unit_quaternion(where: str, q: np.ndarray) -> None:
    """Reject a quaternion whose norm is not 1 within :data:`UNIT_QUATERNION_TOLERANCE`."""
    norm = math.hypot(*q)  # no overflow for huge components
    if abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE:
        raise _fail(where, f"not a unit quaternion (norm {norm:.9g})")


def check_covariance(where: str, cov: np.ndarray) -> None:
    """Reject a matrix that is not symmetric positive semi-definite (within round-off)."""
    scale = max(1.0, float(np.abs(cov).max()))
    if np.abs(cov - cov.T).max() > _SYMMETRY_TOLERANCE * scale:
        raise _fail(where, "covariance is not symmetric")
    if not _positive_definite()(cov):
        _check_eigenvalues(where, cov, scale)


def check_semidefinite(where: str, cov: np.ndarray) -> None:
    """Reject a (symmetric) matrix that is not positive semi-definite within round-off: the
    ``WORKER`` level's covariance check. The tolerance's scale is the largest absolute entry
    (of a positive semi-definite matrix, its largest diagonal entry: within a factor n of its
    trace, and, unlike the trace of huge entries, never overflowing)."""
    if not _positive_definite()(cov):
        _check_eigenvalues(where, cov, None)


@functools.cache
def _positive_definite() -> Callable[[np.ndarray], bool]:
    """Whether a symmetric matrix is positive definite, by a Cholesky factorisation (Golub &
    Van Loan, Matrix Computations, 4.2.5): it decides at once for every covariance a sensor or
    an estimate produces, at half an eigendecomposition's cost; only a singular or indefinite
    one (an exact component, round-off) needs the eigenvalues (:func:`_check_eigenvalues`).
    LAPACK's ``dpotrf`` called directly where SciPy is loaded (every worker), which costs 2 us,
    and 40 us on a CPU woken for the sample, against 7 and 100 us through numpy's wrapper (its
    error state and checks); numpy's where it is not (the agent runs without SciPy, and is not
    made to import it here)."""
    if "scipy" in sys.modules:
        from scipy.linalg.lapack import dpotrf

        return lambda matrix: dpotrf(matrix, lower=1, clean=0)[1] == 0
    return _positive_definite_by_numpy


def _positive_definite_by_numpy(matrix: np.ndarray) -> bool:
    """Whether ``matrix`` is positive definite by numpy's Cholesky; given a stack of matrices
    (n x m x m), whether every one is, by one call (:func:`stacked_check`)."""
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        return False
    return True


def _unit_quaternions(stack: np.ndarray) -> bool:
    """Whether every quaternion of a stack (n x 4) passes :func:`check_unit_quaternion`: its
    norm as the square root of the sum of squares, within the tolerance less a relative margin
    of 1e-6, against which the few units in the last place by which it may differ from
    ``math.hypot``'s are nothing; a sum that overflows or underflows fails here (each is then
    checked alone, by ``math.hypot``, which does neither)."""
    norms = np.sqrt(np.einsum("ij,ij->i", stack, stack))
    return bool((np.abs(norms - 1.0) <= UNIT_QUATERNION_TOLERANCE * (1.0 - 1e-6)).all())


def _covariances(stack: np.ndarray) -> bool:
    """Whether every matrix of a stack (n x m x m) passes :func:`check_covariance`: its
    symmetry test matrix by matrix (the same floating-point operations on the same numbers:
    the same verdict), then numpy's Cholesky factorisation of the whole stack, as for
    :func:`check_semidefinite`."""
    scale = np.maximum(1.0, np.abs(stack).max(axis=(1, 2)))
    asymmetry = np.abs(stack - stack.transpose(0, 2, 1)).max(axis=(1, 2))
    symmetric = bool((asymmetry <= _SYMMETRY_TOLERANCE * scale).all())
    return symmetric and _positive_definite_by_numpy(stack)


_STACKED_CHECKS: dict[Callable[[str, np.ndarray], None], Callable[[np.ndarray], bool]] = {
    # Where numpy's factorisation succeeds, check_semidefinite passes: no eigenvalue is left
    # below round-off, far inside its tolerance.
    check_semidefinite: _positive_definite_by_numpy,
    # A value from outside (FULL) in a run: an application's relation, a worker's input from a
    # provider (docs/performance.md, "Throughput, session 22": each was checked alone before,
    # which made a run dearer than its samples one by one).
    check_covariance: _covariances,
    check_unit_quaternion: _unit_quaternions,
}


def stacked_check(
    check: Callable[[str, np.ndarray], None],
) -> Callable[[np.ndarray], bool] | None:
    """For a field's ``check``, a test over a stack of such arrays that passes only where
    ``check`` passes for every one: how a run of samples is checked at once
    (``core.codec.decode_run``); None where there is none, and each array is checked alone."""
    return _STACKED_CHECKS.get(check)


def _check_eigenvalues(where: str, cov: np.ndarray, scale: float | None) -> None:
    """Reject ``cov`` unless its smallest eigenvalue is at least ``-_PSD_TOLERANCE * scale``
    (``scale`` None: the largest absolute entry, at least 1) and finite (the eigenvalues of
    huge entries may overflow)."""
    if scale is None:
        scale = max(1.0, float(np.abs(cov).max()))
    smallest = float(np.linalg.eigvalsh(cov)[0])
    if not smallest >= -_PSD_TOLERANCE * scale:  # also NaN
        raise _fail(where, f"covariance is not positive semi-definite (eigenvalue {smallest:.3g})")


def check_intrinsic_matrix(where: str, k: np.ndarray) -> None:
    """Reject a matrix that is not ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with fx, fy > 0."""
    if k[1, 0] != 0.0 or k[2, 0] != 0.0 or k[2, 1] != 0.0 or k[2, 2] != 1.0:
        raise _fail(where, "must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    if k[0, 0] <= 0.0 or k[1, 1] <= 0.0:
        raise _fail(where, f"focal lengths must be positive, got fx={k[0, 0]}, fy={k[1, 1]}")


def check_projection(where: str, p: np.ndarray) -> None:
    """Reject a 3x4 projection whose left 3x3 block is singular (no finite camera centre)."""
    singular_values = np.linalg.svd(p[:, :3], compute_uv=False)
    if singular_values[0] == 0.0 or singular_values[2] < 1e-12 * singular_values[0]:
        raise _fail(where, "left 3x3 block is singular")


class FixedLayout(NamedTuple):
    """The fields of a measurement type that holds only its timestamp and arrays of fixed
    shapes (every type but the lists and the camera intrinsics): what the lean paths of the
    decoder and of :meth:`Measurement.derived` rely on."""

    names: tuple[str, ...]
    """The array fields, in ``ARRAY_FIELDS`` order."""
    shapes: tuple[tuple[int, ...], ...]
    fields: frozenset[str]
    """Every field's name, ``timestamp_ns`` included."""
    required: frozenset[str]
    """The fields a value must hold: ``fields`` but the optional arrays."""
    absent: dict[str, None]
    """Each optional array field left out (None), for a value that holds only ``required``."""


@functools.cache
def fixed_layout(cls: type[Measurement]) -> FixedLayout | None:
    """``cls``'s :class:`FixedLayout`, None if a field is a list or no array."""
    specs = cls.ARRAY_FIELDS
    names = tuple(spec.name for spec in specs)
    if any(None in spec.shape for spec in specs) or {f.name for f in fields(cls)} != {
        "timestamp_ns",
        *names,
    }:
        return None
    shapes = tuple(spec.shape for spec in specs)
    optional = [spec.name for spec in specs if spec.optional]
    every = frozenset({"timestamp_ns", *names})
    return FixedLayout(names, shapes, every, every - set(optional), dict.fromkeys(optional))  # type: ignore[arg-type]


@functools.cache
def _defaults(cls: type) -> tuple[tuple[str, Callable[[], Any] | Any], ...]:
    """Each dataclass field of ``cls`` with a function making its default (``MISSING`` for a
    required field): ``Measurement.checked`` builds values without the dataclass constructor."""
    made = []
    for f in fields(cls):
        if f.default is not MISSING:
            made.append((f.name, lambda value=f.default: value))
        elif f.default_factory is not MISSING:
            made.append((f.name, f.default_factory))
        else:
            made.append((f.name, MISSING))
    return tuple(made)


@dataclass(frozen=True, eq=False)
class Measurement:
    """Base class: a timestamped value of one SRG edge type.

    Subclasses declare ``TYPE_TAG`` (the wire tag), ``SRG_TYPE`` (the edge type it measures:
    ``6D``, ``3D``, ``2D``, ``3R``, ``3x4`` or ``intrinsics``) and ``ARRAY_FIELDS``.
    """

    TYPE_TAG: ClassVar[str]
    SRG_TYPE: ClassVar[str]
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]]

    timestamp_ns: int

    def __post_init__(self) -> None:
        self._validate(FULL)

    def _validate(self, level: str, finite: bool = False) -> None:
        name = type(self).__name__
        values = self.__dict__  # a frozen dataclass: fields set here, once, before use
        timestamp = values["timestamp_ns"]
        if not is_timestamp(timestamp):
            values["timestamp_ns"] = check_timestamp(f"{name}.timestamp_ns", timestamp)
        present = []
        for spec in self.ARRAY_FIELDS:
            value = values[spec.name]
            if value is None:
                if not spec.optional:
                    raise _fail(f"{name}.{spec.name}", "is required")
                continue
            present.append(spec)
            if not _is_float_array(value, spec):
                value = _shaped(f"{name}.{spec.name}", value, spec)  # a copy if it could change
                value.flags.writeable = False
                values[spec.name] = value
            elif value.flags.writeable:
                # The maths' own new array is kept (DERIVED); anyone else's is copied. Either
                # way it is made read-only; a decoded one (over the message's bytes) already is.
                value = value if level == DERIVED else value.copy()
                value.flags.writeable = False
                values[spec.name] = value
        if level != DERIVED:  # a result's numbers are checked by the encoder
            arrays = [values[spec.name] for spec in present]
            if arrays and not finite:
                _check_finite(name, present, arrays)
            for spec, array in zip(present, arrays, strict=True):
                check = spec.check_at(level)
                if check is not None:
                    check(f"{name}.{spec.name}", array)
        self._check_extra()

    @classmethod
    def checked(cls, level: str, *, finite: bool = False, **values: Any) -> Self:
        """A measurement of ``values`` validated at ``level`` (``FULL``, ``WORKER`` or
        ``DERIVED``; the constructor is ``FULL``); ``finite``: the caller has checked that
        every number is finite (the decoder, over a message's bytes at once)."""
        value = object.__new__(cls)
        fields_of = value.__dict__  # a frozen dataclass: set here, once, before anyone uses it
        for name, default in _defaults(cls):
            if name in values:
                fields_of[name] = values[name]
            elif default is MISSING:
                raise TypeError(f"{cls.__name__}: missing {name}")
            else:
                fields_of[name] = default()
        value._validate(level, finite)
        return value

    @classmethod
    def derived(cls, **values: Any) -> Self:
        """A measurement computed by this package's maths from valid measurements, validated at
        level ``DERIVED``: the data path uses it for results. Anything from outside goes through
        the validating constructor or the decoder.

        The maths' float64 arrays of the declared shapes are taken in one pass over the type's
        :func:`fixed_layout` (a result is built on every hop, and a generic pass costs it 30 us
        more on a CPU woken for the sample: ``docs/performance.md``, "Data path"); anything
        else goes through :meth:`checked`, which converts it or names the fault."""
        layout = fixed_layout(cls)
        if layout is None:
            return cls.checked(DERIVED, **values)
        keys = values.keys()
        if keys != layout.fields:
            if keys != layout.required:
                return cls.checked(DERIVED, **values)
            values.update(layout.absent)
        if not is_timestamp(values["timestamp_ns"]) or not all(
            _is_float_array(value, spec)
            for spec in cls.ARRAY_FIELDS
            if (value := values[spec.name]) is not None or not spec.optional
        ):
            return cls.checked(DERIVED, **values)
        for name in layout.names:
            if (value := values[name]) is not None:
                value.setflags(write=False)
        return cls.unchecked(values)

    @classmethod
    def unchecked(cls, values: dict[str, Any]) -> Self:
        """A measurement holding ``values`` as they are, nothing checked: the caller built
        them itself, every field of the type, its arrays float64 of the declared shapes and
        read-only (:meth:`derived` after its checks, ``core.poses`` for the poses it composes).
        Every check a result skips costs a numpy call, about 10 us each on a CPU woken for the
        sample among other processes (``docs/performance.md``, "Data path")."""
        value = object.__new__(cls)
        value.__dict__.update(values)  # a frozen dataclass: set here, once, before use
        return value

    def restamped(self, timestamp_ns: int) -> Self:
        """The same value at another time (no re-validation of the unchanged arrays)."""
        value = object.__new__(type(self))
        value.__dict__.update(self.__dict__)
        object.__setattr__(value, "timestamp_ns", check_timestamp("timestamp_ns", timestamp_ns))
        return value

    def _check_extra(self) -> None:
        """Validate fields that are not float arrays (overridden where there are any)."""

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # type: ignore[assignment]


_ROTATION = ArrayField("rotation", (4,), check=check_unit_quaternion)


def normalise_typed_quaternion(where: str, value: Any) -> np.ndarray:
    """``value``, a quaternion (x, y, z, w) read from a file: as given if it is a unit quaternion
    within :data:`UNIT_QUATERNION_TOLERANCE` (so files round-trip exactly), else divided by its
    norm; raises :class:`MeasurementError` naming ``where`` if it is not four finite numbers or
    its norm is more than :data:`TYPED_QUATERNION_TOLERANCE` from 1."""
    q = _as_array(where, value, _ROTATION)
    if not np.isfinite(q).all():
        raise _fail(where, "contains NaN or infinity")
    deviation = abs(math.hypot(*q) - 1.0)
    if deviation > TYPED_QUATERNION_TOLERANCE:
        raise _fail(
            where,
            f"not a unit quaternion (norm {math.hypot(*q):.9g}, more than "
            f"{TYPED_QUATERNION_TOLERANCE:g} from 1): normalise it",
        )
    return q if deviation <= UNIT_QUATERNION_TOLERANCE else q / math.hypot(*q)


_TRANSLATION = ArrayField("translation", (3,))


@dataclass(frozen=True, eq=False)
class Pose(Measurement):
    """6D pose of B in A: unit quaternion ``rotation`` (x, y, z, w) and ``translation`` (m)."""

    TYPE_TAG: ClassVar[str] = "Pose"
    SRG_TYPE: ClassVar[str] = "6D"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (_ROTATION, _TRANSLATION)

    rotation: np.ndarray
    translation: np.ndarray


@dataclass(frozen=True, eq=False)
class ErrorPose(Measurement):
    """6D pose with a 6x6 covariance over the left perturbation ``xi = (phi, rho)``.

    ``static_covariance`` (optional) is the part of ``covariance`` that is the error of static
    edges (a calibration's, a survey's): the same in every sample of the flow that computed it,
    so a filter fusing many of them must not average it away. A worker marks a fixed input's
    whole covariance so (``net.spec.InputBinding.fixed_error``), ``core.poses`` carries the part
    through inversions and concatenations as the covariance, and the fusion's filter *considers* it
    (``services.algorithms.pose_filter``, Schmidt-Kalman). Absent, the whole error is white.
    """

    TYPE_TAG: ClassVar[str] = "ErrorPose"
    SRG_TYPE: ClassVar[str] = "6D"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (
        _ROTATION,
        _TRANSLATION,
        ArrayField("covariance", (6, 6), check=check_covariance, worker_check=check_semidefinite),
        ArrayField(
            "static_covariance",
            (6, 6),
            optional=True,
            check=check_covariance,
            worker_check=check_semidefinite,
        ),
    )

    rotation: np.ndarray
    translation: np.ndarray
    covariance: np.ndarray
    static_covariance: np.ndarray | None = None

    def mean(self) -> Pose:
        """The pose without its covariance."""
        return Pose(self.timestamp_ns, self.rotation, self.translation)


@dataclass(frozen=True, eq=False)
class Position3D(Measurement):
    """3D position of B in A (m), with an optional 3x3 covariance (m^2)."""

    TYPE_TAG: ClassVar[str] = "Position3D"
    SRG_TYPE: ClassVar[str] = "3D"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (
        ArrayField("position", (3,)),
        ArrayField(
            "covariance",
            (3, 3),
            optional=True,
            check=check_covariance,
            worker_check=check_semidefinite,
        ),
    )

    position: np.ndarray
    covariance: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Position2D(Measurement):
    """2D image position (px) of a point B in image plane A, optional 2x2 covariance (px^2)."""

    TYPE_TAG: ClassVar[str] = "Position2D"
    SRG_TYPE: ClassVar[str] = "2D"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (
        ArrayField("position", (2,)),
        ArrayField(
            "covariance",
            (2, 2),
            optional=True,
            check=check_covariance,
            worker_check=check_semidefinite,
        ),
    )

    position: np.ndarray
    covariance: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Rotation3D(Measurement):
    """Orientation of B in A as a unit quaternion (x, y, z, w): the ``3R`` edge type."""

    TYPE_TAG: ClassVar[str] = "Rotation3D"
    SRG_TYPE: ClassVar[str] = "3R"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (_ROTATION,)

    rotation: np.ndarray


@dataclass(frozen=True, eq=False)
class PositionList3D(Measurement):
    """N simultaneous 3D positions (N x 3, m): one sample of a space-expanded 3D edge set."""

    TYPE_TAG: ClassVar[str] = "PositionList3D"
    SRG_TYPE: ClassVar[str] = "3D"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (ArrayField("positions", (None, 3)),)

    positions: np.ndarray


@dataclass(frozen=True, eq=False)
class PositionList2D(Measurement):
    """N simultaneous image positions (N x 2, px): one sample of a space-expanded 2D edge set."""

    TYPE_TAG: ClassVar[str] = "PositionList2D"
    SRG_TYPE: ClassVar[str] = "2D"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (ArrayField("positions", (None, 2)),)

    positions: np.ndarray


@dataclass(frozen=True, eq=False)
class Projection(Measurement):
    """3x4 projection matrix ``P = K [R | t]`` mapping homogeneous points of B to image A."""

    TYPE_TAG: ClassVar[str] = "Projection"
    SRG_TYPE: ClassVar[str] = "3x4"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (
        ArrayField("matrix", (3, 4), check=check_projection),
    )

    matrix: np.ndarray


@dataclass(frozen=True, eq=False)
class CameraIntrinsics(Measurement):
    """Intrinsic matrix, OpenCV distortion coefficients and optional image size (w, h) in px."""

    TYPE_TAG: ClassVar[str] = "CameraIntrinsics"
    SRG_TYPE: ClassVar[str] = "intrinsics"
    ARRAY_FIELDS: ClassVar[tuple[ArrayField, ...]] = (
        ArrayField("matrix", (3, 3), check=check_intrinsic_matrix),
        ArrayField("distortion", (None,), allowed_lengths=OPENCV_DISTORTION_LENGTHS),
    )

    matrix: np.ndarray
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(0))
    image_size: tuple[int, int] | None = None

    def _check_extra(self) -> None:
        if self.image_size is None:
            return
        where = "CameraIntrinsics.image_size"
        size = self.image_size
        if not isinstance(size, tuple | list) or len(size) != 2:
            raise _fail(where, "must be a pair (width, height)")
        for value in size:
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise _fail(where, "width and height must be integers")
            if not 0 < int(value) <= 1 << 20:
                raise _fail(where, f"width and height must be in [1, 2**20], got {value}")
        object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))


MEASUREMENT_TYPES: dict[str, type[Measurement]] = {
    cls.TYPE_TAG: cls
    for cls in (
        Pose,
        ErrorPose,
        Position3D,
        Position2D,
        Rotation3D,
        PositionList3D,
        PositionList2D,
        Projection,
        CameraIntrinsics,
    )
}
"""Every measurement type by its wire tag."""
