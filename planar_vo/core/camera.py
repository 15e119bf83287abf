"""Camera model: pinhole intrinsics with ROS ``plumb_bob``, ``rational_polynomial`` or
``equidistant`` distortion.

Everything is expressed as point maps with analytic Jacobians, so that affine correspondences can
be moved between pixel, distorted and ideal normalised coordinates by the chain rule
(`planar_vo.core.correspondences.AffineCorrespondences.transformed`). For an undistorted pinhole
camera `normalize_points` and `normalize_affines` do the same directly from ``K``.

Models (ROS ``sensor_msgs/CameraInfo`` names and coefficient order):

- ``plumb_bob`` ``D = [k1, k2, p1, p2, k3]`` (Brown-Conrady): with ``r2 = x^2 + y^2``,
  ``x_d = x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)`` and likewise for y.
- ``rational_polynomial`` ``D = [k1, k2, p1, p2, k3, k4, k5, k6]`` (OpenCV's rational model):
  as ``plumb_bob`` with the radial factor ``(1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5
  r2^2 + k6 r2^3)``.
- ``equidistant`` ``D = [k1, k2, k3, k4]`` (Kannala-Brandt fisheye): ``theta = atan(r)``,
  ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
  ``x_d = (theta_d / r) x``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planar_vo.core.checks import as_array
from planar_vo.errors import CameraModelError, one_line

__all__ = [
    'DISTORTION_MODELS',
    'CameraModel',
    'field_of_view_for_focal',
    'fits_distortion_model',
    'focal_for_field_of_view',
    'intrinsic_matrix',
    'normalize_affines',
    'normalize_points',
]

DISTORTION_MODELS = {'none': 0, 'plumb_bob': 5, 'rational_polynomial': 8, 'equidistant': 4}

# Plausible fields of view of real lenses, for `CameraModel.check_plausible` (degrees, across
# the image's width or height). The narrowest: a 3-degree view is a 700 mm lens on a full-frame
# sensor (a 100x wrong focal length turns a 60-degree camera into one of 0.6 degrees); nothing
# narrower is mounted on a vehicle, and no image of such a lens holds the road that planar
# odometry needs. The widest: a rectilinear (pinhole, plumb_bob, rational_polynomial) lens
# cannot reach 180 degrees, and the widest ones built cover about 130 (160 leaves room for
# calibrations of fisheye lenses with plumb_bob or the rational model); the widest fisheye lenses
# built cover about 220-280 degrees.
MIN_FIELD_OF_VIEW_DEG = 3.0
MAX_FIELD_OF_VIEW_DEG = {'none': 160.0, 'plumb_bob': 160.0, 'rational_polynomial': 160.0,
                         'equidistant': 280.0}
_UNDISTORT_ITERATIONS = 20
# The largest plausible skew, as a share of fx (a pixel shear of 5.7 degrees; real cameras: 0).
_MAX_SKEW = 0.1
# Points along each grid pixel's undistorted ray at which the distortion must be one-to-one
# (`CameraModel.check_plausible`).
_FOLD_SAMPLES = 24


def focal_for_field_of_view(width: float, fov: float, distortion_model: str = 'none') -> float:
    """The focal length (pixels) that spreads a horizontal field of view of ``fov`` radians over
    ``width`` pixels, centred: ``width / (2 tan(fov / 2))`` through a rectilinear lens (every
    model but the fisheye), ``width / fov`` through an equidistant (fisheye) one, whose image
    radius is ``f theta`` (the inverse of `CameraModel.field_of_view`)."""
    if distortion_model == 'equidistant':
        return width / fov
    return 0.5 * width / math.tan(0.5 * fov)


def field_of_view_for_focal(width: float, focal: float, distortion_model: str = 'none'
                            ) -> float:
    """The inverse of `focal_for_field_of_view`: the horizontal field of view (radians) of
    ``focal`` pixels over ``width`` pixels, centred."""
    if distortion_model == 'equidistant':
        return width / focal
    return 2.0 * math.atan(0.5 * width / focal)


def _inverse_2x2(J: np.ndarray) -> np.ndarray:
    """Inverses of ``(N, 2, 2)`` matrices by the adjugate, non-finite where one is singular
    (instead of `numpy.linalg.LinAlgError` for the whole batch)."""
    a, b, c, d = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
    det = a * d - b * c
    return np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], 1) / det[:, None, None]


def fits_distortion_model(model: str, D) -> bool:
    """Whether the coefficients ``D`` suit the distortion model (`DISTORTION_MODELS`): their
    count, 4 also for ``plumb_bob`` (k3 = 0), more when the extra ones are zero for
    ``plumb_bob`` and ``rational_polynomial`` (drivers publish the 8 or 14 entries of OpenCV's
    larger models), and any all-zero list for ``none``."""
    n = DISTORTION_MODELS[model]
    padded = model in ('plumb_bob', 'rational_polynomial') and len(D) > n and not any(D[n:])
    return (len(D) == n or (model == 'plumb_bob' and len(D) == 4) or padded
            or (n == 0 and not any(D)))


@dataclass(frozen=True)
class CameraModel:
    """A calibrated camera.

    Attributes:
        width, height: image size in pixels.
        K: intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (3x3).
        distortion_model: one of `DISTORTION_MODELS` (``'none'``, ``'plumb_bob'``,
            ``'rational_polynomial'``, ``'equidistant'``).
        D: distortion coefficients in ROS order (empty for ``'none'``).
    """

    width: int
    height: int
    K: np.ndarray
    distortion_model: str = 'none'
    D: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        K = _check_K(self.K)
        if isinstance(self.width, bool) or isinstance(self.height, bool) or not (
                int(self.width) == self.width and int(self.height) == self.height
                and self.width > 0 and self.height > 0):
            # (a user test: a width of True was taken as 1)
            raise CameraModelError(f'image size: expected positive integers, got '
                                   f'{self.width}x{self.height}')
        if self.distortion_model not in DISTORTION_MODELS:
            raise CameraModelError(f"distortion_model: expected one of {list(DISTORTION_MODELS)}, "
                                   f"got '{self.distortion_model}'")
        try:
            D = tuple(float(d) for d in self.D)
        except (TypeError, ValueError, OverflowError) as err:
            raise CameraModelError(f'D: expected real coefficients, got {type(self.D).__name__} '
                                   f'({err})') from err
        n = DISTORTION_MODELS[self.distortion_model]
        if not fits_distortion_model(self.distortion_model, D):
            padding = (' (more only if the extra ones are 0)' if self.distortion_model in
                       ('plumb_bob', 'rational_polynomial') and len(D) > n else '')
            raise CameraModelError(f"D: expected {n} coefficients for '{self.distortion_model}'"
                                   f'{padding}, got {len(D)}')
        if self.distortion_model == 'plumb_bob':
            D = (D + (0.0,) * (5 - len(D)))[:5]
        elif self.distortion_model == 'rational_polynomial':
            D = D[:8]
        if not np.all(np.isfinite(D)):
            raise CameraModelError(f'D: expected finite coefficients, got {list(D)}')
        K = K.copy()
        K.setflags(write=False)
        object.__setattr__(self, 'K', K)
        object.__setattr__(self, 'D', D if n else ())
        object.__setattr__(self, 'width', int(self.width))
        object.__setattr__(self, 'height', int(self.height))

    def __reduce__(self):
        # Rebuilt through the constructor: checked, and K read-only again (a user test: a
        # pickled and unpickled model's K was writable).
        return type(self), (self.width, self.height, self.K, self.distortion_model, self.D)

    # -- construction ------------------------------------------------------------------------

    @classmethod
    def pinhole(cls, width: int, height: int, fx: float, fy: float | None = None,
                cx: float | None = None, cy: float | None = None) -> CameraModel:
        """An undistorted camera; the principal point defaults to the image centre."""
        fy = fx if fy is None else fy
        try:
            cx = (width - 1) / 2.0 if cx is None else cx
            cy = (height - 1) / 2.0 if cy is None else cy
            K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)
        except (TypeError, ValueError, OverflowError) as err:
            raise CameraModelError(f'pinhole: expected real numbers for the size and '
                                   f'intrinsics, got one that is not or is too large for float64 '
                                   f'({err})') from err
        return cls(width, height, K)

    @classmethod
    def from_camera_info(cls, msg: Any, *, rectified: bool = False) -> CameraModel:
        """From a ``sensor_msgs/CameraInfo`` (rclpy or rosbags message; duck-typed).

        ``rectified``: the images are rectified (``image_rect``): the model is ``P``'s left 3x3
        (fx', fy', cx', cy') without distortion, as ``image_geometry`` projects rectified
        images; otherwise ``K`` and ``D`` (raw images).

        The models of `DISTORTION_MODELS` are read (``plumb_bob``, ``rational_polynomial``,
        ``equidistant``; a coefficient list padded with zeros as the shorter model, all zeros
        and an empty model with all-zero ``d`` as ``'none'``); other models are rejected with
        `CameraModelError`, and so are implausible intrinsics (`check_plausible`).

        Binning and region of interest (REP-104): ``width``, ``height`` and ``K`` describe the
        full-resolution sensor, the images are its ``roi`` (0 width: all of it) binned by
        ``binning_x``, ``binning_y`` (0 or 1: none). The model is that of the images, as
        ``image_geometry`` computes it: ``fx / binning_x``, ``(cx - roi.x_offset) /
        binning_x`` (likewise in y), the ROI's size over the binning; the distortion, defined
        on normalised coordinates, is unchanged.
        """
        try:
            k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
            d = tuple(float(v) for v in msg.d)
            model = str(msg.distortion_model or '').strip()
            if rectified:
                k = np.asarray(msg.p, dtype=np.float64).reshape(3, 4)[:, :3].copy()
                d, model = (), ''
            width, height = int(msg.width), int(msg.height)
            bx, by = (max(int(getattr(msg, f'binning_{a}', 0) or 0), 1) for a in 'xy')
            roi = getattr(msg, 'roi', None)
            x0, y0, roi_w, roi_h = ((int(roi.x_offset), int(roi.y_offset), int(roi.width),
                                     int(roi.height)) if roi is not None else (0, 0, 0, 0))
        except (AttributeError, TypeError, ValueError) as err:
            raise CameraModelError(f'camera_info: not a CameraInfo message ({err})') from err
        if not np.any(k):
            if rectified:
                raise CameraModelError('camera_info: P is all zeros, and camera.rectified uses '
                                       "it (a raw camera's CameraInfo: set camera.rectified "
                                       'false)')
            raise CameraModelError('camera_info: K is all zeros (uncalibrated camera); set the '
                                   'camera.fx/fy/cx/cy parameters or enable camera.estimate_focal')
        if roi_w == 0 or roi_h == 0:                      # REP-104: the full image
            x0, y0, roi_w, roi_h = 0, 0, width, height
        if min(x0, y0) < 0 or x0 + roi_w > width or y0 + roi_h > height:
            raise CameraModelError(f'camera_info: region of interest {roi_w}x{roi_h} at ({x0}, '
                                   f'{y0}) does not fit the {width}x{height} sensor')
        if (bx, by, x0, y0, roi_w, roi_h) != (1, 1, 0, 0, width, height):
            k = np.diag([1.0 / bx, 1.0 / by, 1.0]) @ (k - np.array([[0.0, 0.0, x0],
                                                                    [0.0, 0.0, y0],
                                                                    [0.0, 0.0, 0.0]]) * k[2, 2])
            width, height = roi_w // bx, roi_h // by
        if model == '' or (model in ('plumb_bob', 'rational_polynomial') and not any(d)):
            if any(d):
                raise CameraModelError(f'camera_info: distortion coefficients {list(d)} given '
                                       f'without a distortion model')
            model, d = 'none', ()
        camera = cls(width, height, k, model, d)
        try:
            camera.check_plausible()
        except CameraModelError as err:
            raise CameraModelError(f'camera_info: {err}') from None
        return camera

    def check_plausible(self) -> None:
        """`CameraModelError` unless the intrinsics describe a real lens: the principal point
        inside the image, fields of view (`field_of_view`) between `MIN_FIELD_OF_VIEW_DEG`
        and the model's `MAX_FIELD_OF_VIEW_DEG` (a focal length off by a large factor, a
        principal point given for another resolution), a skew of at most a tenth of fx and a
        distortion that can be inverted over most of the image."""
        if not (0.0 <= self.cx <= self.width and 0.0 <= self.cy <= self.height):
            raise CameraModelError(f'principal point ({self.cx:g}, {self.cy:g}) '
                                   f'lies outside the {self.width}x{self.height} image')
        widest = MAX_FIELD_OF_VIEW_DEG[self.distortion_model]
        kind = 'fisheye' if self.distortion_model == 'equidistant' else 'rectilinear'
        for axis, fov in zip(('horizontal', 'vertical'), np.degrees(self.field_of_view)):
            if not MIN_FIELD_OF_VIEW_DEG <= fov <= widest:
                raise CameraModelError(
                    f'{axis} field of view {fov:.3g} deg (fx {self.fx:g}, fy '
                    f'{self.fy:g} px on {self.width}x{self.height}) is outside the '
                    f'{MIN_FIELD_OF_VIEW_DEG:g}-{widest:g} deg of real {kind} lenses: is the '
                    f'focal length in pixels of this resolution?')
        skew = float(self.K[0, 1])
        if abs(skew) > _MAX_SKEW * self.fx:
            raise CameraModelError(f'skew {skew:.6g} is more than {_MAX_SKEW:g} fx '
                                   f'(fx {self.fx:g}): real pixels are not sheared that much')
        if self.is_distorted:
            # The distortion must be invertible over the image: Newton's undistortion converges
            # at most pixels of a 9x9 grid (a real wide-angle calibration may fail in the far
            # corners; absurd coefficients fail everywhere, and every frame would be lost).
            grid = np.stack(np.meshgrid(np.linspace(0.0, self.width - 1.0, 9),
                                        np.linspace(0.0, self.height - 1.0, 9)), -1)
            grid = grid.reshape(-1, 2)
            if self.distortion_model == 'equidistant':
                # A fisheye's rays more than 90 deg off its axis have no pinhole coordinates
                # (planar_vo works in them; their ACs are dropped): only the pixels of rays
                # within 90 deg must invert (a review: every lens over 185 deg was refused).
                xd, _ = self._pixel_to_distorted(grid)
                k1, k2, k3, k4 = self.D
                t2 = (math.pi / 2.0) ** 2
                edge = math.pi / 2.0 * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
                grid = grid[np.hypot(xd[:, 0], xd[:, 1]) < edge]
            with np.errstate(all='ignore'):
                q, _ = self.pixel_to_normalized(grid)
                ok = np.isfinite(q).all(axis=1)
                # ... on the lens's own branch: the distortion one-to-one (its Jacobian's
                # determinant positive) all the way from the centre to the undistorted point,
                # not a root beyond a fold (a user test: D = [1e6, -1e6, 0, 0, 1e6] passed, and
                # its frames ran on unit steps with a std of 5 km).
                t = np.linspace(1.0 / _FOLD_SAMPLES, 1.0, _FOLD_SAMPLES)
                ray = (t[:, None, None] * np.where(ok[:, None], q, 0.0)[None]).reshape(-1, 2)
                _, J = self.distort(ray)
                det = (J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]).reshape(t.size, -1)
                ok &= np.all(det > 0.0, axis=0)
            inverted = int(np.count_nonzero(ok))
            if inverted < 0.75 * len(grid) or not len(grid):
                raise CameraModelError(
                    f'the {self.distortion_model} distortion {list(self.D)} cannot '
                    f'be inverted over the image ({len(grid) - inverted} of {len(grid)} grid '
                    f'pixels have no undistorted position on the lens\'s one-to-one part)')
            # ... and the field of view it leaves a real one too (a user test: D = [1e6, -1e6,
            # 0, 0, 1e6] is one-to-one and squeezes the image into 1 deg).
            edges = np.array([[0.0, self.cy], [self.width - 1.0, self.cy],
                              [self.cx, 0.0], [self.cx, self.height - 1.0]])
            with np.errstate(all='ignore'):
                q, _ = self.pixel_to_normalized(edges)
            # (a fisheye's ray beyond 90 deg has no pinhole coordinates: 90 deg at least)
            angle = np.where(np.isfinite(q).all(axis=1), np.arctan(np.hypot(*q.T)),
                             np.pi / 2.0 if self.distortion_model == 'equidistant' else np.nan)
            for axis, pair in (('horizontal', angle[:2]), ('vertical', angle[2:])):
                fov = float(np.degrees(np.sum(pair)))
                if np.all(np.isfinite(pair)) and not MIN_FIELD_OF_VIEW_DEG <= fov <= widest:
                    raise CameraModelError(
                        f'the {self.distortion_model} distortion {list(self.D)} leaves a '
                        f'{axis} field of view of {fov:.3g} deg, outside the '
                        f'{MIN_FIELD_OF_VIEW_DEG:g}-{widest:g} deg of real {kind} lenses')

    # -- properties --------------------------------------------------------------------------

    @property
    def field_of_view(self) -> tuple[float, float]:
        """Horizontal and vertical field of view (radians) through the principal point, from
        the focal lengths (pinhole: ``atan``; equidistant: the angle is ``r / f``), without the
        distortion's higher-order terms."""
        angles = []
        for size, c, f in ((self.width, self.cx, self.fx), (self.height, self.cy, self.fy)):
            extents = np.array([c, size - c]) / f
            angles.append(float(np.sum(extents if self.distortion_model == 'equidistant'
                                       else np.arctan(extents))))
        return angles[0], angles[1]

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def is_distorted(self) -> bool:
        """The model maps rays other than a pinhole: any non-zero coefficient, and
        ``equidistant`` always (all zeros is the ideal fisheye, ``theta_d = theta``; a user
        test: it was taken for a pinhole)."""
        return self.distortion_model == 'equidistant' or (
            self.distortion_model != 'none' and any(self.D))

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``."""
        return self.width, self.height

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraModel):
            return NotImplemented
        return (self.size == other.size and np.array_equal(self.K, other.K)
                and self.distortion_model == other.distortion_model and self.D == other.D)

    def __hash__(self) -> int:
        return hash((self.size, self.K.tobytes(), self.distortion_model, self.D))

    def pixel_shift(self, other: CameraModel) -> float:
        """How far ``other`` moves the image (pixels): the largest distance, over a 5x5 grid of
        pixels spanning the image, between a pixel and where ``other`` images the same ray.
        Infinite for another image size or a ray ``other`` cannot image."""
        if other.size != self.size:
            return math.inf
        u, v = np.meshgrid(np.linspace(0.0, self.width - 1.0, 5),
                           np.linspace(0.0, self.height - 1.0, 5))
        grid = np.column_stack([u.ravel(), v.ravel()])
        moved, _ = other.normalized_to_pixel(self.pixel_to_normalized(grid)[0])
        shift = np.linalg.norm(moved - grid, axis=1)
        return float(shift.max()) if np.isfinite(shift).all() else math.inf

    # -- distortion of normalised coordinates ------------------------------------------------

    def distort(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal normalised ``(N, 2)`` -> distorted normalised, with the Jacobian ``(N, 2, 2)``."""
        x = np.asarray(x, dtype=np.float64)
        n = x.shape[0]
        if not self.is_distorted:
            return x.copy(), np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
        if self.distortion_model == 'plumb_bob':
            return _distort_plumb_bob(x, self.D)
        if self.distortion_model == 'rational_polynomial':
            return _distort_rational(x, self.D)
        return _distort_equidistant(x, self.D)

    def undistort(self, xd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalised ``(N, 2)`` -> ideal normalised, with the Jacobian ``(N, 2, 2)``.

        Newton's method on `distort` (vectorised); the Jacobian is the inverse of the distortion
        Jacobian at the solution. Points where the iteration does not converge (far outside the
        calibrated field of view, or where the distortion folds over: a singular Jacobian) are
        NaN, each on its own (a review: one singular point of a batch raised for all of them).
        """
        xd = np.asarray(xd, dtype=np.float64)
        if not self.is_distorted:
            return xd.copy(), np.broadcast_to(np.eye(2), (xd.shape[0], 2, 2)).copy()
        x = xd.copy()
        with np.errstate(all='ignore'):
            for _ in range(_UNDISTORT_ITERATIONS):
                f, J = self.distort(x)
                x = x - (_inverse_2x2(J) @ (f - xd)[..., None])[..., 0]
            f, J = self.distort(x)
            good = np.linalg.norm(f - xd, axis=1) <= 1e-9 * (1.0 + np.linalg.norm(xd, axis=1))
            J_inv = _inverse_2x2(J)
        bad = ~(good & np.isfinite(J_inv).all(axis=(1, 2)))
        x[bad] = np.nan
        J_inv[bad] = np.nan
        return x, J_inv

    # -- pixels ------------------------------------------------------------------------------

    def pixel_to_normalized(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``(N, 2)`` -> ideal normalised coordinates, with the Jacobian ``dq/dp``.

        A non-finite pixel, or one the distortion cannot be inverted at, gives NaN in its row
        (not an error: `AffineCorrespondences.transformed` drops such items, the others go on).
        """
        p = as_array('p', p, (None, 2), min_items=0, finite=False)
        xd, L_inv = self._pixel_to_distorted(p)
        if not self.is_distorted:
            return xd, np.broadcast_to(L_inv, (xd.shape[0], 2, 2)).copy()
        q, Ju = self.undistort(xd)
        return q, Ju @ L_inv

    def normalizing_map(self):
        """`pixel_to_normalized` as a map for `AffineCorrespondences.transformed`; without
        distortion the same numbers with the one ``(2, 2)`` Jacobian of the linear map instead
        of an ``(N, 2, 2)`` copy of it."""
        if self.is_distorted:
            return self.pixel_to_normalized
        return lambda p: self._pixel_to_distorted(np.asarray(p, dtype=np.float64))

    def _pixel_to_distorted(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels -> distorted normalised coordinates ``K^-1 p`` and the 2x2 ``L^-1``."""
        L_inv = np.linalg.inv(self.K[:2, :2])
        return (p - self.K[:2, 2]) @ L_inv.T, L_inv

    def normalized_to_pixel(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal normalised ``(N, 2)`` -> pixels, with the Jacobian ``dp/dq``."""
        q = as_array('q', q, (None, 2), min_items=0, finite=False)
        xd, Jd = self.distort(q)
        L = self.K[:2, :2]
        return xd @ L.T + self.K[:2, 2], L @ Jd


# --------------------------------------------------------------------------------------------
# Pinhole normalisation (no distortion)
# --------------------------------------------------------------------------------------------

def intrinsic_matrix(fx: float, fy: float | None = None, cx: float = 0.0, cy: float = 0.0
                     ) -> np.ndarray:
    """The 3x3 upper-triangular intrinsics ``C`` (no skew); ``fy`` defaults to ``fx``."""
    fy = fx if fy is None else fy
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise CameraModelError(f'intrinsics: expected finite fx > 0 and fy > 0, got fx={fx}, '
                               f'fy={fy}, cx={cx}, cy={cy}')
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _check_K(K) -> np.ndarray:
    """``K`` as a finite upper-triangular 3x3 intrinsic matrix, or `CameraModelError`."""
    try:
        arr = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):     # OverflowError: a Python 10**400
        arr = np.zeros(0)
    if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
        # Lists, not numpy's repr (a user test: 'array([[ nan, 0. , ...').
        shown = arr.tolist() if arr.size else one_line(repr(K))
        raise CameraModelError(f'K: expected a finite 3x3 matrix, got {shown}')
    if arr[0, 0] <= 0 or arr[1, 1] <= 0 or arr[1, 0] != 0 or np.any(arr[2] != (0.0, 0.0, 1.0)):
        raise CameraModelError(f'K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy '
                               f'> 0, got {arr.tolist()}')
    return arr


def normalize_points(K: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Normalised coordinates ``q = C^-1 p`` of pixels ``p`` ``(N, 2)``; returns ``(N, 2)``."""
    K = _check_K(K)
    p = as_array('p', p, (None, 2), min_items=0)
    v = (p[:, 1] - K[1, 2]) / K[1, 1]
    u = (p[:, 0] - K[0, 2] - K[0, 1] * v) / K[0, 0]
    return np.stack([u, v], axis=-1)


def normalize_affines(K1: np.ndarray, K2: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Affines in normalised coordinates, ``A_n = L2^-1 A L1`` with ``L`` the 2x2 block of ``C``.

    For zero skew this is ``diag(1/fx2, 1/fy2) A diag(fx1, fy1)``.
    """
    K1, K2 = _check_K(K1), _check_K(K2)
    A = as_array('A', A, (None, 2, 2), min_items=0)
    return np.linalg.inv(K2[:2, :2]) @ A @ K1[:2, :2]


def _distort_plumb_bob(x: np.ndarray, D: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, p1, p2, k3 = D
    u, v = x[:, 0], x[:, 1]
    r2 = u * u + v * v
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)          # d radial / d r2
    return _brown_conrady(x, u, v, r2, radial, dradial, p1, p2)


def _distort_rational(x: np.ndarray, D: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, p1, p2, k3, k4, k5, k6 = D
    u, v = x[:, 0], x[:, 1]
    r2 = u * u + v * v
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    with np.errstate(divide='ignore', invalid='ignore'):
        radial = num / den
        dradial = (dnum * den - num * dden) / (den * den)    # d radial / d r2
    return _brown_conrady(x, u, v, r2, radial, dradial, p1, p2)


def _brown_conrady(x, u, v, r2, radial, dradial, p1, p2) -> tuple[np.ndarray, np.ndarray]:
    """The distorted points and Jacobian of a radial factor (``radial`` and its derivative
    with respect to ``r2``) and the tangential terms ``p1, p2``."""
    xd = u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u)
    yd = v * radial + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * u * v
    J = np.empty((x.shape[0], 2, 2))
    J[:, 0, 0] = radial + 2.0 * u * u * dradial + 2.0 * p1 * v + 6.0 * p2 * u
    J[:, 0, 1] = 2.0 * u * v * dradial + 2.0 * p1 * u + 2.0 * p2 * v
    J[:, 1, 0] = 2.0 * u * v * dradial + 2.0 * p1 * u + 2.0 * p2 * v
    J[:, 1, 1] = radial + 2.0 * v * v * dradial + 6.0 * p1 * v + 2.0 * p2 * u
    return np.stack([xd, yd], -1), J


def _distort_equidistant(x: np.ndarray, D: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, k3, k4 = D
    r = np.hypot(x[:, 0], x[:, 1])
    th = np.arctan(r)
    t2 = th * th
    poly = 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    th_d = th * poly
    dth_d = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    small = r < 1e-9
    rs = np.where(small, 1.0, r)
    scale = np.where(small, 1.0, th_d / rs)                  # x_d = scale(r) x
    # d scale / d r = (dth_d * dth/dr * r - th_d) / r^2, with dth/dr = 1 / (1 + r^2).
    dscale = np.where(small, 0.0, (dth_d / (1.0 + r * r) * rs - th_d) / (rs * rs))
    ur = np.where(small, 0.0, x[:, 0] / rs)
    vr = np.where(small, 0.0, x[:, 1] / rs)
    J = np.empty((x.shape[0], 2, 2))
    J[:, 0, 0] = scale + x[:, 0] * dscale * ur
    J[:, 0, 1] = x[:, 0] * dscale * vr
    J[:, 1, 0] = x[:, 1] * dscale * ur
    J[:, 1, 1] = scale + x[:, 1] * dscale * vr
    return x * scale[:, None], J
