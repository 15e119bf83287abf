"""Camera frames from a bag: decoded images with their stamps and the current camera model.

One bad image or CameraInfo never stops the stream: a frame carries either its image or the
reason it could not be decoded, and a CameraInfo that cannot be parsed is reported on the next
frame (the last good camera model stays in use).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.errors import BagError, CameraModelError, ImageError
from planar_vo.io.reader import BagMessage, BagReader
from planar_vo.pipeline.clock import Stamp
from planar_vo.ros.messages import (
    compressed_to_array,
    image_to_array,
    stamp_problem,
    stamp_to_ns,
)

__all__ = [
    'CAMERA_INFO_TYPE',
    'COMPRESSED_IMAGE_TYPE',
    'IMAGE_TYPE',
    'CameraFrame',
    'CameraFrameDecoder',
    'iter_camera_frames',
]

log = logging.getLogger(__name__)

IMAGE_TYPE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE_TYPE = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO_TYPE = 'sensor_msgs/msg/CameraInfo'


@dataclass(frozen=True)
class CameraFrame:
    """One image message of a bag.

    Attributes:
        index: position of the image message on its topic (0-based).
        topic: the image topic.
        log_time_ns: bag receive time (ns).
        stamp_ns: ``header.stamp`` in integer ns (the log time if the header is undecodable).
        frame_id: ``header.frame_id``.
        image: ``(H, W)`` uint8 grey pixels, or None when the message could not be decoded.
        error: why the image could not be decoded (None when ``image`` is set).
        camera: the latest valid camera model from the CameraInfo topic (before the first
            CameraInfo message: the first valid one; None if the bag has none).
        camera_error: a CameraInfo received since the previous frame that could not be parsed.
        bad_stamp: the header stamp is not a ROS time (negative, ``nanosec`` of a second or
            more, beyond 2038): ``error`` says so and ``image`` is None.
    """

    index: int
    topic: str
    log_time_ns: int
    stamp_ns: int
    frame_id: str
    image: np.ndarray | None
    error: str | None = None
    camera: CameraModel | None = None
    camera_error: str | None = None
    bad_stamp: bool = False

    @property
    def stamp(self) -> Stamp:
        """Header stamp in seconds, keeping its nanoseconds (a `Stamp`, a float)."""
        return Stamp(self.stamp_ns)


class CameraFrameDecoder:
    """Turns the image and CameraInfo messages of a bag into `CameraFrame` s, in stream order.

    Used by `iter_camera_frames` and by replay (which interleaves other topics in one pass).
    ``mono16_shift``: the right shift of 16-bit grey images to 8 bits (``camera.mono16_bits -
    8``); ``rectified``: rectified images, whose model is CameraInfo's ``P``
    (`CameraModel.from_camera_info`, ``camera.rectified``).
    """

    def __init__(self, bag: BagReader, image_topic: str, camera_info_topic: str | None,
                 mono16_shift: int = 8, rectified: bool = False) -> None:
        self.bag = bag
        self.mono16_shift = mono16_shift
        self.rectified = rectified
        self.image_topic = image_topic
        self.camera_info_topic = camera_info_topic
        self.camera: CameraModel | None = None
        self.camera_errors = 0
        self._pending_camera_error: str | None = None
        self._index = 0

    def prime(self) -> None:
        """Start from the bag's first valid CameraInfo, so images recorded just before it (a
        camera driver publishes both with one stamp, in either order) are not left without."""
        if self.camera_info_topic is None:
            return
        for message in self.bag.messages([self.camera_info_topic]):
            try:
                self.camera = self._model(message)
                return
            except (BagError, CameraModelError):
                continue

    def _model(self, message: BagMessage) -> CameraModel:
        return CameraModel.from_camera_info(self.bag.deserialize(message),
                                            rectified=self.rectified)

    def feed(self, message: BagMessage) -> CameraFrame | None:
        """A frame for an image message; None for a CameraInfo (which updates the camera)."""
        if message.topic == self.camera_info_topic:
            self._update_camera(message)
            return None
        if message.topic == self.image_topic:
            return self._decode(message)
        return None

    def _update_camera(self, message: BagMessage) -> None:
        try:
            self.camera = self._model(message)
        except (BagError, CameraModelError) as err:
            self.camera_errors += 1
            self._pending_camera_error = f'camera_info at {message.log_time_ns} ns: {err}'
            if self.camera_errors == 1:           # `camera_errors` counts them all
                log.warning('ignoring %s (further bad camera_info messages are counted, not '
                            'logged)', self._pending_camera_error)

    def _decode(self, message: BagMessage) -> CameraFrame:
        stamp_ns, frame_id = message.log_time_ns, ''
        image, error, bad_stamp = None, None, False
        try:
            msg = self.bag.deserialize(message)
            stamp_ns, frame_id = stamp_to_ns(msg.header.stamp), str(msg.header.frame_id)
            problem = stamp_problem(msg.header.stamp)
            if problem:
                # (a user test: a first frame stamped -1 s aborted the replay when its odometry
                # was written; nanosec 4e9 read as 4 s later)
                bad_stamp = True
                raise BagError(problem)
            if message.msgtype == COMPRESSED_IMAGE_TYPE:
                image = compressed_to_array(msg, mono16_shift=self.mono16_shift)
            else:
                image = image_to_array(msg, mono16_shift=self.mono16_shift)
        except (BagError, ImageError) as err:
            error = str(err)
        frame = CameraFrame(self._index, message.topic, message.log_time_ns, stamp_ns, frame_id,
                            image, error, self.camera, self._pending_camera_error, bad_stamp)
        self._index += 1
        self._pending_camera_error = None
        return frame


def resolve_camera_topics(bag: BagReader, image_topic: str | None,
                          camera_info_topic: str | None) -> tuple[str, str | None]:
    """The image topic (given or the only Image/CompressedImage topic) and the CameraInfo topic
    (given, the only one, the one next to the image topic, or None when the bag has none)."""
    image_topic = bag.find_topic('image_topic', image_topic, (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE))
    info = bag.find_topic('camera_info_topic', camera_info_topic, (CAMERA_INFO_TYPE,),
                          required=False, near=image_topic)
    return image_topic, info


def iter_camera_frames(bag: BagReader, image_topic: str | None = None,
                       camera_info_topic: str | None = None) -> Iterator[CameraFrame]:
    """Every image message of a bag as a `CameraFrame`, in log-time order.

    Args:
        bag: an open bag (`open_bag`).
        image_topic: a ``sensor_msgs/Image`` or ``CompressedImage`` topic; None picks the only
            one (`BagError` listing them if there are several, or naming the topics if none).
        camera_info_topic: a ``sensor_msgs/CameraInfo`` topic; None picks the only one (or the
            one in the image topic's namespace); frames carry ``camera=None`` if there is none.
            Each frame has the latest CameraInfo logged before it; frames before the first carry
            the first valid one.

    Raises:
        BagError: unknown/ambiguous topics, or a storage failure mid-way (frames yielded before
            stay valid). A single undecodable image or CameraInfo does not raise.
    """
    image_topic, info = resolve_camera_topics(bag, image_topic, camera_info_topic)
    decoder = CameraFrameDecoder(bag, image_topic, info)
    decoder.prime()
    for message in bag.messages([image_topic] + ([info] if info else [])):
        frame = decoder.feed(message)
        if frame is not None:
            yield frame
