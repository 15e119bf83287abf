"""Writing camera drives as ROS 2 bags: images, camera info, ground truth and a speed topic.

Used by ``planar_vo import-kitti`` and by the recorder of rendered drives
(`planar_vo.tools.record`), so that both produce bags with the same topics:

- ``/camera/image_raw`` (``sensor_msgs/Image``, mono8) and ``/camera/camera_info``;
- ``/ground_truth/odom`` (``nav_msgs/Odometry``, REP-105 ``odom -> base_link``) when known;
- ``/speed`` (``geometry_msgs/TwistStamped``, the vehicle's velocity in base_link) when known.
"""

from __future__ import annotations

from decimal import Decimal

import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.checks import positive_number
from planar_vo.errors import InputError
from planar_vo.io.images import CAMERA_INFO_TYPE, IMAGE_TYPE
from planar_vo.io.outputs import deferred_interrupts
from planar_vo.io.reader import TYPESTORE
from planar_vo.io.writer import ODOMETRY_TYPE, BagWriter, check_stamp_ns
from planar_vo.ros.messages import ns_to_stamp_fields

__all__ = [
    'CAMERA_INFO_TOPIC',
    'DEFAULT_START',
    'GROUND_TRUTH_TOPIC',
    'IMAGE_TOPIC',
    'PARTIAL_KEY',
    'SPEED_TOPIC',
    'CameraBagWriter',
    'frame_rate',
]

IMAGE_TOPIC = '/camera/image_raw'
CAMERA_INFO_TOPIC = '/camera/camera_info'
GROUND_TRUTH_TOPIC = '/ground_truth/odom'
SPEED_TOPIC = '/speed'
# metadata.yaml custom data of an import stopped by an interrupt: 'F of N frames (...)'
PARTIAL_KEY = 'planar_vo.partial'
# The frame rates (Hz) an import takes: a camera's, from a time-lapse to a high-speed one.
FRAME_RATE_RANGE = (0.01, 1000.0)


def frame_rate(name: str, value) -> float:
    """A frame rate an import is given (Hz) as a float, or `InputError` naming ``name``:
    finite, within `FRAME_RATE_RANGE` (a user test: 1e9 Hz was imported, and replayed as
    steps 1 ns apart at 1e9 m/s)."""
    lo, hi = FRAME_RATE_RANGE
    rate = positive_number(name, value, f'a camera frame rate of {lo:g}-{hi:g} Hz')
    if not lo <= rate <= hi:
        raise InputError(f'{name}: expected a camera frame rate of {lo:g}-{hi:g} Hz, got '
                         f'{value!r}')
    return rate


# Seconds added to drives whose own times start at 0 (KITTI, rendered), so that bags start at a
# plausible epoch.
DEFAULT_START = Decimal('1700000000')
TWIST_STAMPED_TYPE = 'geometry_msgs/msg/TwistStamped'


class CameraBagWriter(BagWriter):
    """A new bag of camera frames (context manager; never overwrites).

    Args:
        path: bag directory to create.
        storage: ``'mcap'`` or ``'sqlite3'``.
        ground_truth: also register ``/ground_truth/odom``.
        camera_info: register ``/camera/camera_info`` (False: frames are written without
            intrinsics, ``camera=None``).
        speed: also register ``/speed``.
        camera_frame, odom_frame, base_frame: frame ids.

    Attributes:
        frames: frames written (each whole: an interrupt waits for its last message).
        expected: the frames the source holds (an import sets it; None: unknown). A bag kept
            with fewer, because an interrupt stopped the import (with the count unknown, any
            bag an interrupt stopped), says so in its outcome and in its ``metadata.yaml``
            (custom data ``planar_vo.partial``, which replay reports and passes on to its
            odometry bag, and eval then reports).
    """

    def __init__(self, path, *, storage: str = 'mcap', ground_truth: bool = False,
                 speed: bool = False, camera_frame: str = 'camera', odom_frame: str = 'odom',
                 base_frame: str = 'base_link', camera_info: bool = True) -> None:
        super().__init__(path, storage=storage)
        self._camera_info = camera_info
        self._ground_truth = ground_truth
        self._speed = speed
        self.camera_frame, self.odom_frame, self.base_frame = camera_frame, odom_frame, base_frame
        self.frames = 0
        self.expected: int | None = None
        self._interrupted = False

    @property
    def partial(self) -> str:
        """``'F of N frames'`` when fewer frames than `expected` were written (``'F frames'``
        when the source's count is unknown, a video's, and the import was interrupted), else
        empty."""
        if self.expected is None:
            return f'{self.frames} frames' if self._interrupted else ''
        if self.frames >= self.expected:
            return ''
        return f'{self.frames} of {self.expected} frames'

    @property
    def outcome(self) -> str:
        text = super().outcome
        if self.kept and self.partial:
            text += f' ({self.partial}: the rest were not imported)'
        return text

    def __exit__(self, exc_type, exc, tb) -> None:
        self._interrupted = isinstance(exc, KeyboardInterrupt)
        if self._interrupted and self.partial:
            # (a user test: a bag cut short by Ctrl-C looked like a complete import, to replay
            # and eval alike)
            self.custom_data[PARTIAL_KEY] = f'{self.partial} (the import was interrupted)'
        super().__exit__(exc_type, exc, tb)

    def open(self) -> None:
        super().open()
        if self._camera_info:
            self.add_topic(CAMERA_INFO_TOPIC, CAMERA_INFO_TYPE)
        self.add_topic(IMAGE_TOPIC, IMAGE_TYPE)
        if self._ground_truth:
            self.add_topic(GROUND_TRUTH_TOPIC, ODOMETRY_TYPE)
        if self._speed:
            self.add_topic(SPEED_TOPIC, TWIST_STAMPED_TYPE)

    @staticmethod
    def _camera_info_message(header, size: tuple[int, int], camera: CameraModel,
                             projection: np.ndarray | None):
        t = TYPESTORE.types
        height, width = size
        P = np.column_stack([camera.K, np.zeros(3)]) if projection is None else projection
        model = 'plumb_bob' if camera.distortion_model == 'none' else camera.distortion_model
        d = np.zeros(5) if camera.distortion_model == 'none' else np.asarray(camera.D, float)
        return t[CAMERA_INFO_TYPE](
            header=header, height=height, width=width, distortion_model=model,
            d=d, k=camera.K.reshape(9).copy(), r=np.eye(3).reshape(9),
            p=np.asarray(P, float).reshape(12).copy(), binning_x=0, binning_y=0,
            roi=t['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0,
                                                      do_rectify=False))

    def write_frame(self, stamp_ns: int, image: np.ndarray, camera: CameraModel | None, *,
                    projection: np.ndarray | None = None, pose: np.ndarray | None = None,
                    twist: np.ndarray | None = None) -> None:
        """Write one frame: camera info first (a reader then has it for the image), the image,
        and the ground truth and speed when given.

        Args:
            stamp_ns: header stamp and log time in integer ns (`check_stamp_ns`: 1970 to 2038).
            image: 8-bit grey image ``(H, W)`` of the camera's size.
            camera: its camera model (intrinsics and distortion); None (only with
                ``camera_info=False``) writes no CameraInfo.
            projection: the 3x4 ``P`` of CameraInfo (default ``[K | 0]``).
            pose: ground-truth ``T_odom_base`` (needs ``ground_truth=True``).
            twist: ground-truth body velocity ``(vx, vy, vz, wx, wy, wz)``; also written as the
                ``/speed`` TwistStamped when ``speed=True``.
        """
        with deferred_interrupts():         # a frame is written whole, or not at all
            self._write_frame(stamp_ns, image, camera, projection, pose, twist)

    def _write_frame(self, stamp_ns, image, camera, projection, pose, twist) -> None:
        t = TYPESTORE.types
        height, width = image.shape
        stamp_ns = check_stamp_ns('stamp', stamp_ns)
        sec, nanosec = ns_to_stamp_fields(stamp_ns)
        stamp = t['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
        header = t['std_msgs/msg/Header'](stamp=stamp, frame_id=self.camera_frame)
        if (camera is None) == self._camera_info:
            raise ValueError('write_frame: a camera model exactly when the bag has CameraInfo')
        if camera is not None:
            self.write_message(CAMERA_INFO_TOPIC, int(stamp_ns),
                               self._camera_info_message(header, image.shape, camera, projection))
        msg = t[IMAGE_TYPE](header=header, height=height, width=width, encoding='mono8',
                            is_bigendian=0, step=width,
                            data=np.ascontiguousarray(image).reshape(-1))
        self.write_message(IMAGE_TOPIC, int(stamp_ns), msg)
        if pose is not None and self._ground_truth:
            self.write_odometry(GROUND_TRUTH_TOPIC, int(stamp_ns), pose,
                                odom_frame=self.odom_frame, base_frame=self.base_frame,
                                twist=twist)
        if twist is not None and self._speed:
            vec = t['geometry_msgs/msg/Vector3']
            speed_msg = t[TWIST_STAMPED_TYPE](
                header=t['std_msgs/msg/Header'](stamp=stamp, frame_id=self.base_frame),
                twist=t['geometry_msgs/msg/Twist'](linear=vec(x=float(twist[0]),
                                                              y=float(twist[1]),
                                                              z=float(twist[2])),
                                                   angular=vec(x=float(twist[3]),
                                                               y=float(twist[4]),
                                                               z=float(twist[5]))))
            self.write_message(SPEED_TOPIC, int(stamp_ns), speed_msg)
        self.frames += 1
