"""Several calibrated cameras' 2D detections triangulated into one skeleton (pure numpy).

Camera models (:class:`Camera`: intrinsics K in pixels, OpenCV distortion k1 k2 p1 p2 k3,
world-to-camera rotation R and translation t in metres; camera axes x right, y down, z forward)
come from

* a Qualisys QTM ``.qca.txt`` calibration (:func:`read_qca`): per camera ``transform`` (the
  camera's position x y z in mm and the matrix r11..r33, which turns world axes into QTM's camera
  axes, y up and looking along -z: R = diag(1, -1, -1) r in OpenCV's) and
  ``intrinsic`` (focal lengths and principal point in QTM sub-pixel units, 64 to a pixel, the
  principal point relative to the sensor, made relative to ``fov_video``; radial and tangential
  distortion as OpenCV's k1 k2 k3 p1 p2);
* an OpenCV-style TOML or YAML file (:func:`read_opencv_calibration`, the layout Pose2Sim and
  anipose write): one table per camera with ``name``, ``size`` [w, h] px, ``matrix`` (3x3 K, px),
  ``distortions`` [k1, k2, p1, p2(, k3)], ``rotation`` (Rodrigues vector or 3x3 matrix, world to
  camera) and ``translation`` (world to camera, m). YAML: the same tables under a top-level
  mapping (optionally under ``cameras:``).

Triangulation (:func:`triangulate`) is a confidence-weighted DLT over all joints at once
(batched SVD), in normalised (undistorted) camera coordinates, with a consensus over camera
pairs: a camera whose reprojection error for a joint exceeds ``reject_px`` disagrees and is
dropped for that joint. Quality: good when at least ``good_cameras`` cameras agree within
``good_px``, estimated when two agree, missing otherwise.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..formats.errors import FormatError
from ..messages.quality import QUALITY_ESTIMATED, QUALITY_GOOD, QUALITY_MISSING

QTM_SUBPIXELS = 64.0           # QTM stores focal length and principal point in 1/64 pixel
_QTM_AXES = np.diag([1.0, -1.0, -1.0])   # QTM camera axes (y up, looking along -z) -> OpenCV's


class CalibrationError(FormatError):
    """A calibration file that cannot be used (one line: file and fault)."""


@dataclass
class Camera:
    """A pinhole camera with OpenCV's lens distortion; R, t: world (m) to camera."""

    name: str
    K: np.ndarray
    dist: np.ndarray            # k1, k2, p1, p2, k3
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int] = (0, 0)

    @property
    def center(self) -> np.ndarray:
        """Camera position, m, world."""
        return -self.R.T @ self.t

    def rotated(self, axis: np.ndarray, degrees: float) -> "Camera":
        """The same camera turned by ``degrees`` about ``axis`` (camera frame), centre kept."""
        a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
        th = np.radians(degrees)
        k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        turn = np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * (k @ k)
        R = turn @ self.R
        return Camera(self.name, self.K, self.dist, R, -R @ self.center, self.size)


# ----- reading calibrations -------------------------------------------------------------------
def read_qca(path: str | Path) -> list[Camera]:
    """Cameras of a Qualisys ``.qca.txt`` calibration (see the module note for the units)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as e:
        raise CalibrationError(path, f"not a QTM calibration ({e})") from None
    cams = []
    for c in root.iter("camera"):
        name = c.get("serial") or f"camera{len(cams) + 1}"
        try:
            tr, it, fov = c.find("transform").attrib, c.find("intrinsic").attrib, c.find("fov_video").attrib
            r = np.array([[float(tr[f"r{a}{b}"]) for b in "123"] for a in "123"])
            pos = np.array([float(tr[k]) for k in "xyz"]) / 1000.0
            left, top = float(fov["left"]), float(fov["top"])
            size = (int(fov["right"]) - int(left) + 1, int(fov["bottom"]) - int(top) + 1)
            K = np.array([[float(it["focalLengthU"]) / QTM_SUBPIXELS, 0.0, float(it["centerPointU"]) / QTM_SUBPIXELS - left],
                          [0.0, float(it["focalLengthV"]) / QTM_SUBPIXELS, float(it["centerPointV"]) / QTM_SUBPIXELS - top],
                          [0.0, 0.0, 1.0]])
            dist = np.array([float(it.get(k, 0.0)) for k in ("radialDistortion1", "radialDistortion2",
                             "tangentalDistortion1", "tangentalDistortion2", "radialDistortion3")])
        except (AttributeError, KeyError, ValueError) as e:
            raise CalibrationError(path, f"camera {name}: incomplete transform/intrinsic/fov_video ({e})") from None
        R = _QTM_AXES @ r
        cams.append(Camera(name, K, dist, R, -R @ pos, size))
    if not cams:
        raise CalibrationError(path, "no <camera> in the calibration")
    return cams


def _rodrigues(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    th = np.linalg.norm(v)
    if th < 1e-12:
        return np.eye(3)
    a = v / th
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * (k @ k)


def read_opencv_calibration(path: str | Path) -> list[Camera]:
    """Cameras of an OpenCV-style TOML / YAML calibration (see the module note for the layout)."""
    path = Path(path)
    try:
        text = path.read_text()
        if path.suffix.lower() == ".toml":
            import tomllib
            data = tomllib.loads(text)
        else:
            import yaml
            data = yaml.safe_load(text)
    except Exception as e:  # noqa: BLE001 - any parser fault is this file's fault, in one line
        raise CalibrationError(path, f"cannot be parsed ({type(e).__name__}: {e})") from None
    if isinstance(data, dict) and isinstance(data.get("cameras"), dict):
        data = data["cameras"]
    cams = []
    for key, d in (data or {}).items():
        if not isinstance(d, dict) or "matrix" not in d:
            continue                                  # e.g. Pose2Sim's [metadata] table
        try:
            dist = np.zeros(5)
            given = np.asarray(d.get("distortions", []), dtype=np.float64).ravel()[:5]
            dist[:len(given)] = given
            R = _rodrigues(np.asarray(d["rotation"], dtype=np.float64)) if np.size(d["rotation"]) == 3 \
                else np.asarray(d["rotation"], dtype=np.float64).reshape(3, 3)
            size = tuple(int(round(float(x))) for x in d.get("size", (0, 0)))
            cams.append(Camera(str(d.get("name", key)), np.asarray(d["matrix"], dtype=np.float64).reshape(3, 3), dist,
                               R, np.asarray(d["translation"], dtype=np.float64).reshape(3), size))
        except (KeyError, ValueError, TypeError) as e:
            raise CalibrationError(path, f"camera {key}: {type(e).__name__}: {e}") from None
    if not cams:
        raise CalibrationError(path, "no camera table (name, size, matrix, distortions, rotation, translation)")
    return cams


def read_calibration(path: str | Path) -> list[Camera]:
    """Cameras of a ``.qca.txt`` / ``.qca`` (QTM) or ``.toml`` / ``.yaml`` (OpenCV-style) file."""
    p = Path(path)
    if not p.is_file():
        raise CalibrationError(p, "no such calibration file")
    if p.name.lower().endswith((".qca.txt", ".qca", ".xml")):
        return read_qca(p)
    return read_opencv_calibration(p)


def match_cameras(cameras: list[Camera], names: list[str], *, path: str | Path | None = None) -> list[Camera]:
    """The calibration's camera for each name (a video's stem), in the names' order; CalibrationError
    naming the videos the calibration lacks and the cameras it has."""
    by = {c.name: c for c in cameras}
    by_low = {c.name.lower().replace("_", ""): c for c in cameras}
    out, lost = [], []
    for n in names:
        c = by.get(n) or by_low.get(n.lower().replace("_", ""))
        (out if c is not None else lost).append(c if c is not None else n)
    if lost:
        raise CalibrationError(path, f"no camera for {', '.join(lost)} "
                                     f"(its cameras: {', '.join(sorted(by))})")
    return out


# ----- projection and distortion --------------------------------------------------------------
def distort(cam: Camera, xn: np.ndarray) -> np.ndarray:
    """Normalised undistorted coordinates [..., 2] -> pixels [..., 2] (OpenCV's model)."""
    k1, k2, p1, p2, k3 = cam.dist
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = cam.K
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)


def undistort(cam: Camera, uv: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Pixels [..., 2] -> normalised undistorted coordinates [..., 2] (fixed-point inversion of
    :func:`distort`, as OpenCV's undistortPoints)."""
    K = cam.K
    yd = (uv[..., 1] - K[1, 2]) / K[1, 1]
    xd = (uv[..., 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    k1, k2, p1, p2, k3 = cam.dist
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    return np.stack([x, y], axis=-1)


def project(cam: Camera, X: np.ndarray) -> np.ndarray:
    """World points [..., 3] m -> pixels [..., 2] with distortion (NaN behind the camera)."""
    Xc = X @ cam.R.T + cam.t
    z = np.where(Xc[..., 2] > 1e-9, Xc[..., 2], np.nan)
    return distort(cam, Xc[..., :2] / z[..., None])


# ----- triangulation ----------------------------------------------------------------------------
@dataclass
class Triangulation:
    """One frame (or a batch) of triangulated points.

    points: [..., J, 3] m (NaN: missing); error_px: [..., C, J] each camera's reprojection error
    (NaN where the camera saw nothing); used: bool [..., C, J] cameras kept; quality: int8 [..., J].
    """

    points: np.ndarray
    error_px: np.ndarray
    used: np.ndarray
    quality: np.ndarray
    notes: list[str] = field(default_factory=list)


def _dlt(xn: np.ndarray, w: np.ndarray, Rt: np.ndarray) -> np.ndarray:
    """Weighted DLT: xn [C, ..., 2] normalised coords, w [C, ...] weights (0: unused), Rt [C, 3, 4]
    -> points [..., 3] (NaN with fewer than two weighted cameras)."""
    x = np.nan_to_num(xn)
    P = Rt.reshape(Rt.shape[:1] + (1,) * (x.ndim - 2) + (3, 4))           # [C, 1.., 3, 4]
    rows_u = x[..., 0:1] * P[..., 2, :] - P[..., 0, :]                    # [C, ..., 4]
    rows_v = x[..., 1:2] * P[..., 2, :] - P[..., 1, :]
    A = np.concatenate([rows_u * w[..., None], rows_v * w[..., None]], axis=0)   # [2C, ..., 4]
    _, _, vt = np.linalg.svd(np.moveaxis(A, 0, -2))                      # [..., 2C, 4]
    h = vt[..., -1, :]
    with np.errstate(all="ignore"):
        X = h[..., :3] / h[..., 3:4]
    X[(w > 0).sum(axis=0) < 2] = np.nan
    return X


def _project_all(cameras: list[Camera], X: np.ndarray) -> np.ndarray:
    """Pixels [C, ..., 2] of points X [..., 3] in every camera (NaN behind a camera)."""
    R = np.stack([c.R for c in cameras])
    t = np.stack([c.t for c in cameras])
    K = np.stack([c.K for c in cameras])
    k1, k2, p1, p2, k3 = np.stack([c.dist for c in cameras]).T.reshape(5, -1, *([1] * (X.ndim - 1)))
    Xc = np.einsum("cij,...j->c...i", R, X) + t.reshape(t.shape[:1] + (1,) * (X.ndim - 1) + (3,))
    z = np.where(Xc[..., 2] > 1e-9, Xc[..., 2], np.nan)
    x, y = Xc[..., 0] / z, Xc[..., 1] / z
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    sh = (-1,) + (1,) * (X.ndim - 1)
    return np.stack([K[:, 0, 0].reshape(sh) * xd + K[:, 0, 1].reshape(sh) * yd + K[:, 0, 2].reshape(sh),
                     K[:, 1, 1].reshape(sh) * yd + K[:, 1, 2].reshape(sh)], axis=-1)


def reprojection_errors(cameras: list[Camera], X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """[C, N] pixel distance between each camera's detection uv [C, N, 2] and the projection of X [N, 3]."""
    return np.linalg.norm(_project_all(cameras, X) - uv, axis=-1)


def triangulate(cameras: list[Camera], uv: np.ndarray, conf: np.ndarray, *, min_conf: float = 0.5,
                reject_px: float = 50.0, good_px: float = 30.0, good_cameras: int = 3) -> Triangulation:
    """Triangulate detections uv [C, N, 2] px (NaN: not seen) with confidences conf [C, N] in [0, 1].

    Consensus, all N points and all camera pairs at once: every pair of cameras is triangulated
    (DLT) and each camera whose reprojection error to that point is within ``reject_px`` agrees
    with the pair; the pair with most agreeing cameras (then the most confident ones) wins, and the
    point is solved again from its agreeing cameras, weighted by confidence. A camera whose ray
    disagrees is thus dropped for that point. Quality per point: good with >= ``good_cameras``
    agreeing cameras all within ``good_px``, estimated with two agreeing, else missing.
    """
    C = len(cameras)
    uv = np.asarray(uv, dtype=np.float64)
    conf = np.nan_to_num(np.asarray(conf, dtype=np.float64))
    N = uv.shape[1]
    seen = np.isfinite(uv).all(-1) & (conf >= min_conf)                  # [C, N]
    xn = np.stack([undistort(c, uv[k]) for k, c in enumerate(cameras)])  # [C, N, 2]
    Rt = np.stack([np.hstack([c.R, c.t[:, None]]) for c in cameras])     # [C, 3, 4]
    a, b = np.triu_indices(C, 1)                                         # camera pairs [Q]
    w = np.zeros((C, len(a), N))
    w[a, np.arange(len(a))] = seen[a]
    w[b, np.arange(len(a))] = seen[b]
    Xq = _dlt(np.broadcast_to(xn[:, None], (C, len(a), N, 2)), w, Rt)   # [Q, N, 3]
    err_q = np.linalg.norm(_project_all(cameras, Xq) - uv[:, None], axis=-1)   # [C, Q, N]
    with np.errstate(invalid="ignore"):
        agree = seen[:, None] & (err_q <= reject_px)
    n = agree.sum(axis=0)                                                # [Q, N]
    score = n * 1e3 + np.where(agree, conf[:, None], 0.0).sum(axis=0) \
        - 1e-3 * np.where(agree, err_q, 0.0).sum(axis=0)
    score = np.where(n >= 2, score, -np.inf)
    best = np.argmax(score, axis=0)                                      # [N]
    used = agree[:, best, np.arange(N)] & np.isfinite(score[best, np.arange(N)])   # [C, N]
    X = _dlt(xn, np.where(used, np.maximum(conf, 1e-3), 0.0), Rt)
    err = np.where(seen, reprojection_errors(cameras, X, uv), np.nan)
    kept_err = np.where(used, err, -np.inf).max(axis=0)
    n_used = used.sum(axis=0)
    q = np.where((n_used >= min(good_cameras, C)) & (kept_err <= good_px), QUALITY_GOOD,
                 np.where((n_used >= 2) & (kept_err <= reject_px), QUALITY_ESTIMATED, QUALITY_MISSING)).astype(np.int8)
    X[q == QUALITY_MISSING] = np.nan
    return Triangulation(X, err, used, q)


def triangulate_frames(cameras: list[Camera], uv: np.ndarray, conf: np.ndarray, **kw) -> Triangulation:
    """Triangulate a clip: uv [C, T, J, 2], conf [C, T, J] -> points [T, J, 3], error_px [C, T, J],
    used [C, T, J], quality [T, J] (every frame's joints in one batch)."""
    C, T, J = conf.shape
    r = triangulate(cameras, uv.reshape(C, T * J, 2), conf.reshape(C, T * J), **kw)
    return Triangulation(r.points.reshape(T, J, 3), r.error_px.reshape(C, T, J), r.used.reshape(C, T, J),
                         r.quality.reshape(T, J))


def camera_report(cameras: list[Camera], tri: Triangulation, *, factor: float = 2.0) -> list[str]:
    """One line per camera whose median reprojection error is over ``factor`` times the median of
    the others' (a camera with a wrong calibration): empty if they all agree."""
    med = np.array([np.nanmedian(tri.error_px[k]) if np.isfinite(tri.error_px[k]).any() else np.nan
                    for k in range(len(cameras))])
    return off_cameras([c.name for c in cameras], med, factor=factor)


def off_cameras(names: list[str], med: np.ndarray, *, factor: float = 2.0) -> list[str]:
    """:func:`camera_report`'s lines from each camera's median reprojection error ``med`` [C] px."""
    lines = []
    for k, name in enumerate(names):
        rest = np.delete(med, k)
        if not np.isfinite(rest).any():
            continue
        others = np.nanmedian(rest)
        if np.isfinite(med[k]) and med[k] > factor * others:
            lines.append(f"camera {name}: median reprojection error {med[k]:.1f} px, the others "
                         f"{others:.1f} px: check its calibration")
    return lines
