"""Frame-to-frame odometry of the peer estimators on real frames, and the trajectory record
every method's run is kept in (`OdometryRun`), for the benchmarks on real drives.

`PeerOdometry` runs the five-point peers (`planar_vo.bench.peers`: OpenCV and PoseLib) on the
correspondences of consecutive frames, extracted once per pair and shared between the
estimators: the point parts of planar_vo's front-end ACs, the same front-end's ACs without its
per-frame budget, and DIS-flow points on that dense grid. A peer's motion is scaled by a given
step length (the benchmarks give the true one) and chained into camera poses
(`chain_camera_motions`). With ``focal``, PoseLib's shared-focal six-point runs on the dense
front-end points.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.conventions import se3
from planar_vo.errors import InputError

__all__ = [
    'FIVE_POINT',
    'PEER_GRID_STEP',
    'POSELIB_DEFAULTS',
    'SOURCES',
    'THRESHOLD_PX',
    'OdometryRun',
    'PeerOdometry',
    'chain_camera_motions',
]

THRESHOLD_PX = 1.0
# PoseLib's own RANSAC defaults (poselib.RansacOptions): success probability 0.9999, at least
# 1,000 and at most 100,000 iterations.
POSELIB_DEFAULTS = {'confidence': 0.9999, 'min_iters': 1000, 'max_iters': 100000}
# The peers' dense ACs and DIS points: one per 12-pixel cell with texture, however many there
# are (about 1,300 candidates on a KITTI frame; at KITTI size exactly the front-end's grid
# before it had a per-frame budget).
PEER_GRID_STEP = 12
_PEER_MAX_POINTS = 30000

FIVE_POINT = {
    'opencv': 'OpenCV five-point (findEssentialMat + recoverPose)',
    'poselib': 'PoseLib five-point LO-RANSAC + refinement, PoseLib defaults (>= 1000 iterations)',
    'poselib_early': 'PoseLib five-point LO-RANSAC + refinement, early stop (confidence 0.999, '
                     '<= 1000 iterations)',
}
SOURCES = {'frontend': 'front-end AC points',
           'dense': 'front-end AC points without its frame budget',
           'dis': 'DIS-flow grid points'}
TRUE_STEP = 'TRUE step length'
FOCAL_PEER = ('PoseLib shared-focal six-point (PoseLib defaults), front-end AC points without '
              'its frame budget')


@dataclass
class OdometryRun:
    """One method's camera trajectory over a drive.

    Attributes:
        label: what ran.
        scale: where the metric scale came from.
        stamps_ns: ``(N,)`` frame stamps (integer ns).
        poses: ``(N, 4, 4)`` ``T_world_camera`` (world = the first camera frame); a frame without
            odometry holds the previous pose.
        ok: ``(N,)`` whether the frame gave odometry (False for the first frame).
        seconds: per frame after the first, the whole processing time.
        estimator_seconds: per frame after the first, the estimator's part.
        extra: JSON-ready details (drop reasons, options).
    """

    label: str
    scale: str
    stamps_ns: np.ndarray
    poses: np.ndarray
    ok: np.ndarray
    seconds: np.ndarray
    estimator_seconds: np.ndarray
    extra: dict = field(default_factory=dict)

    def aligned(self, stamps_ns: np.ndarray, tolerance_ns: int = 1_000_000) -> OdometryRun:
        """The run on the frames ``stamps_ns`` (increasing), matched by the nearest stamp within
        ``tolerance_ns``; a frame the run did not see has no odometry (the pose is held)."""
        stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
        own = self.stamps_ns
        j = np.zeros(len(stamps_ns), dtype=np.int64)
        seen = np.zeros(len(stamps_ns), dtype=bool)
        if len(own):
            j = np.searchsorted(own, stamps_ns)
            lo, hi = np.clip(j - 1, 0, len(own) - 1), np.clip(j, 0, len(own) - 1)
            j = np.where(np.abs(own[lo] - stamps_ns) <= np.abs(own[hi] - stamps_ns), lo, hi)
            seen = np.abs(own[j] - stamps_ns) <= tolerance_ns
        poses = np.tile(np.eye(4), (len(stamps_ns), 1, 1))
        ok = np.zeros(len(stamps_ns), dtype=bool)
        last = np.eye(4)
        for k in range(len(stamps_ns)):
            if seen[k]:
                last = self.poses[j[k]]
                ok[k] = self.ok[j[k]]
            poses[k] = last
        return OdometryRun(self.label, self.scale, stamps_ns, poses, ok, self.seconds,
                           self.estimator_seconds, self.extra)


def chain_camera_motions(R: np.ndarray, t: np.ndarray, steps: np.ndarray, ok: np.ndarray
                         ) -> np.ndarray:
    """Camera poses from frame-to-frame motions.

    Args:
        R, t: ``(N, 3, 3)``, ``(N, 3)``: motion ``X2 = R X1 + t`` from frame ``k`` to ``k + 1``
            (unit ``t``; planar_vo's and PoseLib's convention).
        steps: ``(N,)`` step lengths (m): the camera centre moves by ``steps[k]``.
        ok: ``(N,)`` which motions exist; a missing one leaves the camera where it was (its
            motion is lost, as in frame-to-frame odometry).

    Returns:
        ``(N + 1, 4, 4)`` ``T_world_camera`` with world = the first camera frame:
        ``T(k + 1) = T(k) [R^T | -R^T t s]``.
    """
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    ok = np.asarray(ok, dtype=bool) & np.all(np.isfinite(t), axis=1) \
        & np.all(np.isfinite(R), axis=(1, 2))
    Rt = np.swapaxes(R, 1, 2)
    step = se3(Rt, -np.einsum('nij,nj->ni', Rt, t) * np.asarray(steps, float)[:, None])
    step[~ok] = np.eye(4)
    poses = np.empty((len(step) + 1, 4, 4))
    poses[0] = np.eye(4)
    for k in range(len(step)):
        poses[k + 1] = poses[k] @ step[k]
    return poses


class PeerOdometry:
    """Frame-to-frame odometry of the peer estimators, correspondences shared between them.

    Per consecutive frame pair, each source's correspondences are extracted once: ``'frontend'``
    (the point parts of planar_vo's front-end ACs, `ACExtractor` with the given front-end
    configuration), ``'dense'`` (the same front-end on a `PEER_GRID_STEP` grid without its
    per-frame budget) and ``'dis'`` (DIS 'fast' flow sampled at the dense grid's points,
    `planar_vo.frontend.flow.flow_candidates`: ``p2 = p1 + flow(p1)``); every five-point
    estimator of `FIVE_POINT` runs on them with a 1 px threshold; the motion is scaled by the
    step length given with the frame. With ``focal``, PoseLib's shared-focal six-point runs on
    the dense front-end points in pixels about the image centre (what an uncalibrated user
    assumes).

    Args:
        estimators: keys of `FIVE_POINT`.
        sources: keys of `SOURCES`.
        focal: also run the focal peer.
        config: the front-end configuration (`FrontendConfig`; default: the shipped one).
    """

    def __init__(self, estimators: Sequence[str] = tuple(FIVE_POINT),
                 sources: Sequence[str] = tuple(SOURCES), *, focal: bool = False,
                 config=None) -> None:
        from planar_vo.config import FrontendConfig
        from planar_vo.frontend import ACExtractor

        for kind, names, known in (('estimators', estimators, FIVE_POINT),
                                   ('sources', sources, SOURCES)):
            bad = [n for n in names if n not in known]
            if bad:
                raise InputError(f'{kind}: expected some of {list(known)}, got {bad}')
        self.estimators, self.sources, self.focal = tuple(estimators), tuple(sources), focal
        self.config = FrontendConfig() if config is None else config
        self._extractor = ACExtractor(self.config)
        # The 'dense' ACs and the DIS points: our grid without our per-frame budget (more
        # points help a five-point RANSAC; the peers are not held to a frame budget).
        self._dense = self.config.replace(grid_step=PEER_GRID_STEP,
                                          max_correspondences=_PEER_MAX_POINTS)
        self._dense_extractor = (ACExtractor(self._dense) if 'dense' in self.sources or focal
                                 else None)
        self._dis = None
        self._previous: np.ndarray | None = None
        self._frames = 0
        self._steps: list[float] = []
        keys = [f'{e}_{s}' for s in self.sources for e in self.estimators]
        self._motions: dict[str, list] = {k: [] for k in keys}      # (R, t, ok) per pair
        self._seconds: dict[str, list] = {k: [] for k in keys}      # (total, estimator)
        self.focal_px: list[float] = []
        self.focal_seconds: list[float] = []

    def add(self, image: np.ndarray | None, camera, step: float) -> None:
        """The next frame (8-bit grey, or None if undecodable), its camera model and the
        distance (m) the camera moved since the previous frame (ignored for the first)."""
        first = self._frames == 0
        self._frames += 1
        previous, self._previous = self._previous, image
        if first:
            return
        self._steps.append(float(step))
        usable = previous is not None and image is not None and camera is not None
        acs, acs_seconds = None, 0.0
        if usable and 'frontend' in self.sources:
            t0 = time.perf_counter()
            acs = self._extractor.extract(previous, image)
            acs_seconds = time.perf_counter() - t0
        dense, dense_seconds = None, 0.0
        if usable and ('dense' in self.sources or self.focal):
            t0 = time.perf_counter()
            dense = self._dense_extractor.extract(previous, image)
            dense_seconds = time.perf_counter() - t0
        for source in self.sources:
            t0 = time.perf_counter()
            given = dense if source == 'dense' else acs
            q = self._points(source, given, previous, image, camera) if usable else None
            seconds = time.perf_counter() - t0 + {'frontend': acs_seconds,
                                                  'dense': dense_seconds}.get(source, 0.0)
            for name in self.estimators:
                R, t, ok, est_seconds = self._five_point(name, q, camera)
                self._motions[f'{name}_{source}'].append((R, t, ok))
                self._seconds[f'{name}_{source}'].append((seconds + est_seconds, est_seconds))
        if self.focal:
            self._focal_pair(dense, image)

    def _points(self, source: str, acs, previous, image, camera
                ) -> tuple[np.ndarray, np.ndarray]:
        """Normalised (undistorted) point pairs of one source, ``(N, 2)`` each."""
        if source in ('frontend', 'dense'):
            norm = acs.normalized(camera)
            return norm.p1, norm.p2
        import cv2

        from planar_vo.frontend.flow import DIS_PRESETS, flow_candidates

        if self._dis is None:
            self._dis = cv2.DISOpticalFlow_create(DIS_PRESETS['fast'])
        flow = self._dis.calc(previous, image, None)
        p1 = flow_candidates(previous, self._dense).points
        p2 = p1 + flow[p1[:, 1], p1[:, 0]].astype(np.float64)
        q1, _ = camera.pixel_to_normalized(p1.astype(np.float64))
        q2, _ = camera.pixel_to_normalized(p2)
        good = np.all(np.isfinite(q1), axis=1) & np.all(np.isfinite(q2), axis=1)
        return q1[good], q2[good]

    @staticmethod
    def _five_point(name: str, q, camera) -> tuple[np.ndarray, np.ndarray, bool, float]:
        """One estimator on one pair: ``R``, unit ``t``, success and its seconds."""
        from planar_vo.bench.peers import estimate_5pc_opencv, estimate_5pc_poselib

        if q is None or len(q[0]) < 5:
            return np.full((3, 3), np.nan), np.full(3, np.nan), False, 0.0
        threshold = THRESHOLD_PX / camera.fx
        t0 = time.perf_counter()
        if name == 'opencv':
            est = estimate_5pc_opencv(q[0], q[1], threshold=threshold)
        elif name == 'poselib':
            est = estimate_5pc_poselib(q[0], q[1], threshold=threshold, **POSELIB_DEFAULTS)
        else:
            est = estimate_5pc_poselib(q[0], q[1], threshold=threshold)
        return est.R, est.t, est.ok, time.perf_counter() - t0

    def _focal_pair(self, acs, image) -> None:
        """The focal peer on this pair's dense front-end points (pixels about the image
        centre)."""
        from planar_vo.bench.peers import estimate_6pc_focal_poselib

        if acs is None or len(acs) < 6:
            self.focal_px.append(math.nan)
            self.focal_seconds.append(math.nan)
            return
        centre = (np.array(image.shape[::-1], dtype=np.float64) - 1.0) / 2.0
        t0 = time.perf_counter()
        est = estimate_6pc_focal_poselib(acs.p1 - centre, acs.p2 - centre,
                                         threshold=THRESHOLD_PX, **POSELIB_DEFAULTS)
        self.focal_seconds.append(time.perf_counter() - t0)
        self.focal_px.append(est.focal if est.ok else math.nan)

    def runs(self, stamps_ns: np.ndarray) -> dict[str, OdometryRun]:
        """The five-point runs on the frames added so far (stamps ``(N,)``), by key
        ``'<estimator>_<source>'``."""
        out = {}
        steps = np.array(self._steps)
        for source in self.sources:
            for name in self.estimators:
                key = f'{name}_{source}'
                motions = self._motions[key]
                R = np.array([m[0] for m in motions]).reshape(-1, 3, 3)
                t = np.array([m[1] for m in motions]).reshape(-1, 3)
                ok = np.array([m[2] for m in motions], dtype=bool)
                seconds = np.array(self._seconds[key]).reshape(-1, 2)
                options = ({'threshold_px': THRESHOLD_PX, **POSELIB_DEFAULTS}
                           if name == 'poselib' else {'threshold_px': THRESHOLD_PX})
                out[key] = OdometryRun(
                    f'{FIVE_POINT[name]}, {SOURCES[source]}',
                    TRUE_STEP,
                    np.asarray(stamps_ns, dtype=np.int64), chain_camera_motions(R, t, steps, ok),
                    np.concatenate([[False], ok]), seconds[:, 0], seconds[:, 1],
                    {'options': options, 'failed_pairs': int(np.count_nonzero(~ok))})
        return out

    def focal_summary(self, true_focal: float) -> dict:
        """The focal peer's per-pair focal lengths voted by their median."""
        f = np.array(self.focal_px)
        good = f[np.isfinite(f) & (f > 0.0)]
        median = float(np.median(good)) if good.size else math.nan
        q25, q75 = (np.percentile(good, [25, 75]) if good.size else (math.nan, math.nan))
        seconds = np.array(self.focal_seconds)
        return {'label': FOCAL_PEER, 'vote': 'median of the per-pair focal lengths',
                'focal_px': median, 'error_px': median - true_focal,
                'error_pct': 100.0 * (median - true_focal) / true_focal,
                'pairs': int(f.size), 'pairs_with_focal': int(good.size),
                'iqr_px': [float(q25), float(q75)], 'per_pair_px': f.tolist(),
                'estimator_ms_median': 1e3 * float(np.nanmedian(seconds)) if good.size
                else math.nan,
                'options': {'threshold_px': THRESHOLD_PX, **POSELIB_DEFAULTS,
                            'principal_point': 'image centre'}}
