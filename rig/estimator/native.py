"""ctypes binding to the C estimator built as a host shared library.

The library is built from the same sources as the firmware (``make -C
estimator_c native``) when it is missing or older than any source. Struct
mirrors are numpy dtypes (for arrays of events and outputs) and are checked
against the C sizes at load time, so a drifted header fails loudly.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import logging
import os
import subprocess
import threading
from pathlib import Path

import numpy as np

from rig.data.paths import PROJECT_ROOT
from rig.estimator.bias_net import NET_DTYPE

log = logging.getLogger(__name__)

ESTIMATOR_DIR = PROJECT_ROOT / "estimator_c"
BUILD_DIR = ESTIMATOR_DIR / "build"
NATIVE_PROGRAM = BUILD_DIR / "estimator_native"
FIRMWARE_ELF = BUILD_DIR / "stm32f405" / "firmware.elf"
LIBRARY_ENV = "UWB_RIG_ESTIMATOR_LIB"  # use this library instead (e.g. the sanitizer build)

STATE_DIM = 9
MAX_ANCHORS = 16
EV_ACCEL, EV_GYRO, EV_TDOA, EV_STEP = 1, 2, 3, 4
REJECT_REASONS = ("nonfinite", "unknown_anchor", "same_anchor", "exceeds_baseline", "time_backwards",
                  "queue_full", "bad_kind", "gate")

EVENT_DTYPE = np.dtype([("t_us", "<u4"), ("kind", "u1"), ("id_a", "u1"), ("id_b", "u1"), ("reserved", "u1"),
                        ("v", "<f4", 3)])
COUNTERS_DTYPE = np.dtype([("steps", "<u4"), ("imu_samples", "<u4"), ("imu_gaps", "<u4"),
                           ("tdoa_accepted", "<u4"), ("tdoa_downweighted", "<u4"), ("tdoa_rejected", "<u4"),
                           ("rejected", "<u4", len(REJECT_REASONS)), ("resets", "<u4"),
                           ("tdoa_anchor_weighted", "<u4")])
OUTPUT_DTYPE = np.dtype([("t_us", "<u4"), ("pos", "<f4", 3), ("vel", "<f4", 3), ("quat", "<f4", 4),
                         ("cov_diag", "<f4", STATE_DIM), ("counters", COUNTERS_DTYPE)])


class EstimatorParams(ctypes.Structure):
    """Mirror of est_params_t."""

    _fields_ = [
        ("tdoa_std", ctypes.c_float),
        ("accel_noise", ctypes.c_float),
        ("gyro_noise", ctypes.c_float),
        ("position_noise", ctypes.c_float),
        ("velocity_noise", ctypes.c_float),
        ("gate_m", ctypes.c_float),
        ("gm_state_c2", ctypes.c_float),
        ("gm_meas_c2", ctypes.c_float),
        ("robust", ctypes.c_uint8),
        ("irls_iterations", ctypes.c_uint8),
        ("use_bias_net", ctypes.c_uint8),
        ("thrust_only", ctypes.c_uint8),
        ("trust_prior_n", ctypes.c_float),
        ("anchor_bias_c", ctypes.c_float),
    ]

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name, _ in self._fields_}


class NativeBuildError(RuntimeError):
    """The estimator library could not be built."""


_lock = threading.Lock()
_libraries: dict[Path, ctypes.CDLL] = {}


def _sources() -> list[Path]:
    return [p for p in ESTIMATOR_DIR.rglob("*") if p.suffix in (".c", ".h") or p.name == "Makefile"]


@contextlib.contextmanager
def _build_lock():
    """One build at a time across processes (parallel test workers, a farm's boards):
    two makes in one tree would write the same objects and libraries at once."""
    BUILD_DIR.mkdir(parents=True, exist_ok=True)
    with open(BUILD_DIR / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def make(*targets: str) -> None:
    """Run the estimator's Makefile for `targets`; a failure carries the compiler output."""
    with _build_lock():
        proc = subprocess.run(["make", "-s", "-C", str(ESTIMATOR_DIR), *targets], capture_output=True, text=True)
    if proc.returncode != 0:
        raise NativeBuildError(f"building {' '.join(targets)} failed:\n{proc.stdout}{proc.stderr}")


def built(artifact: Path, make_target: str) -> Path:
    """`artifact`, rebuilt with `make make_target` when missing or older than any source."""
    newest = max(p.stat().st_mtime for p in _sources())
    if not artifact.exists() or artifact.stat().st_mtime < newest:
        make(make_target)           # under the lock, make itself skips what another process just built
    if not artifact.exists():
        raise NativeBuildError(f"make {make_target} did not produce {artifact}")
    return artifact


def build(target: str = "native") -> Path:
    """Build (if stale) and return the path of the host library."""
    name = {"native": "libestimator.so", "sanitize": "libestimator-asan.so"}[target]
    return built(BUILD_DIR / name, target)


def library() -> ctypes.CDLL:
    """The loaded estimator library (built on first use)."""
    path = Path(os.environ[LIBRARY_ENV]) if LIBRARY_ENV in os.environ else build()
    with _lock:
        if path not in _libraries:
            _libraries[path] = _load(path)
        return _libraries[path]


def _load(path: Path) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    for name in ("estimator", "event", "output", "params", "bias_net"):
        getattr(lib, f"est_sizeof_{name}").restype = ctypes.c_size_t
    expected = {"event": EVENT_DTYPE.itemsize, "output": OUTPUT_DTYPE.itemsize,
                "params": ctypes.sizeof(EstimatorParams), "bias_net": NET_DTYPE.itemsize}
    for name, size in expected.items():
        actual = getattr(lib, f"est_sizeof_{name}")()
        if actual != size:
            raise NativeBuildError(f"{path}: sizeof({name}) is {actual} in C, {size} in the binding")
    lib.est_default_params.argtypes = [ctypes.POINTER(EstimatorParams)]
    lib.est_init.argtypes = [ctypes.c_void_p, ctypes.POINTER(EstimatorParams)]
    lib.est_set_anchor.argtypes = [ctypes.c_void_p, ctypes.c_uint8, ctypes.c_void_p, ctypes.c_void_p]
    lib.est_set_anchor.restype = ctypes.c_int
    lib.est_set_bias_net.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.est_reset.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_void_p, ctypes.c_void_p]
    lib.est_replay.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_size_t]
    lib.est_replay.restype = ctypes.c_size_t
    lib.est_copy_covariance.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.est_correction_trust.argtypes = [ctypes.c_void_p]
    lib.est_copy_anchor_weights.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.est_correction_trust.restype = ctypes.c_float
    lib.bn_features.argtypes = [ctypes.c_void_p] * 7
    lib.bn_features_batch.argtypes = [ctypes.c_size_t] + [ctypes.c_void_p] * 7
    lib.bn_predict.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint]
    lib.bn_predict.restype = ctypes.c_float
    return lib


def default_params() -> EstimatorParams:
    params = EstimatorParams()
    library().est_default_params(ctypes.byref(params))
    return params


def _f32(values, shape) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(values, np.float32).reshape(shape))


def _ptr(array: np.ndarray) -> ctypes.c_void_p:
    return ctypes.c_void_p(array.ctypes.data)


class Estimator:
    """One C estimator_t, owned by Python memory."""

    def __init__(self, params: EstimatorParams | None = None):
        self.lib = library()
        self._memory = ctypes.create_string_buffer(self.lib.est_sizeof_estimator())
        self.handle = ctypes.cast(self._memory, ctypes.c_void_p)
        self.params = params if params is not None else default_params()
        self.lib.est_init(self.handle, ctypes.byref(self.params))
        self._net: np.ndarray | None = None  # keeps the weights alive while C points at them

    def set_anchor(self, anchor_id: int, position, quaternion) -> None:
        pos, quat = _f32(position, 3), _f32(quaternion, 4)  # named: alive during the call
        if self.lib.est_set_anchor(self.handle, anchor_id, _ptr(pos), _ptr(quat)):
            raise ValueError(f"anchor {anchor_id} rejected by the estimator (id range or non-finite pose)")

    def set_bias_net(self, packed: np.ndarray | None) -> None:
        self._net = packed
        self.lib.est_set_bias_net(self.handle, _ptr(packed) if packed is not None else None)

    def reset(self, t_us: int, position, quaternion=None) -> None:
        pos = _f32(position, 3)
        quat = _f32(quaternion, 4) if quaternion is not None else None
        self.lib.est_reset(self.handle, int(t_us), _ptr(pos), _ptr(quat) if quat is not None else None)

    def correction_trust(self) -> float:
        """The share of the bias correction the estimator applies now: the regression slope
        of the flight's uncorrected innovations on the corrections so far."""
        return float(self.lib.est_correction_trust(self.handle))

    def anchor_weights(self) -> np.ndarray:
        """Each anchor id's weight in the blocked-anchor weighting now (1: not discounted)."""
        out = np.ones(MAX_ANCHORS, np.float32)
        self.lib.est_copy_anchor_weights(self.handle, _ptr(out))
        return out

    def covariance(self) -> np.ndarray:
        out = np.zeros((STATE_DIM, STATE_DIM), np.float32)
        self.lib.est_copy_covariance(self.handle, _ptr(out))
        return out

    def replay(self, events: np.ndarray) -> np.ndarray:
        """Run an EVENT_DTYPE array; returns the OUTPUT_DTYPE array (one row per STEP)."""
        events = np.ascontiguousarray(events, dtype=EVENT_DTYPE)
        outputs = np.zeros(int(np.count_nonzero(events["kind"] == EV_STEP)), OUTPUT_DTYPE)
        n = self.lib.est_replay(self.handle, _ptr(events), len(events), _ptr(outputs), len(outputs))
        return outputs[:n]


def features(tag_pos, tag_quat, a_pos, a_quat, b_pos, b_quat) -> np.ndarray:
    """The C feature function for one measurement (quaternions x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    lib = library()
    out = np.zeros(14, np.float32)
    # Every array is held by a name for the duration of the call (a bare temporary's
    # memory could be freed before C reads it).
    mats = [_f32(Rotation.from_quat(q).as_matrix(), (3, 3)) for q in (tag_quat, a_quat, b_quat)]
    points = [_f32(p, 3) for p in (tag_pos, a_pos, b_pos)]
    lib.bn_features(_ptr(points[0]), _ptr(mats[0]), _ptr(points[1]), _ptr(mats[1]), _ptr(points[2]),
                    _ptr(mats[2]), _ptr(out))
    return out


def features_batch(tag_pos, tag_rot, a_pos, a_rot, b_pos, b_rot) -> np.ndarray:
    """The C feature function over n measurements: positions (n, 3), rotation matrices (n, 3, 3)."""
    arrays = [_f32(x, (-1, 3)) if k % 2 == 0 else _f32(x, (-1, 3, 3))
              for k, x in enumerate((tag_pos, tag_rot, a_pos, a_rot, b_pos, b_rot))]
    n = len(arrays[0])
    if any(len(a) != n for a in arrays):
        raise ValueError("features_batch: all inputs need the same number of rows")
    out = np.zeros((n, 14), np.float32)
    library().bn_features_batch(n, *(_ptr(a) for a in arrays), _ptr(out))
    return out


def predict_bias(packed: np.ndarray, feature_vector, id_a: int = 0, id_b: int = 1) -> float:
    """The C inference of a packed model for one measurement between anchors id_a and id_b."""
    features32 = _f32(feature_vector, 14)
    return float(library().bn_predict(_ptr(packed), _ptr(features32), id_a, id_b))


def params_with(**overrides) -> EstimatorParams:
    """Default parameters with some fields replaced."""
    params = default_params()
    for key, value in overrides.items():
        if key not in dict(EstimatorParams._fields_):
            raise ValueError(f"unknown estimator parameter {key!r}")
        setattr(params, key, value)
    return params
