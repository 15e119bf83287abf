"""Convert a KITTI odometry sequence folder into a ROS 2 bag with REP-103 ground truth.

Input folder (KITTI odometry layout):

- ``image_0/`` (or ``image_l/``): the left greyscale camera, ``000000.png``, ``000001.png``...
- ``calib.txt``: first line ``P0`` as 12 numbers (row-major 3x4), with or without ``P0:``.
- ``times.txt``: one time in seconds per image (not needed with ``rate_hz``).
- ``poses.txt`` (optional): per image 12 numbers, the row-major 3x4 pose ``T_w_cam(i)`` of
  camera 0 in the frame of camera 0 at frame 0 (x right, y down, z forward). Without it, in
  the layout of the KITTI odometry download (``dataset/sequences/06/`` beside
  ``dataset/poses/06.txt``), the sequence's file in ``poses/`` is read.

Output topics: ``/camera/image_raw`` (``sensor_msgs/Image`` mono8), ``/camera/camera_info``
(``K`` from ``P0``, no distortion) and, with poses, ``/ground_truth/odom`` (``nav_msgs/Odometry``).

Frames (REP-103/105): ``base_link`` is the camera projected to the ground, `camera_height` below
it, x forward, y left, z up; ``odom`` is ``base_link`` at frame 0. With the mount
``T_bc = mount_transform(height=camera_height)``:

    T_odom_base(i) = T_bc  T_w_cam(i)  T_bc^-1

(``T_w_cam(0) = I`` gives ``T_odom_base(0) = I``; driving along the camera's z gives +x, a left
turn positive yaw.) The ground-truth twist is the finite difference over the previous interval
(the next one for frame 0), expressed in the current ``base_link``.
"""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.checks import positive_number
from planar_vo.core.conventions import invert, mount_transform, quaternion_from_rotation
from planar_vo.core.trajectory import rotation_defects
from planar_vo.errors import CameraModelError, ImageError, InputError
from planar_vo.frontend.images import read_image
from planar_vo.io.camera_bag import (
    CAMERA_INFO_TOPIC,
    DEFAULT_START,
    GROUND_TRUTH_TOPIC,
    IMAGE_TOPIC,
    CameraBagWriter,
    frame_rate,
)
from planar_vo.io.writer import MAX_STAMP_NS
from planar_vo.ros.messages import seconds_to_ns

__all__ = [
    'KittiImportSummary',
    'KittiSequence',
    'camera_to_vehicle',
    'import_kitti',
    'kitti_ground_truth',
    'read_kitti_poses',
    'read_kitti_sequence',
    'read_kitti_times',
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class KittiSequence:
    """The parsed text files of a KITTI sequence folder (images are read lazily).

    Attributes:
        images: PNG paths in frame order.
        P0: ``(3, 4)`` projection matrix of camera 0.
        times: per image, seconds as exact decimals (None when not given).
        poses: ``(N, 4, 4)`` ``T_w_cam`` (None without a poses file).
        poses_path: the file the poses came from (None without one).
        poses_sought: the files looked for (to say what is missing).
    """

    images: tuple[Path, ...]
    P0: np.ndarray
    times: tuple[Decimal, ...] | None
    poses: np.ndarray | None
    poses_path: Path | None = None
    poses_sought: tuple[Path, ...] = ()


@dataclass(frozen=True)
class KittiImportSummary:
    """What `import_kitti` wrote."""

    path: Path
    frames: int
    camera: CameraModel
    ground_truth: bool
    first_stamp_ns: int
    last_stamp_ns: int
    poses_path: Path | None = None
    poses_sought: tuple[Path, ...] = ()

    def format(self) -> str:
        if self.ground_truth:
            source = f' (from {self.poses_path})' if self.poses_path is not None else ''
            gt = f', ground truth on {GROUND_TRUTH_TOPIC}{source}'
        else:
            # Said, not left to `planar_vo eval` to find out (a user test: the download's
            # layout keeps the poses apart, and the import wrote none without a word).
            sought = ' nor '.join(str(p) for p in self.poses_sought) or 'poses.txt'
            gt = f'; no ground truth (no {sought})'
        duration = (self.last_stamp_ns - self.first_stamp_ns) / 1e9
        return (f'wrote {self.frames} frames ({self.camera.width}x{self.camera.height}, '
                f'fx {self.camera.fx:.2f}, {duration:.2f} s) to {self.path}: {IMAGE_TOPIC}, '
                f'{CAMERA_INFO_TOPIC}{gt}')


def _numbers(path: Path, lineno: int, line: str, count: int, what: str) -> np.ndarray:
    tokens = line.split()
    try:
        values = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError:
        values = np.array([])
    if values.size != count:
        raise InputError(f'{path.name} line {lineno}: expected {what} as {count} numbers, got '
                         f'{line.strip()[:80]!r}')
    if not np.all(np.isfinite(values)):
        # (a user test: twelve NaN were said not to be twelve numbers)
        bad = tokens[int(np.flatnonzero(~np.isfinite(values))[0])]
        raise InputError(f'{path.name} line {lineno}: expected {what} as {count} finite '
                         f'numbers, got {bad!r}')
    return values


def _lines(path: Path) -> list[tuple[int, str]]:
    """Non-empty lines with their 1-based numbers (a byte-order mark is not data: a user
    test had a calib.txt saved with one refused)."""
    try:
        text = path.read_text(encoding='utf-8-sig')
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f'{path}: cannot read ({err})') from err
    return [(i, line) for i, line in enumerate(text.splitlines(), 1) if line.strip()]


def read_kitti_sequence(folder: str | Path, *, need_times: bool = True) -> KittiSequence:
    """Parse a KITTI odometry sequence folder (see the module docstring).

    ``need_times=False`` (the frames are stamped at a given rate instead) leaves times.txt
    unread: a missing, short or malformed one is not an error then (``times`` None).

    Raises:
        InputError: missing folder/images/calibration, malformed lines (with line numbers), or
            counts of times/poses that differ from the number of images.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"sequence: '{folder}' is not a directory")
    image_dir = next((folder / d for d in ('image_0', 'image_l') if (folder / d).is_dir()), None)
    if image_dir is None:
        raise InputError(f"sequence: '{folder}' has no image_0/ or image_l/ folder")
    # By number where every name is one (a user test: '10.png' sorted before '2.png' as
    # text, and '02.png' was reported missing), else by name.
    images = sorted(image_dir.glob('*.png'))
    numbered = all(p.stem.isdigit() for p in images)
    images = tuple(sorted(images, key=lambda p: (int(p.stem), p.name)) if numbered else images)
    if not images:
        raise InputError(f"sequence: '{image_dir}' contains no .png images")
    n = len(images)
    # KITTI numbers its frames without gaps (from 000000; an excerpt may keep its first
    # number): a missing one would shift every later frame's time and pose by one (a user
    # test: it was blamed on times.txt's count, and with a frame rate imported without a word).
    if numbered:
        numbers = [int(p.stem) for p in images]
        for i, number in enumerate(numbers):
            if number != numbers[0] + i:
                if number == numbers[i - 1]:
                    raise InputError(f"images: '{images[i - 1].name}' and '{images[i].name}' "
                                     f"in '{image_dir}' both number frame {number}")
                # (padded like the name before it: '099999.png' is missing before '100000.png')
                width = len(images[i - 1].stem) if images[i - 1].stem.startswith('0') else 0
                raise InputError(f"images: '{numbers[0] + i:0{width}d}.png' is missing from "
                                 f"'{image_dir}' (frames are numbered without gaps; the next "
                                 f"there is '{images[i].name}')")

    calib = folder / 'calib.txt'
    if not calib.is_file():
        raise InputError(f"sequence: '{folder}' has no calib.txt")
    calib_lines = _lines(calib)
    if not calib_lines:
        raise InputError(f'{calib}: expected P0 on the first line, got an empty file')
    lineno, line = calib_lines[0]
    tokens = line.split()
    if tokens and tokens[0].endswith(':'):
        if tokens[0] != 'P0:':
            raise InputError(f"calib.txt line {lineno}: expected P0 first, got '{tokens[0]}'")
        line = ' '.join(tokens[1:])
    P0 = _numbers(calib, lineno, line, 12, 'P0').reshape(3, 4)

    times = None
    times_path = folder / 'times.txt'
    if times_path.is_file() and need_times:
        times = read_kitti_times(times_path)
        if len(times) != n:
            raise InputError(f'times.txt: expected one time per image ({n}), got {len(times)}')
    elif need_times:
        raise InputError(f"sequence: '{folder}' has no times.txt; give the frame rate instead "
                         f'(import-kitti --rate-hz; import_kitti(rate_hz=...) in Python)')

    poses = None
    sought = [folder / 'poses.txt']
    # dataset/sequences/06 -> dataset/poses/06.txt (as given: a symlinked sequence folder
    # stays in its tree).
    where = folder.absolute()
    if where.parent.name == 'sequences':
        sought.append(where.parent.parent / 'poses' / f'{where.name}.txt')
    poses_path = next((path for path in sought if path.is_file()), None)
    if poses_path is not None:
        poses = read_kitti_poses(poses_path)
        if len(poses) != n:
            raise InputError(f'{poses_path.name}: expected one pose per image ({n}), got '
                             f'{len(poses)}')
    return KittiSequence(images, P0, times, poses, poses_path, tuple(sought))


def read_kitti_times(path: str | Path) -> tuple[Decimal, ...]:
    """The increasing times (seconds) of a KITTI ``times.txt``, one per line.

    Raises:
        InputError: a line that is not a finite number, or not after the one before.
    """
    path = Path(path)
    parsed: list[Decimal] = []
    for lineno, line in _lines(path):
        try:
            value = Decimal(line.strip())
            if not value.is_finite():
                raise InvalidOperation
        except InvalidOperation:
            raise InputError(f'{path.name} line {lineno}: expected seconds, got '
                             f'{line.strip()[:40]!r}') from None
        if parsed and value <= parsed[-1]:
            raise InputError(f'{path.name} line {lineno}: expected increasing times, got '
                             f'{value} after {parsed[-1]}')
        parsed.append(value)
    return tuple(parsed)


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """``(N, 4, 4)`` poses ``T_w_cam`` of a KITTI pose file (``poses.txt``, or another
    method's output in that format): a 3x4 matrix per line, row-major.

    Raises:
        InputError: a line without 12 numbers, or a first 3x3 block that is not a rotation.
    """
    path = Path(path)
    name = path.name
    # (comment lines, as a TUM file may have them: a user test)
    lines = [(i, line) for i, line in _lines(path) if not line.lstrip().startswith('#')]
    rows = [_numbers(path, i, line, 12, 'a 3x4 pose') for i, line in lines]
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    if rows:
        poses[:, :3, :] = np.array(rows).reshape(-1, 3, 4)
    # The rotation blocks must be rotations (KITTI writes them to about 1e-6): a scaled,
    # zero or mirrored block would silently become some other ground truth.
    bad, error, det = rotation_defects(poses[:, :3, :3])
    if bad.size:
        raise InputError(f'{name} line {lines[bad[0]][0]}: expected a rotation matrix in the '
                         f'first 3x3 block (orthonormal, determinant +1), got R^T R off the '
                         f'identity by {error[bad[0]]:.3g} and determinant {det[bad[0]]:.3g}')
    return poses


def camera_to_vehicle(poses_cam: np.ndarray, camera_height: float) -> np.ndarray:
    """REP-103 poses ``T_odom_base (N, 4, 4)`` of a level vehicle from an optical camera's
    ``T_w_cam`` (x right, y down, z forward; the world the first camera's frame: KITTI's
    poses, most visual odometry and SLAM outputs), the camera ``camera_height`` metres above
    the ``base_link`` origin: how `import_kitti` writes the ground truth."""
    T_bc = mount_transform(height=camera_height)
    return T_bc @ poses_cam @ invert(T_bc)


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """Axis * angle ``(N, 3)`` of rotations ``(N, 3, 3)`` (via quaternions: stable near 0)."""
    q = quaternion_from_rotation(R)
    v, w = q[:, :3], q[:, 3]
    s = np.linalg.norm(v, axis=1)
    angle = 2.0 * np.arctan2(s, w)
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return v * scale[:, None]


def kitti_ground_truth(poses_cam: np.ndarray, stamps_ns: np.ndarray, camera_height: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """REP-103 poses ``T_odom_base (N, 4, 4)`` and body twists ``(N, 6)`` from KITTI poses.

    Args:
        poses_cam: ``(N, 4, 4)`` ``T_w_cam`` (KITTI ``poses.txt``).
        stamps_ns: ``(N,)`` increasing integer ns.
        camera_height: metres of the camera above the ground (``base_link`` origin).
    """
    poses = camera_to_vehicle(poses_cam, camera_height)
    twists = np.zeros((len(poses), 6))
    if len(poses) > 1:
        rel = invert(poses[:-1]) @ poses[1:]                    # T_prev_cur
        # From the integer differences: float64 nanoseconds near 1.7e18 hold 256 ns (a user
        # test: frames 1 ns apart divided by zero).
        dt = np.diff(np.asarray(stamps_ns, dtype=np.int64)).astype(np.float64) / 1e9
        # displacement in the current frame: R_cur^T (p_cur - p_prev) = R_rel^T t_rel
        v = np.einsum('nji,nj->ni', rel[:, :3, :3], rel[:, :3, 3]) / dt[:, None]
        w = _rotation_vector(rel[:, :3, :3]) / dt[:, None]   # same axis in both frames
        twists[1:] = np.hstack([v, w])
        twists[0] = twists[1]
    return poses, twists


def import_kitti(folder: str | Path, out_path: str | Path, *, storage: str = 'mcap',
                 camera_height: float = 1.65, rate_hz: float | None = None,
                 start: float | str | Decimal | None = None, camera_frame: str = 'camera',
                 odom_frame: str = 'odom', base_frame: str = 'base_link',
                 progress: bool = False) -> KittiImportSummary:
    """Write a KITTI odometry sequence folder as a ROS 2 bag.

    Args:
        folder: the sequence folder (see the module docstring).
        out_path: bag directory to create (must not exist).
        storage: ``'mcap'`` or ``'sqlite3'``.
        camera_height: camera height above the ground in metres (KITTI: 1.65).
        rate_hz: stamp frames at this rate instead of ``times.txt``.
        start: seconds added to every time so the bag starts at a plausible epoch
            (default 1.7e9 s).
        camera_frame, odom_frame, base_frame: frame ids of the messages.
        progress: show a progress bar on stderr.

    Raises:
        InputError: a malformed sequence folder or bad arguments; an image found bad (unreadable
            or of another size) mid-way leaves nothing at `out_path` either.
        BagError: `out_path` exists (nothing touched) or cannot be written.
    """
    from tqdm import tqdm

    camera_height = positive_number('camera_height', camera_height,
                                    'a positive height in metres')
    if not 0.01 <= camera_height <= 100.0:
        # (a user test: 1e9 m was imported, and the replay command it suggests refused it)
        raise InputError(f'camera_height: expected a height above the ground of 0.01-100 m '
                         f'(the range of mount.height), got {camera_height:g}')
    if rate_hz is not None:
        rate_hz = frame_rate('rate_hz', rate_hz)
    try:
        start_ns = seconds_to_ns(DEFAULT_START if start is None else start)
    except InputError:
        raise InputError(f'start: expected a number of seconds, got {start!r}') from None
    seq = read_kitti_sequence(folder, need_times=rate_hz is None)
    n = len(seq.images)
    stamps = _stamps(seq, rate_hz, start_ns)
    first = _read_png(seq.images[0])
    height, width = first.shape
    try:
        camera = CameraModel(width, height, seq.P0[:, :3])
        # The checks the node makes of the CameraInfo (a user test: fx 1 px was imported
        # without a word, and every frame of the bag then refused).
        camera.check_plausible()
    except CameraModelError as err:
        raise InputError(f'calib.txt: P0 does not hold valid intrinsics ({err})') from err
    if seq.poses is not None:
        gt_poses, gt_twists = kitti_ground_truth(seq.poses, stamps, camera_height)
        if not np.all(np.isfinite(gt_twists)):
            i = int(np.flatnonzero(~np.all(np.isfinite(gt_twists), axis=1))[0])
            raise InputError(f'{seq.poses_path.name}: the ground-truth velocity at frame {i} is '
                             f'not finite (poses too far apart for their stamps)')

    with CameraBagWriter(out_path, storage=storage, ground_truth=seq.poses is not None,
                         camera_frame=camera_frame, odom_frame=odom_frame,
                         base_frame=base_frame) as writer:
        writer.expected = n
        try:
            for i, path in enumerate(tqdm(seq.images, desc='import', unit='frame',
                                          file=sys.stderr, disable=not progress, leave=False)):
                image = first if i == 0 else _read_png(path)
                if image.shape != (height, width):
                    raise InputError(f"images: expected every image {width}x{height}, got "
                                     f"{image.shape[1]}x{image.shape[0]} for '{path.name}'")
                writer.write_frame(int(stamps[i]), image, camera, projection=seq.P0,
                                   pose=None if seq.poses is None else gt_poses[i],
                                   twist=None if seq.poses is None else gt_twists[i])
        except InputError:
            # A bag of the frames before a bad image would pass for the whole sequence.
            writer.discard(f'removed: {writer.frames} of {n} frames were written before the '
                           f'bad image')
            raise
    return KittiImportSummary(Path(out_path), n, camera, seq.poses is not None, int(stamps[0]),
                              int(stamps[-1]), seq.poses_path, seq.poses_sought)


def _read_png(path: Path) -> np.ndarray:
    try:
        return read_image(path)
    except ImageError as err:
        raise InputError(f'images: {err}') from err


def _seconds(ns: int) -> str:
    """Integer ns as seconds for messages: exact up to 1e15 s (``1700000000.1``, ``-5``), then
    ``1e+30`` (no float overflow for any size)."""
    seconds = Decimal(ns).scaleb(-9).normalize()
    return f'{seconds:f}' if abs(seconds) < 10**15 else f'{seconds:g}'


def _stamps(seq: KittiSequence, rate_hz: float | None, start_ns: int) -> np.ndarray:
    """Integer ns stamps of the frames: ``times.txt`` (or ``i / rate_hz``) plus `start_ns`.

    Raises:
        InputError: a stamp outside what a ROS time stamp holds (1970 to 2038), or two frames
            less than 1 ns apart (e.g. an absurd frame rate); nothing has been written then.
    """
    if rate_hz is not None:
        source = f'the rate {rate_hz!r} Hz'
        period_ns = Decimal(1_000_000_000) / Decimal(repr(rate_hz))
        offsets = [int((i * period_ns).to_integral_value()) for i in range(len(seq.images))]
    else:
        source = 'times.txt'
        offsets = [seconds_to_ns(t) for t in seq.times]
    stamps = [start_ns + t for t in offsets]
    if min(stamps) < 0 or max(stamps) > MAX_STAMP_NS:
        raise InputError(f'stamps: {source} plus start gives {_seconds(min(stamps))} to '
                         f'{_seconds(max(stamps))} s, outside the range of a ROS time stamp '
                         f'(0 to {_seconds(MAX_STAMP_NS)} s: 1970 to 2038); check times.txt, '
                         f'--rate-hz and --start')
    for i in range(1, len(stamps)):
        if stamps[i] <= stamps[i - 1]:
            raise InputError(f'stamps: {source} gives frames {i - 1} and {i} the same stamp '
                             f'{stamps[i]} ns; frames must be at least 1 ns apart')
    return np.array(stamps, dtype=np.int64)
