"""Trajectory files: TUM files, pose topics of bags, and timestamp association.

A TUM line is ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, unit quaternion in ROS order).
Stamps are kept as integer nanoseconds so that a stamp written and read back is unchanged.
"""

from __future__ import annotations

import collections
import logging
import math
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import InputError
from planar_vo.io.outputs import write_file

__all__ = [
    'POSE_TYPES',
    'associate',
    'is_bag_path',
    'load_trajectory',
    'read_bag_odometry',
    'read_bag_trajectory',
    'read_tum',
    'write_tum',
]

log = logging.getLogger(__name__)

POSE_TYPES = (
    'nav_msgs/msg/Odometry',
    'geometry_msgs/msg/PoseStamped',
    'geometry_msgs/msg/PoseWithCovarianceStamped',
)


# -- TUM files ----------------------------------------------------------------------------------

# The int64 nanoseconds of ROS time, and positions no odometry reaches (a trajectory 1e9 m
# long circles the Earth 25,000 times; squaring larger values overflows the alignment).
_MAX_STAMP_NS = 2 ** 63 - 1
_MAX_COORDINATE = 1e9


def _parse_stamp(text: str) -> int:
    value = Decimal(text)
    if not value.is_finite():
        raise InvalidOperation
    return int((value * 1_000_000_000).to_integral_value())


_TUM_FIELDS = ('tx', 'ty', 'tz', 'qx', 'qy', 'qz', 'qw')


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory file (``#`` comments and blank lines are skipped).

    Raises:
        InputError: unreadable file, a malformed line (named by its number), non-finite values,
            a zero quaternion, stamps not strictly increasing, or no poses.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8-sig')      # a byte-order mark is not data
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"tum: cannot read '{path}' ({err})") from err
    stamps, rows = [], []
    for lineno, line in enumerate(text.splitlines(), 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith('#'):
            continue
        where = f'{path} line {lineno}'
        if len(tokens) != 8:
            kitti = ('; a KITTI pose file? As the estimate it takes --est-times; as ground '
                     'truth, import its sequence with planar_vo import-kitti'
                     if len(tokens) == 12 else '')
            raise InputError(f"{where}: expected 8 values 'timestamp tx ty tz qx qy qz qw', "
                             f'got {len(tokens)}{kitti}')
        try:
            stamp = _parse_stamp(tokens[0])
        except (InvalidOperation, ValueError):
            raise InputError(f'{where}: the timestamp: expected a number, got '
                             f'{tokens[0][:40]!r}') from None
        values = []
        for name, token in zip(_TUM_FIELDS, tokens[1:]):
            # The field by name, with its token (a user test: the line quoted up to 80
            # characters hid a NaN in its last column).
            try:
                value = float(token)
            except ValueError:
                raise InputError(f'{where}: {name}: expected a number, got '
                                 f'{token[:40]!r}') from None
            if not math.isfinite(value):
                raise InputError(f'{where}: {name}: expected a finite value, got {token!r}')
            values.append(value)
        if not -_MAX_STAMP_NS <= stamp <= _MAX_STAMP_NS:
            raise InputError(f'{where}: expected a timestamp in seconds within +-9.2e9 s (ROS '
                             f'time, int64 nanoseconds), got {tokens[0]} (nanoseconds?)')
        if max(abs(v) for v in values[:3]) > _MAX_COORDINATE:
            raise InputError(f'{where}: expected positions within {_MAX_COORDINATE:.0e} m, got '
                             f'{line.strip()[:80]!r}')
        if not any(values[3:]):
            raise InputError(f'{where}: expected a non-zero quaternion, got 0 0 0 0')
        if stamps and stamp <= stamps[-1]:
            raise InputError(f'{where}: expected increasing timestamps, got {tokens[0]} after '
                             f'{_format_ns(stamps[-1])}')
        stamps.append(stamp)
        rows.append(values)
    if not rows:
        raise InputError(f"tum: '{path}' contains no poses")
    data = np.array(rows)
    return Trajectory.from_quaternions(np.array(stamps, dtype=np.int64), data[:, :3], data[:, 3:])


def _format_ns(ns: int) -> str:
    sign = '-' if ns < 0 else ''
    sec, nsec = divmod(abs(int(ns)), 1_000_000_000)
    return f'{sign}{sec}.{nsec:09d}'


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    """Write a TUM file: stamps with all nine decimals, floats in shortest round-trip form.

    The file is written under a temporary name and renamed when complete, so an interruption
    or a full disk never leaves a truncated file at `path`.

    Raises:
        OutputError: the file cannot be written (the message names it and the reason).
    """
    lines = ['# timestamp tx ty tz qx qy qz qw']
    for ns, p, q in zip(trajectory.stamps_ns, trajectory.positions, trajectory.quaternions):
        lines.append(' '.join([_format_ns(int(ns)), *(repr(float(v)) for v in (*p, *q))]))
    write_file(path, '\n'.join(lines) + '\n', role='tum')


# -- bags ---------------------------------------------------------------------------------------

def is_bag_path(path: str | Path) -> bool:
    """A bag directory or a ``.mcap``/``.db3`` file (anything else is read as TUM)."""
    path = Path(path)
    return path.is_dir() or path.suffix in ('.mcap', '.db3')


def read_bag_trajectory(path: str | Path, topic: str, *, role: str = 'topic',
                        span: tuple[str, int, int] | None = None,
                        part: dict | None = None) -> Trajectory:
    """Poses of an Odometry/PoseStamped/PoseWithCovarianceStamped topic, by header stamp.

    Messages are sorted by stamp; a repeated stamp keeps its first message (logged). Stamps
    that go back by more than a second in recording order start another time base (a
    restarted clock, confirmed by the next message; `_one_time_base`): only one part is read
    (logged): the longest, or with ``span`` (``('log', first, last)`` log times, ns, of the
    estimate's part in the same bag, else ``('stamp', first, last)``) the one with the most
    messages in it. ``part``, a dict, receives the read part's ``log_span`` and whether the
    topic was ``split``. `role` names the topic argument in error messages.

    Raises:
        BagError: unreadable bag, unknown topic (listing the available ones), wrong type.
        InputError: no messages on the topic.
    """
    stamps, poses, _ = _read_pose_topic(path, topic, role, covariances=False, span=span,
                                        part=part)
    return Trajectory.from_poses(stamps, poses)


def read_bag_odometry(path: str | Path, topic: str, *, role: str = 'topic',
                      part: dict | None = None) -> tuple[Trajectory, np.ndarray | None]:
    """`read_bag_trajectory` and, in the same order, the pose covariances ``(N, 6, 6)`` of an
    Odometry or PoseWithCovarianceStamped topic (REP-103 order: x, y, z, then rotations about
    x, y, z); None for a topic without them (PoseStamped). One pass over the bag. Raises as
    `read_bag_trajectory`."""
    stamps, poses, covariances = _read_pose_topic(path, topic, role, covariances=True,
                                                  part=part)
    return Trajectory.from_poses(stamps, poses), covariances


def _read_pose_topic(path: str | Path, topic: str, role: str, *, covariances: bool,
                     span: tuple[str, int, int] | None = None, part: dict | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Sorted, de-duplicated stamps, poses and (when asked for and present) covariances."""
    from planar_vo.io import iter_messages, open_bag
    from planar_vo.ros.messages import pose_from_message

    stamps, logs, poses, covs = [], [], [], []
    with open_bag(path) as bag:
        for item in iter_messages(bag, topic, POSE_TYPES, role=role):
            stamps.append(item.stamp_ns)
            logs.append(item.log_time_ns)
            try:
                poses.append(pose_from_message(item.msg))
            except InputError as err:
                raise InputError(f"{role}: '{topic}' in '{path}', the message stamped "
                                 f'{_format_ns(item.stamp_ns)} s: {err}') from err
            if covariances:
                # Odometry.pose.covariance, PoseWithCovarianceStamped.pose.covariance.
                values = getattr(getattr(item.msg, 'pose', None), 'covariance', None)
                covs.append(None if values is None else
                            np.asarray(values, dtype=np.float64).reshape(6, 6))
        if bag.unread.get(topic):
            log.warning("topic '%s' in '%s': %d of its %d messages could not be read (damaged "
                        'storage, skipped by the reader)', topic, path, bag.unread[topic],
                        bag.count(topic))
    if not poses:
        raise InputError(f"{role}: '{topic}' in '{path}' has no messages")
    stamps_arr = np.array(stamps, dtype=np.int64)
    logs_arr = np.array(logs, dtype=np.int64)
    kept = _one_time_base(stamps_arr, logs_arr, topic, span)
    if part is not None:
        part.update(log_span=(int(logs_arr[kept].min()), int(logs_arr[kept].max())),
                    split=bool(kept.size < stamps_arr.size))
    order = kept[np.argsort(stamps_arr[kept], kind='stable')]
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = np.diff(stamps_arr[order]) > 0
    if not np.all(keep):
        log.warning("topic '%s': dropped %d messages with repeated stamps", topic,
                    int(np.count_nonzero(~keep)))
    order = order[keep]
    cov = None
    if covariances and all(c is not None for c in covs):
        cov = np.array(covs)[order]
    return stamps_arr[order], np.array(poses)[order], cov


# A stamp this far behind the ones before it (in recording order), and the next message's
# too, starts another time base: a restarted clock or recording (the odometry's own rule,
# odometry.max_time_jump_back, confirmed by the next frame); a smaller step back, or a single
# message, is out of order.
_TIME_BASE_JUMP_NS = 1_000_000_000
# The stamps before: the median of the last so many of the part (a run of up to ten stamped
# ahead, which the odometry publishes after a gap and then rewinds, moves it but little).
_TIME_BASE_WINDOW = 21


def _one_time_base(stamps: np.ndarray, logs: np.ndarray, topic: str,
                   span: tuple[str, int, int] | None) -> np.ndarray:
    """The indices of the messages on one time base (recording order; see
    `_TIME_BASE_JUMP_NS`): all of them when the stamps never restart, else the longest part,
    or with ``span`` (``('log' | 'stamp', first, last)``) the part with the most log times or
    stamps within it (the estimate's part, for its ground truth), warned. Sorted by stamp, two
    time bases interleave (a user test: a replay across a restarted clock scored 48 m ATE and
    an 11-deg yaw-change error without a word; its odometry had restarted at the origin)."""
    starts, behind = [], []
    recent: collections.deque[int] = collections.deque(maxlen=_TIME_BASE_WINDOW)
    values = stamps.tolist()
    for i, stamp in enumerate(values):
        if recent:
            before = sorted(recent)[len(recent) // 2]
            # (the last message has no next one to confirm it: out of order, like any single)
            if i + 1 < len(values) and stamp < before - _TIME_BASE_JUMP_NS and \
                    values[i + 1] < before - _TIME_BASE_JUMP_NS:
                starts.append(i)
                behind.append(values[i - 1])
                recent.clear()
        recent.append(stamp)
    if not starts:
        return np.arange(stamps.size)
    bounds = np.array([0, *starts, stamps.size])
    sizes = np.diff(bounds)
    score = sizes
    if span is not None:
        kind, lo, hi = span
        values_in = logs if kind == 'log' else stamps
        score = np.array([np.count_nonzero((values_in[a:b] >= lo) & (values_in[a:b] <= hi))
                          for a, b in zip(bounds[:-1], bounds[1:])]) * (stamps.size + 1) + sizes
    k = int(np.flatnonzero(score == score.max())[-1])       # (the last of equal ones)
    first = starts[0]
    log.warning("topic '%s': its stamps go back %d time(s) (first at message %d, %s s after "
                '%s s: a restarted clock or recording, where an odometry restarts from its '
                'origin); evaluating %s, messages %d-%d (%d of %d)', topic, len(starts),
                first, _format_ns(int(stamps[first])), _format_ns(behind[0]),
                'the longest part' if span is None else "the part of the estimate's",
                bounds[k], bounds[k + 1] - 1, sizes[k], stamps.size)
    return np.arange(bounds[k], bounds[k + 1])


def is_kitti_pose_file(path: str | Path) -> bool:
    """``path`` is a text file whose first pose line holds 12 numbers (a KITTI pose file: a
    3x4 matrix per line, no stamps), not 8 (TUM)."""
    path = Path(path)
    if not path.is_file() or is_bag_path(path):
        return False
    try:
        with path.open(encoding='utf-8') as lines:
            for line in lines:
                tokens = line.split()
                if tokens and not tokens[0].startswith('#'):
                    return len(tokens) == 12
    except (OSError, UnicodeDecodeError):
        return False
    return False


def read_kitti_trajectory(path: str | Path, times: str | Path, start: float | str | Decimal,
                          camera_height: float) -> Trajectory:
    """Another method's KITTI-format poses (``T_w_cam`` of an optical camera, the world its
    first frame) as the REP-103 poses of a level vehicle with the camera ``camera_height``
    above its origin, stamped ``start`` plus the times of ``times`` (a KITTI ``times.txt``):
    the frame and stamps `planar_vo.io.import_kitti` gives the ground truth, so the two
    compare.

    Raises:
        InputError: malformed files, or not one time per pose.
    """
    from planar_vo.io.kitti import _seconds, camera_to_vehicle, read_kitti_poses, read_kitti_times
    from planar_vo.io.writer import MAX_STAMP_NS
    from planar_vo.ros.messages import seconds_to_ns

    poses = read_kitti_poses(path)
    if not len(poses):
        raise InputError(f"EST: '{path}' contains no poses")
    if not Path(times).is_file():
        raise InputError(f"--est-times: '{times}' does not exist or is not a file")
    try:
        offsets = read_kitti_times(times)
    except InputError as err:
        raise InputError(f'--est-times: {err}') from err
    if len(offsets) != len(poses):
        raise InputError(f"--est-times: '{times}' holds {len(offsets)} times for the "
                         f'{len(poses)} poses of {Path(path).name}; expected one per pose')
    start_ns = seconds_to_ns(start)
    stamps = [start_ns + seconds_to_ns(t) for t in offsets]
    if min(stamps) < 0 or max(stamps) > MAX_STAMP_NS:
        # (a review: a traceback from the int64 conversion; import-kitti refuses the same)
        raise InputError(f'--est-start: {_seconds(start_ns)} s plus --est-times gives '
                         f'{_seconds(min(stamps))} to {_seconds(max(stamps))} s, outside the '
                         f'range of a ROS time stamp (1970 to 2038)')
    return Trajectory(np.array(stamps, dtype=np.int64), camera_to_vehicle(poses, camera_height))


def load_trajectory(path: str | Path, topic: str | None = None, *, role: str = 'topic',
                    span: tuple[str, int, int] | None = None) -> Trajectory:
    """A TUM file, or `topic` of a bag (see `is_bag_path`; ``span`` as for
    `read_bag_trajectory`); `role` names the argument."""
    if is_bag_path(path):
        if topic is None:
            raise InputError(f"{role}: '{path}' is a bag; expected a topic name, got none")
        return read_bag_trajectory(path, topic, role=role, span=span)
    if not Path(path).exists():
        raise InputError(f"trajectory: '{path}' does not exist")
    return read_tum(path)


# -- association --------------------------------------------------------------------------------

def associate(stamps_a: np.ndarray, stamps_b: np.ndarray, max_diff: float = 0.02
              ) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one nearest-stamp matching.

    Each stamp of `a` is paired with the nearest stamp of `b` if they differ by at most
    `max_diff` seconds; when several stamps of `a` pick the same `b`, the closest pair wins.

    Args:
        stamps_a, stamps_b: sorted integer nanosecond stamps ``(N,)`` and ``(M,)``.
        max_diff: seconds.

    Returns:
        ``(ia, ib)``: matched indices into `a` and `b`, increasing.
    """
    a = np.asarray(stamps_a, dtype=np.int64)
    b = np.asarray(stamps_b, dtype=np.int64)
    if a.size == 0 or b.size == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    hi = np.clip(np.searchsorted(b, a), 0, b.size - 1)
    lo = np.clip(hi - 1, 0, b.size - 1)
    ib = np.where(np.abs(b[lo] - a) <= np.abs(b[hi] - a), lo, hi)
    diff = np.abs(b[ib] - a)
    ia = np.flatnonzero(diff <= round(max_diff * 1e9))
    ib, diff = ib[ia], diff[ia]
    order = np.lexsort((ia, diff))                    # closest first, then earliest
    _, first = np.unique(ib[order], return_index=True)
    chosen = np.sort(order[first])
    return ia[chosen], ib[chosen]
