"""Trajectory error metrics: ATE, RPE per frame and per distance, yaw and heading errors.

Definitions (poses ``T = [R | p]`` in the reference world frame, after association):

- ATE (absolute trajectory error): ``|p_ref(i) - p_est(i)|`` after aligning the estimate
  (`planar_vo.tools.evaluation.align`), summarised by RMSE, mean, median, std, min, max.
- RPE per frame (Sturm et al., IROS 2012): ``E_i = (Q_i^-1 Q_{i+d})^-1 (P_i^-1 P_{i+d})`` with
  reference ``Q`` and estimate ``P``; translational error ``|t(E_i)|`` (m), rotational error the
  angle of ``R(E_i)`` (degrees).
- RPE per distance (Geiger et al., CVPR 2012, the KITTI odometry metric): for every start frame
  ``i`` and segment length ``L``, ``j`` is the first frame whose reference path length from ``i``
  reaches ``L`` (KITTI's devkit takes the first that exceeds it; no difference on real data);
  ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (KITTI's devkit writes the inverse, which has the same
  translation norm and angle); errors ``|t(E)| / L`` (reported in %) and
  ``angle(E) / L`` (deg/m), averaged over all segments.
- KITTI odometry protocol (`kitti_drift`): the same segment errors with
  a start every 10 frames and lengths 100, 200, ..., 800 m (those the drive is long enough
  for), on the estimate as it is (no scale alignment: a scale error counts), reported as
  ``t_rel`` (%) and ``r_rel`` (deg/100 m), in 3D and on SE(2) (z, roll and pitch dropped from
  both trajectories).
- Yaw-change error per frame: ``yaw(R_est(i-1)^T R_est(i)) - yaw(R_ref(i-1)^T R_ref(i))``,
  wrapped to (-180, 180] degrees.
- Heading error per frame: the direction of travel in the previous body frame,
  ``atan2(d_y, d_x)`` with ``d = R(i-1)^T (p(i) - p(i-1))``, estimate minus reference (degrees);
  NaN where either planar displacement is below ``min_step`` (standing still: no direction).
- Covariance consistency (`covariance_consistency`, when the estimate carries its pose
  covariance): the error of each estimated pose against the reference anchored at the first
  matched pose (``T_est(0) T_ref(0)^-1 T_ref(i)``: the odometry's covariance grows from its
  origin, so no fitted alignment), position ``p_est - p_ref`` and rotation
  ``log(R_est R_ref^T)`` in the odometry frame (REP-103 order x, y, z, roll, pitch, yaw: the
  rotations about the fixed axes, to first order), each component divided by its reported
  standard deviation (``|e| / std``), and the 2D position's Mahalanobis distance
  ``sqrt(e_xy^T C_xy^-1 e_xy)``. An honest covariance keeps ``|e| / std`` within 3 (a normal
  error: 99.7 %) and the 2D distance within 3.4 (chi-square, 2 degrees of freedom, 99.7 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.conventions import invert, planar_pose, so3_log, yaw_of
from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import InputError
from planar_vo.tools.evaluation.align import Alignment, align_trajectory
from planar_vo.tools.evaluation.files import associate

__all__ = [
    'Evaluation',
    'ate_errors',
    'covariance_consistency',
    'evaluate',
    'flatten_se2',
    'kitti_drift',
    'rotation_angle',
    'rpe_by_distance',
    'rpe_per_frame',
    'statistics',
    'yaw_heading_errors',
]

DEFAULT_SEGMENTS = (5.0, 10.0, 20.0)
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_STEP = 10
# A drive too short for a 100 m segment gets the same protocol on these (planar_vo bench drives
# does the same): labelled as such, never mixed with the 100-800 m figures.
KITTI_SHORT_LENGTHS = (10.0, 20.0, 30.0, 40.0, 50.0)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angles (radians, ``[0, pi]``) of ``(..., 3, 3)`` rotations.

    ``atan2(sin, cos)`` with ``sin`` from the skew part and ``cos`` from the trace: accurate near
    zero, where ``arccos`` of the trace loses half the digits.
    """
    R = np.asarray(R, dtype=np.float64)
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                     R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=-1),
                      0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0))


def _wrap_deg(angle_rad: np.ndarray) -> np.ndarray:
    return np.degrees(np.angle(np.exp(1j * np.asarray(angle_rad))))


def statistics(values: np.ndarray) -> dict[str, float]:
    """RMSE, mean, median, std, min, max and count of the finite `values`."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        nan = float('nan')
        return {'rmse': nan, 'mean': nan, 'median': nan, 'std': nan, 'min': nan, 'max': nan,
                'count': 0}
    return {'rmse': float(np.sqrt(np.mean(v * v))), 'mean': float(np.mean(v)),
            'median': float(np.median(v)), 'std': float(np.std(v)), 'min': float(np.min(v)),
            'max': float(np.max(v)), 'count': int(v.size)}


COVARIANCE_AXES = ('x', 'y', 'z', 'roll', 'pitch', 'yaw')


def covariance_consistency(ref: Trajectory, est: Trajectory, covariances: np.ndarray) -> dict:
    """How the estimate's errors compare with its reported pose covariance (module docstring).

    Each axis is judged on the poses after the first (the anchor) whose covariance is finite
    and gives that axis a positive variance (a planar odometry may leave z, roll and pitch at
    zero, ROS's -1 marks an unknown one); the 2D distance on those whose x-y block is positive
    definite. The anchor's own uncertainty is not taken off (zero for planar_vo's, whose first
    odometry is the origin itself; another odometry's early poses read a little
    conservative). For an honest covariance and a normal error, ``|e| / std`` has median 0.674
    and p90 1.645, the 2D distance median 1.177 and p90 2.146 (`HONEST`); errors of
    successive poses are strongly correlated, so the shares within the bounds are per-frame
    figures.

    Args:
        ref, est: matched trajectories (same length; the estimate as published, not aligned).
        covariances: ``(N, 6, 6)`` pose covariances of ``est`` (REP-103 order).

    Returns:
        ``{'frames': 0, 'reason': ...}`` when no pose after the first is usable on any axis;
        else ``frames`` (poses after the first with a finite covariance), ``abs_z`` (per usable
        axis: ``frames``, ``median``, ``p90``, ``max`` and ``within``, the share at most
        ``bound`` = 3) and ``position_2d`` (the same for the 2D Mahalanobis distance, bound
        3.4: chi-square with 2 degrees of freedom at 99.7 %), when usable.
    """
    C = np.asarray(covariances, dtype=np.float64)
    if C.shape != (len(est), 6, 6) or len(ref) != len(est):
        raise InputError(f'covariances: expected shape ({len(est)}, 6, 6) for {len(est)} poses '
                         f'matched to {len(ref)}, got {C.shape}')
    finite = np.all(np.isfinite(C), axis=(1, 2))
    finite[0] = False                       # the anchor itself: no error by construction
    index = np.flatnonzero(finite)
    anchor = est.poses[0] @ invert(ref.poses[0])
    errors = np.full((len(est), 6), np.nan)
    for k in index:
        truth = anchor @ ref.poses[k]
        errors[k] = np.concatenate([est.poses[k][:3, 3] - truth[:3, 3],
                                    so3_log(est.poses[k][:3, :3] @ truth[:3, :3].T)])
    variances = np.diagonal(C, axis1=1, axis2=2)
    abs_z, usable = {}, 0
    for i, axis in enumerate(COVARIANCE_AXES):
        use = finite & (variances[:, i] > 0)
        usable = max(usable, int(np.count_nonzero(use)))
        if np.count_nonzero(use) >= 2:
            abs_z[axis] = _consistency(np.abs(errors[use, i]) / np.sqrt(variances[use, i]), 3.0)
    distances = []
    for k in index:
        xy = C[k, :2, :2]
        if xy[0, 0] > 0 and xy[1, 1] > 0 and np.linalg.det(xy) > 1e-12 * xy[0, 0] * xy[1, 1]:
            e = errors[k, :2]
            distances.append(math.sqrt(max(float(e @ np.linalg.solve(xy, e)), 0.0)))
    if not abs_z:
        if usable:          # (a user test: a two-pose bag was said to have no variance)
            reason = (f'needs at least 2 poses after the first with a positive variance on an '
                      f'axis, got {usable}')
        else:
            reason = ('no pose after the first has a positive variance on any axis (a '
                      'covariance of zeros, unknown or not finite)')
        return {'frames': 0, 'reason': reason}
    result = {'frames': int(index.size), 'abs_z': abs_z}
    if len(distances) >= 2:
        result['position_2d'] = _consistency(np.array(distances), 3.4)
    return result


# What an honest covariance gives for a normal error: |e| / std (half-normal) and the 2D
# Mahalanobis distance (Rayleigh), median and p90.
HONEST = {'abs_z': (0.674, 1.645), 'position_2d': (1.177, 2.146)}


def _consistency(values: np.ndarray, bound: float) -> dict[str, float]:
    return {'frames': int(values.size), 'median': float(np.median(values)),
            'p90': float(np.percentile(values, 90)), 'max': float(np.max(values)),
            'bound': bound, 'within': float(np.mean(values <= bound))}


def ate_errors(ref: Trajectory, est: Trajectory) -> np.ndarray:
    """``(N,)`` position errors (m) of associated, aligned trajectories."""
    return np.linalg.norm(ref.positions - est.positions, axis=1)


def rpe_per_frame(ref: Trajectory, est: Trajectory, delta: int = 1, max_gap: float = 1.5
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose errors over `delta` frames: translation (m) and rotation (deg), ``(N-d,)``.

    A pair whose stamps lie more than ``max_gap`` times ``delta`` median intervals apart spans
    dropped frames: NaN in both (left out of their statistics, as in `yaw_heading_errors`; a
    user test: a maximum of 37.6 m over a gap of 100 frames)."""
    if delta < 1:
        raise InputError(f'delta: expected at least 1 frame, got {delta}')
    Q, P = ref.poses, est.poses
    dQ = invert(Q[:-delta]) @ Q[delta:]
    dP = invert(P[:-delta]) @ P[delta:]
    E = invert(dQ) @ dP
    t, r = np.linalg.norm(E[:, :3, 3], axis=1), np.degrees(rotation_angle(E[:, :3, :3]))
    stamps = ref.stamps_ns.astype(np.float64)
    if stamps.size > delta:
        span = stamps[delta:] - stamps[:-delta]
        gap = span > max_gap * delta * float(np.median(np.diff(stamps)))
        t[gap] = r[gap] = np.nan
    return t, r


def rpe_by_distance(ref: Trajectory, est: Trajectory,
                    lengths: tuple[float, ...] = DEFAULT_SEGMENTS, step: int = 1
                    ) -> dict[str, dict[str, float]]:
    """KITTI-style segment errors per segment length.

    Args:
        lengths: segment lengths in metres (KITTI uses 100..800 m; short drives need 5..20 m).
        step: frames between segment starts.

    Returns:
        ``{'5m': {'segments': n, 'translation_percent': ..., 'rotation_deg_per_m': ...}, ...,
        'all': {...}}`` (NaN where the drive is shorter than the segment).
    """
    Q, P = ref.poses, est.poses
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref.positions, axis=0),
                                                           axis=1))])
    out: dict[str, dict[str, float]] = {}
    all_t, all_r = [], []
    for length in lengths:
        first = np.arange(0, len(ref), max(1, int(step)))
        last = np.searchsorted(dist, dist[first] + length, side='left')
        ok = last < len(ref)
        first, last = first[ok], last[ok]
        E = invert(invert(Q[first]) @ Q[last]) @ (invert(P[first]) @ P[last])
        t_err = np.linalg.norm(E[:, :3, 3], axis=1) / length
        r_err = rotation_angle(E[:, :3, :3]) / length
        all_t.append(t_err)
        all_r.append(r_err)
        out[f'{length:g}m'] = _segment_summary(t_err, r_err)
    out['all'] = _segment_summary(np.concatenate(all_t) if all_t else np.zeros(0),
                                  np.concatenate(all_r) if all_r else np.zeros(0))
    return out


def flatten_se2(trajectory: Trajectory) -> Trajectory:
    """The trajectory on SE(2): x, y and yaw kept, z, roll and pitch dropped (z-up frames)."""
    p = trajectory.positions
    return Trajectory(trajectory.stamps_ns, planar_pose(p[:, 0], p[:, 1], trajectory.yaw))


def kitti_drift(ref: Trajectory, est: Trajectory, *, planar: bool = False,
                lengths: tuple[float, ...] = KITTI_LENGTHS, step: int = KITTI_STEP
                ) -> dict[str, float]:
    """Drift by the KITTI odometry protocol (Geiger et al., CVPR 2012).

    Args:
        ref, est: associated trajectories (same length, pose by pose); the estimate is used as
            it is: alignment cannot change relative poses, and no scale is fitted.
        planar: on SE(2) (`flatten_se2` of both) instead of in 3D.
        lengths: segment lengths (m); those without a segment in the drive are left out.
        step: frames between segment starts.

    Returns:
        ``{'t_rel_pct': mean |t(E)| / L in %, 'r_rel_deg_per_100m': mean angle(E) / L in degrees
        per 100 m, 'segments': count, 'lengths_m': the lengths used}``; NaN and 0 segments when
        the drive is shorter than the shortest length.
    """
    if len(ref) != len(est):        # (a user test: unassociated ones gave NaN, no error)
        raise InputError(f'ref, est: expected associated trajectories of one length, got '
                         f'{len(ref)} and {len(est)} poses (evaluate associates them by stamp)')
    if planar:
        ref, est = flatten_se2(ref), flatten_se2(est)
    per_length = rpe_by_distance(ref, est, lengths, step)
    used = [length for length in lengths if per_length[f'{length:g}m']['segments'] > 0]
    total = per_length['all']
    return {'t_rel_pct': total['translation_percent'],
            'r_rel_deg_per_100m': 100.0 * total['rotation_deg_per_m'],
            'segments': total['segments'], 'lengths_m': used}


def _segment_summary(t_err: np.ndarray, r_err: np.ndarray) -> dict[str, float]:
    if t_err.size == 0:
        return {'segments': 0, 'translation_percent': float('nan'),
                'rotation_deg_per_m': float('nan')}
    return {'segments': int(t_err.size), 'translation_percent': float(100.0 * np.mean(t_err)),
            'rotation_deg_per_m': float(np.degrees(np.mean(r_err)))}


def yaw_heading_errors(ref: Trajectory, est: Trajectory, min_step: float = 1e-3,
                       max_gap: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """Per consecutive frame pair: yaw-change error and heading error, degrees, ``(N-1,)``.

    See the module docstring; frames are z-up (REP-103 ``odom``/``base_link``). A pair whose
    stamps lie more than ``max_gap`` times the median interval apart spans dropped frames: it
    is not a frame-to-frame change and is NaN in both (left out of their statistics).
    """
    def yaw_change_and_heading(traj: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        R, p = traj.rotations, traj.positions
        dyaw = yaw_of(np.swapaxes(R[:-1], 1, 2) @ R[1:])
        d = np.einsum('nji,nj->ni', R[:-1], np.diff(p, axis=0))       # R_prev^T (p - p_prev)
        return dyaw, np.arctan2(d[:, 1], d[:, 0]), np.hypot(d[:, 0], d[:, 1])

    yaw_r, head_r, step_r = yaw_change_and_heading(ref)
    yaw_e, head_e, step_e = yaw_change_and_heading(est)
    heading = _wrap_deg(head_e - head_r)
    heading[(step_r < min_step) | (step_e < min_step)] = np.nan
    yaw = _wrap_deg(yaw_e - yaw_r)
    dt = np.diff(ref.stamps_ns).astype(np.float64)
    if dt.size:
        gap = dt > max_gap * float(np.median(dt))
        yaw[gap] = heading[gap] = np.nan
    return yaw, heading


@dataclass(frozen=True)
class Evaluation:
    """Everything `evaluate` computed (per-frame arrays and summaries)."""

    ref: Trajectory
    est: Trajectory
    aligned: Trajectory
    alignment: Alignment
    ate: np.ndarray
    rpe_translation: np.ndarray
    rpe_rotation_deg: np.ndarray
    yaw_change_error_deg: np.ndarray
    heading_error_deg: np.ndarray
    segments: dict[str, dict[str, float]]
    unmatched: dict[str, int] = field(default_factory=dict)
    kitti: dict[str, float] = field(default_factory=dict)
    kitti_se2: dict[str, float] = field(default_factory=dict)
    kitti_short: dict[str, float] = field(default_factory=dict)
    kitti_short_se2: dict[str, float] = field(default_factory=dict)
    covariance: dict = field(default_factory=dict)

    def metrics(self) -> dict:
        """JSON-ready summary."""
        def abs_stats(values: np.ndarray) -> dict[str, float]:
            stats = statistics(np.abs(values))
            finite = values[np.isfinite(values)]
            stats['bias'] = float(np.mean(finite)) if finite.size else float('nan')
            return stats

        return {
            'poses': {'matched': len(self.ref), **self.unmatched},
            'path_length_m': self.ref.path_length,
            'alignment': self.alignment.to_dict(),
            'ate_m': statistics(self.ate),
            'rpe_frame': {'translation_m': statistics(self.rpe_translation),
                          'rotation_deg': statistics(self.rpe_rotation_deg)},
            'rpe_distance': self.segments,
            'kitti': self.kitti,
            'kitti_se2': self.kitti_se2,
            **({'kitti_short': self.kitti_short, 'kitti_short_se2': self.kitti_short_se2}
               if self.kitti_short else {}),
            'yaw_change_error_deg': abs_stats(self.yaw_change_error_deg),
            'heading_error_deg': abs_stats(self.heading_error_deg),
            **({'covariance': self.covariance} if self.covariance else {}),
        }

    def _alignment_line(self) -> str:
        """The alignment's method and scale; for a path that is almost a line, why its ATE
        reads low (`Alignment.line_like`)."""
        a = self.alignment
        line = f'{a.method} (scale {a.scale:.6f})'
        if a.line_like:
            along, across = a.spread
            line += (f'; the path is almost a line (standard deviations {across:.2f} m across, '
                     f'{along:.1f} m along it): the fit turns the estimate about it to absorb '
                     f'errors, so the ATE reads low (--align origin does not)')
        return line

    def format_table(self) -> str:
        """Markdown table of the main numbers."""
        m = self.metrics()
        poses = m['poses']
        matched = f"{poses['matched']}"
        if 'estimate_unmatched' in poses:
            matched += (f" (unmatched: {poses['estimate_unmatched']} estimated, "
                        f"{poses['reference_unmatched']} reference)")
        rows = [('matched poses', matched),
                ('path length (m)', f"{m['path_length_m']:.3f}"),
                ('alignment', self._alignment_line())]
        for key, label in (('ate_m', 'ATE (m)'),):
            s = m[key]
            rows.append((f'{label} rmse / mean / median / max',
                         f"{s['rmse']:.6f} / {s['mean']:.6f} / {s['median']:.6f} / "
                         f"{s['max']:.6f}"))
        t, r = m['rpe_frame']['translation_m'], m['rpe_frame']['rotation_deg']
        rows.append(('RPE/frame trans (m) rmse / max', f"{t['rmse']:.6f} / {t['max']:.6f}"))
        rows.append(('RPE/frame rot (deg) rmse / max', f"{r['rmse']:.6f} / {r['max']:.6f}"))
        for name, seg in m['rpe_distance'].items():
            rows.append((f'RPE {name} segments: trans (%) / rot (deg/m)',
                         f"{seg['translation_percent']:.4f} / {seg['rotation_deg_per_m']:.6f} "
                         f"(n={seg['segments']})"))
        for key, label in (('kitti', 'KITTI protocol, 3D'),
                           ('kitti_se2', 'KITTI protocol, SE(2)'),
                           ('kitti_short', 'KITTI protocol on 10-50 m (short drive), 3D'),
                           ('kitti_short_se2', 'KITTI protocol on 10-50 m (short drive), SE(2)')):
            if key not in m or (key in ('kitti', 'kitti_se2') and 'kitti_short' in m):
                continue                    # (a short drive: its 10-50 m rows instead)
            k = m[key]
            used = ', '.join(f'{v:g}' for v in k['lengths_m']) or 'none'
            if k['segments'] == 0:          # (a user test: 'nan / nan (n=0, lengths none m)')
                rows.append((f'{label}: t_rel (%) / r_rel (deg/100 m)',
                             f"none: no segment of 10 m or more fits the "
                             f"{m['path_length_m']:.1f} m path"))
                continue
            rows.append((f'{label}: t_rel (%) / r_rel (deg/100 m)',
                         f"{k['t_rel_pct']:.3f} / {k['r_rel_deg_per_100m']:.3f} "
                         f"(n={k['segments']}, lengths {used} m)"))
        for key, label in (('yaw_change_error_deg', 'yaw-change error (deg)'),
                           ('heading_error_deg', 'heading error (deg)')):
            s = m[key]
            rows.append((f'{label} mean |e| / rmse / max / bias',
                         f"{s['mean']:.4f} / {s['rmse']:.4f} / {s['max']:.4f} / "
                         f"{s['bias']:+.4f} (n={s['count']})"))
        if 'covariance' in m:
            c = m['covariance']
            if not c['frames']:
                rows.append(('covariance', f"not evaluated: {c['reason']}"))
            else:
                (zm, z90), (dm, d90) = HONEST['abs_z'], HONEST['position_2d']
                rows.append(('covariance: error / std, median / p90 / max',
                             f"anchored at the first pose; honest: {zm:.2f} / {z90:.2f} "
                             f"(2D: {dm:.2f} / {d90:.2f})"))
                named = [(f'  {axis}', z) for axis, z in c['abs_z'].items()]
                if 'position_2d' in c:
                    named.append(('  x, y together (2D Mahalanobis)', c['position_2d']))
                for label, z in named:
                    rows.append((label, f"{z['median']:.2f} / {z['p90']:.2f} / {z['max']:.2f} "
                                        f"({100 * z['within']:.1f} % within {z['bound']:g}, "
                                        f"n={z['frames']})"))
        width = max(len(k) for k, _ in rows)
        lines = [f"| {'metric'.ljust(width)} | value |", f"|{'-' * (width + 2)}|-------|"]
        lines += [f'| {k.ljust(width)} | {v} |' for k, v in rows]
        return '\n'.join(lines)


def evaluate(ref: Trajectory, est: Trajectory, *, align: str = 'se3', max_diff: float = 0.02,
             segment_lengths: tuple[float, ...] = DEFAULT_SEGMENTS,
             min_step: float = 1e-3, names: dict[str, str] | None = None,
             covariances: np.ndarray | None = None) -> Evaluation:
    """Associate `est` with `ref` by stamp, align it, and compute every metric.

    Args:
        ref, est: reference (ground truth) and estimate.
        align: ``'se3'``, ``'sim3'``, ``'origin'`` or ``'none'`` (see `align_trajectory`).
        max_diff: association tolerance in seconds.
        segment_lengths: RPE-by-distance segment lengths in metres.
        min_step: planar displacement (m) below which a frame has no heading.
        names: what error messages call ``ref``, ``est`` and ``max_diff`` where the caller's
            names differ (the CLI: ``{'ref': '--gt', 'max_diff': '--max-diff'}``).
        covariances: ``(len(est), 6, 6)`` pose covariances of `est`, for
            `covariance_consistency` (None: not evaluated).

    Raises:
        InputError: fewer than 2 poses matched (the message gives both stamp ranges).
    """
    name = {'ref': 'ref', 'est': 'est', 'max_diff': 'max_diff', **(names or {})}
    for key, value in (('ref', ref), ('est', est)):
        if not isinstance(value, Trajectory):
            raise InputError(f'{name[key]}: expected a Trajectory (Trajectory.from_poses, '
                             f'read_tum, read_bag_trajectory), got {type(value).__name__}')
    if not (math.isfinite(max_diff) and max_diff >= 0):
        raise InputError(f"{name['max_diff']}: expected a non-negative number of seconds, got "
                         f'{max_diff}')
    if covariances is not None and np.shape(covariances) != (len(est), 6, 6):
        raise InputError(f'covariances: expected shape ({len(est)}, 6, 6) for the {len(est)} '
                         f'poses of {name["est"]}, got {np.shape(covariances)}')
    ie, ir = associate(est.stamps_ns, ref.stamps_ns, max_diff)
    if len(ie) < 2:
        def span(t: Trajectory) -> str:
            return f'{t.stamps[0]:.3f}..{t.stamps[-1]:.3f} s' if len(t) else 'empty'
        hint = ''
        if len(est) and len(ref) and (est.stamps[-1] < ref.stamps[0]
                                      or ref.stamps[-1] < est.stamps[0]):
            # Disjoint ranges: another clock or stamps relative to the start (a user test: a
            # TUM file from 0 s against a bag of import-kitti from 1.7e9 s).
            offset = float(ref.stamps[0] - est.stamps[0])
            hint = (f'; the ranges do not overlap: the estimate starts {abs(offset):.3f} s '
                    f'{"before" if offset > 0 else "after"} the reference (stamps of another '
                    f'clock, or relative to the start?)')
        raise InputError(f'association: expected at least 2 poses matched within {max_diff} s, '
                         f'got {len(ie)} (estimate {len(est)} poses {span(est)}, reference '
                         f'{len(ref)} poses {span(ref)}){hint}')
    est_m, ref_m = est.subset(ie), ref.subset(ir)
    aligned, alignment = align_trajectory(est_m, ref_m, align,
                                          names=(name['est'], name['ref']))
    rpe_t, rpe_r = rpe_per_frame(ref_m, aligned)
    yaw, heading = yaw_heading_errors(ref_m, aligned, min_step)
    kitti = kitti_drift(ref_m, est_m), kitti_drift(ref_m, est_m, planar=True)
    short: tuple[dict, dict] = ({}, {})
    if kitti[0]['segments'] == 0:           # no 100 m segment fits: the short drive's lengths
        short = (kitti_drift(ref_m, est_m, lengths=KITTI_SHORT_LENGTHS),
                 kitti_drift(ref_m, est_m, planar=True, lengths=KITTI_SHORT_LENGTHS))
        if short[0]['segments'] == 0:       # not even 10 m: nothing to report
            short = ({}, {})
    consistency = ({} if covariances is None else
                   covariance_consistency(ref_m, est_m, np.asarray(covariances)[ie]))
    return Evaluation(ref_m, est_m, aligned, alignment, ate_errors(ref_m, aligned), rpe_t, rpe_r,
                      yaw, heading, rpe_by_distance(ref_m, aligned, segment_lengths),
                      {'estimate_unmatched': len(est) - len(ie),
                       'reference_unmatched': len(ref) - len(ir)}, *kitti, *short, consistency)
