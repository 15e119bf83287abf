"""A video file or a folder of images (a dashcam's, a phone's) as a ROS 2 bag.

`import_video` writes ``/camera/image_raw`` (``sensor_msgs/Image``, mono8) at the video's frame
rate (or ``rate_hz``) and, only when the intrinsics are given, ``/camera/camera_info``: a camera
of unknown focal length is replayed with the focal self-calibration (``camera.estimate_focal``),
and a CameraInfo made up here would be a wrong calibration the replay believed.

Stamps are ``start`` plus each frame's presentation time in a video (a phone records at a
variable rate), or its index over the frame rate for a folder of images or a given rate; a
subsampled import (``every``) keeps the source's timing.
"""

from __future__ import annotations

import logging
import dataclasses
import math
import os
import re
import sys
from collections.abc import Callable, Iterator
from decimal import Decimal
from pathlib import Path

import cv2
import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.errors import CameraModelError, ImageError, InputError, plural
from planar_vo.frontend.images import MIN_IMAGE_SIZE, read_image
from planar_vo.io.camera_bag import (
    CAMERA_INFO_TOPIC,
    DEFAULT_START,
    IMAGE_TOPIC,
    CameraBagWriter,
    frame_rate,
)
from planar_vo.io.writer import MAX_STAMP_NS
from planar_vo.ros.messages import seconds_to_ns

log = logging.getLogger(__name__)

__all__ = ['IMAGE_SUFFIXES', 'VideoImportSummary', 'frame_size', 'import_video']

# Image files a folder source may hold (what `read_image` decodes), matched case-insensitively.
IMAGE_SUFFIXES = ('.png', '.jpg', '.jpeg')
# FFmpeg's own messages ('moov atom not found', a damaged packet) would come before and between
# the command's lines; what they mean is said once (the file cannot be opened; fewer frames
# decoded than the video states). OpenCV reads this when its first capture opens; a value the
# user set wins (e.g. 24 for FFmpeg's warnings).
os.environ.setdefault('OPENCV_FFMPEG_LOGLEVEL', '-8')
# A video must decode all but at most this many of the frames its container states, where the
# container counts them (MP4 and MOV sample tables, the AVI index); Matroska, WebM and MPEG-TS
# state an estimate from the duration, wrong for a variable rate (a review). Where a frame was
# lost cannot be told (OpenCV's times and positions count the decoded frames), and every frame
# after a lost one would be stamped a frame period early: a share of the count (98 %, as
# before) kept 77 of 80 frames with a damaged part, stamped 0.3 s early after it (a user test).
# The slack is for a count an end's rounding makes one or two too high.
_MISSING_FRAMES = 2
_COUNTED_SUFFIXES = ('.mp4', '.m4v', '.mov', '.3gp', '.avi')
# The file names FFmpeg's 'tty' format (text rendered as video) claims.
_TEXT_SUFFIXES = ('.txt', '.asc', '.nfo', '.ans', '.art', '.diz', '.ice', '.vt')
# A frame rate a container states beyond this is not believed (some write 1000 or 90000 for
# "unknown").
_MAX_PLAUSIBLE_FPS = 500.0


@dataclasses.dataclass(frozen=True)
class VideoImportSummary:
    """What `import_video` wrote.

    Attributes:
        path: the bag; source: the video file or image folder; kind: ``'video'`` or
        ``'images'``.
        frames: frames written; read: frames read from the source (``every`` keeps one in so
            many); stated_frames: the count the video's container states (None: not stated, or
            a folder).
        width, height: the written images' size; scale: written over source width.
        rate_hz: the source's frame rate the stamps follow; rate_source: where it came from.
        camera: the intrinsics written as CameraInfo (at the written size), or None.
        first_stamp_ns, last_stamp_ns: the first and last stamps.
        every: one frame in so many was kept.
    """

    path: Path
    source: Path
    kind: str
    frames: int
    read: int
    stated_frames: int | None
    width: int
    height: int
    scale: float
    rate_hz: float
    rate_source: str
    camera: CameraModel | None
    first_stamp_ns: int
    last_stamp_ns: int
    every: int = 1

    def format(self) -> str:
        duration = (self.last_stamp_ns - self.first_stamp_ns) / 1e9
        size = f'{self.width}x{self.height}'
        if self.scale != 1.0:
            size += f', shrunk {self.scale:.4g}x'
        kept = (f'{self.frames} of {self.read} frames' if self.read != self.frames
                else plural(self.frames, 'frame'))
        rate = f'the {self.rate_source} {self.rate_hz:g} Hz'
        if self.every > 1:
            rate += f', every {_ordinal(self.every)} frame: {self.rate_hz / self.every:.4g} Hz'
        lines = [f'wrote {kept} ({size}, {duration:.2f} s at {rate}) to {self.path}: '
                 f'{IMAGE_TOPIC}'
                 + (f', {CAMERA_INFO_TOPIC} (fx {self.camera.fx:.2f})' if self.camera else
                    ' (no CameraInfo: intrinsics not given)')]
        if self.stated_frames is not None and self.stated_frames != self.read:
            # Within the tolerance of a counted container, or an estimated count.
            lines.append(f'note: the video states {self.stated_frames} frames; '
                         f'{self.read} could be decoded')
        return '\n'.join(lines)


def _ordinal(n: int) -> str:
    return f'{n}{"th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")}'


def _natural_key(path: Path) -> list:
    """Sort key that orders ``frame2`` before ``frame10`` (digit runs compared as numbers)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r'(\d+)', path.name)]


def _folder_images(folder: Path) -> list[Path]:
    # Hidden files are not frames (macOS leaves '._0001.jpg' beside each image on an SD card).
    images = sorted((p for p in folder.iterdir() if p.is_file() and not p.name.startswith('.')
                     and p.suffix.lower() in IMAGE_SUFFIXES), key=_natural_key)
    if not images:
        raise InputError(f"source: no image files ({', '.join(IMAGE_SUFFIXES)}) in folder "
                         f"'{folder}'")
    _check_numbering(folder, images)
    return images


def _check_numbering(folder: Path, images: list[Path]) -> None:
    """`InputError` for numbered frames with one missing: names that differ only in their last
    run of digits (``frame_0007.png``) must number the frames at one steady step (1, or 2 for a
    folder of every other frame), since the frames are stamped at the given rate by their
    order and a missing one would stamp every later frame early (a user test; as
    `planar_vo.io.kitti.read_kitti_sequence` refuses it)."""
    parts = [re.fullmatch(r'(.*\D)?(\d+)(\D*)', p.name) for p in images]
    if len(images) < 2 or not all(parts):
        return
    if len({(m.group(1) or '', m.group(3).lower()) for m in parts}) != 1:
        return                                  # not one numbered series
    numbers = [int(m.group(2)) for m in parts]
    steps = [b - a for a, b in zip(numbers, numbers[1:])]
    step = min(steps)
    if step > 2:
        return          # not frame numbers (a review: names that are time stamps)
    if step == 0:
        i = steps.index(0)
        raise InputError(f"source: '{images[i].name}' and '{images[i + 1].name}' in '{folder}' "
                         f'both number frame {numbers[i]}')
    for i, gap in enumerate(steps):
        if gap != step:
            digits = parts[i + 1].group(2)
            width = len(digits) if digits.startswith('0') else 0
            m = parts[i + 1]
            missing = f"{m.group(1) or ''}{numbers[i] + step:0{width}d}{m.group(3)}"
            raise InputError(f"source: '{missing}' is missing from '{folder}' (the frames are "
                             f'numbered {numbers[0]}, {numbers[0] + step}, ... at steps of '
                             f"{step}; the next there is '{images[i + 1].name}'): the frames "
                             f'after a missing one would be stamped early; import the frames '
                             f'up to it, or rename them')


def _gray(frame: np.ndarray) -> np.ndarray:
    """A decoded video frame (8-bit BGR) or image file (already grey) as 8-bit grey."""
    if frame.ndim == 3:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    return frame


class _Video:
    """Frames of a video file through OpenCV's FFmpeg back-end."""

    def __init__(self, path: Path) -> None:
        if path.suffix.lower() in IMAGE_SUFFIXES:
            raise InputError(f"source: '{path}' is an image; give the folder of the images "
                             f'(with --rate-hz)')
        if path.suffix.lower() in _TEXT_SUFFIXES:
            # FFmpeg's 'tty' format renders a text file as a video (a user test). By name
            # only: Y4M video and ffconcat playlists are text too, and a pipe must not be read
            # before FFmpeg opens it (a review).
            raise InputError(f"source: '{path}' is a text file, not a video")
        self.capture = cv2.VideoCapture(str(path))
        if not self.capture.isOpened():
            raise InputError(f"source: cannot open '{path}' as a video (not a video file, or a "
                             f'format this OpenCV build does not decode)')
        fps = float(self.capture.get(cv2.CAP_PROP_FPS))
        self.fps = fps if math.isfinite(fps) and 0 < fps <= _MAX_PLAUSIBLE_FPS else None
        count = float(self.capture.get(cv2.CAP_PROP_FRAME_COUNT))
        self.stated = int(count) if math.isfinite(count) and count > 0 else None

    def __iter__(self) -> Iterator[tuple[str, np.ndarray, float | None]]:
        """``(name, frame, presentation time in ms or None)`` of every frame decoded."""
        index = 0
        try:
            while True:
                ok, frame = self.capture.read()
                if not ok:
                    return
                ms = float(self.capture.get(cv2.CAP_PROP_POS_MSEC))
                yield f'frame {index}', frame, ms if math.isfinite(ms) else None
                index += 1
        finally:
            self.capture.release()


def _images(paths: list[Path]) -> Iterator[tuple[str, np.ndarray, None]]:
    for path in paths:
        try:
            yield f"'{path.name}'", read_image(path), None
        except ImageError as err:
            raise InputError(f'source: {err}') from err


@dataclasses.dataclass
class _Source:
    """An opened source: its frames ``(name, frame, time in ms or None)``, their count (the
    folder's images, or what the video states; None: not stated) and the video's own rate."""

    kind: str
    frames: Iterator[tuple[str, np.ndarray, float | None]]
    count: int | None
    fps: float | None
    close: Callable[[], None]


def _open_source(source: Path) -> _Source:
    if not source.exists():
        raise InputError(f"source: '{source}' does not exist")
    if source.is_dir():
        paths = _folder_images(source)
        return _Source('images', _images(paths), len(paths), None, lambda: None)
    video = _Video(source)
    return _Source('video', iter(video), video.stated, video.fps, video.capture.release)


def frame_size(source: str | Path) -> tuple[int, int]:
    """``(width, height)`` of the first frame of a video file or image folder (`import_video`'s
    sources; the same errors)."""
    opened = _open_source(Path(source))
    try:
        for _, frame, _ in opened.frames:
            return frame.shape[1], frame.shape[0]
    finally:
        opened.close()
    raise InputError(f"source: no frame could be decoded from '{source}'")


def import_video(source: str | Path, out_path: str | Path, *, storage: str = 'mcap',
                 rate_hz: float | None = None, every: int = 1, max_width: int | None = None,
                 camera: CameraModel | None = None, start: float | str | Decimal | None = None,
                 camera_frame: str = 'camera', progress: bool = False) -> VideoImportSummary:
    """Write a video file or a folder of images as a ROS 2 bag of grey frames.

    Args:
        source: a video file (what OpenCV's FFmpeg decodes: MP4, MOV, AVI, MKV...) or a folder
            of PNG/JPEG images, taken in natural name order (``2.png`` before ``10.png``).
        out_path: bag directory to create (must not exist).
        storage: ``'mcap'`` or ``'sqlite3'``.
        rate_hz: the source's frame rate; required for a folder, overrides a video's own.
        every: keep one frame in ``every`` (a 30 Hz dashcam at ``every=3`` is 10 Hz).
        max_width: shrink wider frames to this width (area interpolation; the intrinsics
            follow); None keeps the size.
        camera: the source's intrinsics at its own size, written as CameraInfo; None writes
            none (replay with ``camera.estimate_focal: true``, or ``camera.fx`` set).
        start: seconds of the first frame's stamp (default 1.7e9 s).
        camera_frame: the images' frame id.
        progress: a progress bar on stderr.

    Raises:
        InputError: a missing or unreadable source, a text file or a single image, an empty
            folder, no frame rate, frames of different sizes, fewer than two frames, a video
            with a frame count (MP4, MOV, AVI) decoded to more than 2 frames fewer, bad
            arguments;
            nothing is left at `out_path` then.
        BagError: `out_path` exists (nothing touched) or cannot be written.
    """
    from tqdm import tqdm

    source = Path(source)
    if rate_hz is not None:
        rate_hz = frame_rate('rate_hz', rate_hz)
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise InputError(f'every: expected a whole number of frames >= 1, got {every!r}')
    if max_width is not None and (isinstance(max_width, bool)
                                  or not isinstance(max_width, (int, np.integer))
                                  or max_width < 16):
        raise InputError(f'max_width: expected a width of at least 16 pixels, got {max_width!r}')
    try:
        start_ns = seconds_to_ns(DEFAULT_START if start is None else start)
    except InputError:
        raise InputError(f'start: expected a number of seconds, got {start!r}') from None
    if not 0 <= start_ns <= MAX_STAMP_NS:
        raise InputError(f'start: expected seconds within what a ROS time stamp holds (0 to '
                         f'{MAX_STAMP_NS // 10**9}: 1970 to 2038), got {start!r}')
    opened = _open_source(source)
    kind, frames, total = opened.kind, opened.frames, opened.count
    stated = opened.count if kind == 'video' else None
    if rate_hz is None and opened.fps is None:
        opened.close()
        if kind == 'images':
            raise InputError(f"rate_hz: a folder of images has no frame rate; give the rate "
                             f"the {total} images were taken at")
        raise InputError(f"rate_hz: '{source.name}' states no plausible frame rate; give the "
                         f'rate it was recorded at')
    rate_source = 'given' if rate_hz is not None else "video's"
    rate_hz = rate_hz if rate_hz is not None else opened.fps
    period_ns = Decimal(1_000_000_000) / Decimal(repr(float(rate_hz)))
    if period_ns < 1:
        raise InputError(f'rate_hz: {rate_hz:g} Hz puts frames less than 1 ns apart')

    written = read = 0
    offset_ns: int | None = None
    size = scale = None
    scaled_camera = None
    first_ns = last_ns = start_ns
    bar = tqdm(total=total, desc='import', unit='frame', file=sys.stderr, disable=not progress,
               leave=False)
    try:
        with CameraBagWriter(out_path, storage=storage, camera_frame=camera_frame,
                             camera_info=camera is not None) as writer:
            if kind == 'images':
                writer.expected = -(-total // every)      # every one in `every`, the first on
            try:
                for name, frame, ms in frames:
                    read += 1
                    bar.update(1)
                    # The frame's own time where the video has one (a phone's variable rate
                    # drops to 15-24 Hz in the dark while stating 30), else its index.
                    nominal = int(((read - 1) * period_ns).to_integral_value())
                    if ms is None or rate_source == 'given':
                        offset = nominal
                    else:
                        offset = round(ms * 1e6)
                        if offset_ns is not None and offset <= offset_ns:
                            offset = offset_ns + int(period_ns.to_integral_value())
                    offset_ns = offset
                    if (read - 1) % every:
                        continue
                    image = _gray(frame)
                    if size is None:
                        size = image.shape
                        scale, scaled_camera = _first_frame(image, max_width, camera)
                    elif image.shape != size:
                        raise InputError(f'source: expected every frame {size[1]}x{size[0]}, '
                                         f'got {image.shape[1]}x{image.shape[0]} for {name}')
                    if scale != 1.0:
                        image = cv2.resize(image, _shrunk(size, scale),
                                           interpolation=cv2.INTER_AREA)
                    stamp = start_ns + offset
                    if stamp > MAX_STAMP_NS:
                        raise InputError(f'start: frame {read - 1} would be stamped beyond what'
                                         f' a ROS time stamp holds (2038); give an earlier '
                                         f'--start')
                    writer.write_frame(stamp, image, scaled_camera)
                    written += 1
                    last_ns = stamp
                if written == 0:
                    raise InputError(f"source: no frame could be decoded from '{source}'")
                if (stated is not None and source.suffix.lower() in _COUNTED_SUFFIXES
                        and read < stated - _MISSING_FRAMES):
                    # A damaged part is skipped by the decoder, and the frames after it would
                    # be stamped early (a user test): refused, like a bad image in a folder.
                    raise InputError(f"source: decoded {read} of the {stated} frames "
                                     f"'{source.name}' states: a damaged or truncated video "
                                     f'(the frames after a damaged part would be stamped '
                                     f'wrongly); repair or re-encode it, or import its frames '
                                     f'as images')
                if written == 1:
                    raise InputError(f"source: one frame written from '{source}'; odometry "
                                     f'needs two at least' + (f' (check --every {every})'
                                                              if every > 1 else ''))
            except InputError:
                writer.discard(f'removed: {written} frames were written before the error')
                raise
    finally:
        bar.close()
    width, height = _shrunk(size, scale)
    return VideoImportSummary(Path(out_path), source, kind, written, read, stated, width, height,
                              scale, float(rate_hz), rate_source, scaled_camera, first_ns,
                              last_ns, every)


def _shrunk(size: tuple[int, ...], scale: float) -> tuple[int, int]:
    """``(width, height)`` of a ``(height, width)`` frame shrunk by `scale`."""
    if scale == 1.0:
        return size[1], size[0]
    return max(1, round(size[1] * scale)), max(1, round(size[0] * scale))


def _first_frame(image: np.ndarray, max_width: int | None, camera: CameraModel | None
                 ) -> tuple[float, CameraModel | None]:
    """The shrink factor for the source's size and the intrinsics at the written size."""
    height, width = image.shape
    scale = 1.0 if max_width is None or width <= max_width else max_width / width
    new_w, new_h = _shrunk(image.shape, scale)
    if min(new_w, new_h) < MIN_IMAGE_SIZE:
        # (a user test: --max-width 40 wrote 40x12 frames that replay drops, without a word)
        shrunk = f' (max_width {max_width} shrinks the {width}x{height} source)' \
            if scale != 1.0 else ''
        log.warning('frames of %dx%d pixels%s: the odometry needs at least %dx%d, so replay '
                    'will drop every one as bad_image', new_w, new_h, shrunk, MIN_IMAGE_SIZE,
                    MIN_IMAGE_SIZE)
    if camera is None:
        return scale, None
    if (camera.width, camera.height) != (width, height):
        raise InputError(f'camera: the intrinsics are for {camera.width}x{camera.height} '
                         f'images, the source is {width}x{height}')
    if scale == 1.0:
        return scale, camera
    sx, sy = new_w / width, new_h / height
    K = camera.K.copy()
    # Pixel centres: x' + 0.5 = s (x + 0.5).
    K[0, 0] *= sx
    K[0, 2] = sx * (K[0, 2] + 0.5) - 0.5
    K[1, 1] *= sy
    K[1, 2] = sy * (K[1, 2] + 0.5) - 0.5
    try:
        return scale, CameraModel(new_w, new_h, K, camera.distortion_model, camera.D)
    except CameraModelError as err:
        raise InputError(f'camera: {err}') from err
