"""Offline replay: images of a bag through a frame processor, odometry into a new bag.

The processor is anything with the `FrameProcessor` interface (the pipeline's
``VisualOdometry``): ``process(image, stamp, camera) -> FrameResult`` and
``add_speed(stamp, speed)``. For every image message, in log-time order:

1. speed messages stamped at or before the image's header stamp are fed first;
2. an undecodable image is counted as ``bad_image`` (the processor does not see it);
3. otherwise ``process`` runs; an ``ok`` result, and the first frame's (``first_frame``: the
   origin that sets ``odom``), become a ``nav_msgs/Odometry`` stamped with the image's exact
   header stamp, any other result is counted under its `DropReason`.

The first frame dropped for each reason is logged with the reason's message; further ones are
only counted (in the summary), so that a bag of undecodable images does not log every frame.

Ground-truth-like topics (Odometry, Path, TF, poses) are copied through unchanged, so the output
bag holds estimate and reference for ``planar_vo eval``.
"""

from __future__ import annotations

import bisect
import logging
import os
import sys
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from planar_vo.config import PlanarVoConfig
from planar_vo.core.camera import CameraModel
from planar_vo.errors import (
    BagError,
    ConfigError,
    ImageError,
    InputError,
    OutputError,
    plural,
)
from planar_vo.io.camera_bag import GROUND_TRUTH_TOPIC, PARTIAL_KEY
from planar_vo.io.images import CameraFrame, CameraFrameDecoder, resolve_camera_topics
from planar_vo.io.outputs import deferred_interrupts
from planar_vo.io.reader import BagReader, iter_messages, open_bag
from planar_vo.io.writer import ODOMETRY_TYPE, OdometryBagWriter
from planar_vo.pipeline.clock import GAP_WATCH, GapCounter
from planar_vo.pipeline.road_image import pixels_note
from planar_vo.tools.provenance import bag_custom_data, provenance
from planar_vo.pipeline.types import DropReason, FrameResult, unit_note
from planar_vo.ros.messages import speed_from_message

__all__ = ['COPY_TYPES', 'SPEED_TYPES', 'FrameProcessor', 'ReplaySummary', 'replay_bag']

log = logging.getLogger(__name__)

# Topics of these types are copied to the output by default (ground truth and references).
COPY_TYPES = (
    ODOMETRY_TYPE,
    'nav_msgs/msg/Path',
    'tf2_msgs/msg/TFMessage',
    'geometry_msgs/msg/PoseStamped',
    'geometry_msgs/msg/PoseWithCovarianceStamped',
    'geometry_msgs/msg/TransformStamped',
)
SPEED_TYPES = (
    'geometry_msgs/msg/TwistStamped',
    'geometry_msgs/msg/TwistWithCovarianceStamped',
    ODOMETRY_TYPE,
)
BAD_IMAGE = DropReason.BAD_IMAGE.value
BAD_STAMP = DropReason.BAD_STAMP.value
# Images the bag's index counts that reading skipped (damaged storage): replay's own reason.
UNREADABLE = 'unreadable'


class FrameProcessor(Protocol):
    """What replay drives (``planar_vo.pipeline.VisualOdometry``)."""

    def process(self, image: np.ndarray, stamp: float,
                camera: CameraModel | None) -> FrameResult: ...

    def add_speed(self, stamp: float, speed: float) -> None: ...


@dataclass
class ReplaySummary:
    """Counts and timing of one replay.

    Attributes:
        input, output, tum: the paths involved (``tum`` None if not written).
        image_topic, camera_info_topic, speed_topic: topics used (None: none).
        frames_in: image messages read.
        odometry_out: odometry messages written.
        origins: of those, the first frames of keyframe chains, at the origin (no motion
            estimated; `FrameResult.has_odometry`).
        dropped: frames without odometry, by `DropReason` value (``bad_image`` includes
            undecodable messages).
        copied: messages copied per topic.
        speed_messages: speed messages fed to the processor.
        speed_errors, speed_error: speed messages refused (a non-finite or implausible
            velocity: skipped), and the first one's stamp and reason.
        camera_info_errors: CameraInfo messages that could not be parsed.
        camera_info_unused: why the bag's CameraInfo was not used (configured intrinsics or
            the focal self-calibration, as in the node); empty if it was.
        wall_time: seconds from opening the input to closing the output.
        focal: the focal length in use at the end and where it came from (the processor's
            ``focal_status()``: CameraInfo, configured, or self-calibrated / provisional).
        scale: where the metric scale came from (the processor's ``scale_status()``: the
            camera height of the ground scale, the speed topic, ...); empty if it has none.
        scale_sources: odometry messages by the source of their step length (``ground``,
            ``speed``, ``hold``, ``unit``, ``stationary``, ...).
        road_top_ups: frames whose ground scale asked the front-end for more road ACs (the
            processor's ``road_top_ups``; None if it has none).
        image_road_steps: ground steps measured on the road's pixels where the road ACs were
            too few (the processor's ``image_road_steps``; None if it has none).
        image_road_misses: the road's pixels' scans that found no step, by reason (the
            processor's ``image_road_misses``), and each reason's first message
            (``image_road_examples``).
        why_none: without any motion estimated (no odometry beyond the origin), the most
            frequent drop reason and its first message (empty otherwise).
        unreadable: messages per topic that the bag's index counts but reading skipped
            (damaged storage); the image topic's are also in ``frames_in`` and ``dropped``
            (``unreadable``).
        not_copied: an input topic of the output odometry's name, not copied (empty if none).
        tum_note: what the TUM file leaves out (the poses before the stamps last jumped back: a
            TUM file holds one time base), or empty.
        gaps, missing_frames: intervals of the image stamps far above the usual one, and
            about how many frames they lack (lost before the recording; `GapCounter`, as the
            node counts them).
        partial_input: the input's own record of an import cut short (``'F of N frames (the
            import was interrupted)'``, its ``metadata.yaml``), or empty.
        first_pass: with ``two_pass``, what the first pass did (frames, seconds), else empty.
        carry: a self-calibrated focal length as the settings that start this camera's next
            drive from it (the processor's ``focal_carry()``), else empty.
    """

    input: str
    output: str
    tum: str | None = None
    image_topic: str = ''
    camera_info_topic: str | None = None
    speed_topic: str | None = None
    frames_in: int = 0
    odometry_out: int = 0
    origins: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    copied: dict[str, int] = field(default_factory=dict)
    speed_messages: int = 0
    speed_errors: int = 0
    speed_error: str = ''
    camera_info_errors: int = 0
    camera_info_unused: str = ''
    wall_time: float = 0.0
    focal: str = ''
    scale: str = ''
    scale_sources: dict[str, int] = field(default_factory=dict)
    road_top_ups: int | None = None
    image_road_steps: int | None = None
    image_road_misses: dict[str, int] = field(default_factory=dict)
    image_road_examples: dict[str, str] = field(default_factory=dict)
    why_none: str = ''
    unreadable: dict[str, int] = field(default_factory=dict)
    gaps: int = 0
    missing_frames: int = 0
    not_copied: str = ''
    tum_note: str = ''
    partial_input: str = ''
    first_pass: str = ''
    carry: dict[str, float] = field(default_factory=dict)

    @property
    def motion_out(self) -> int:
        """Odometry messages from an estimated motion (all but the origins)."""
        return self.odometry_out - self.origins

    @property
    def no_motion(self) -> str | None:
        """Why the replay gave no motion (``no motion estimated from N frame(s) (...)``), or
        None when it did (or read no frame)."""
        if not self.frames_in or self.motion_out:
            return None
        why = self.why_none or 'every frame was the first of a keyframe chain'
        return f'no motion estimated from {self.frames_in} frame(s) ({why})'

    @property
    def throughput(self) -> float:
        """Frames per second of wall time."""
        return self.frames_in / self.wall_time if self.wall_time > 0 else float('nan')

    def format(self) -> str:
        """A human-readable multi-line report."""
        dropped = ', '.join(f'{k} {v}' for k, v in sorted(self.dropped.items())) or 'none'
        copied = ', '.join(f'{k} {v}' for k, v in sorted(self.copied.items())) or 'none'
        sources = ', '.join(f'{k} {v}' for k, v in sorted(self.scale_sources.items())) or 'none'
        unreadable = ', '.join(f'{k} {v}' for k, v in sorted(self.unreadable.items()))
        info = self.camera_info_topic or 'none'
        if self.camera_info_unused:
            info += f' not used: {self.camera_info_unused}'
        lines = [
            f'replay {self.input} -> {self.output}',
            *([f'  input              an import cut short: {self.partial_input}']
              if self.partial_input else []),
            f'  image topic        {self.image_topic} (camera info: {info}, speed: '
            f'{self.speed_topic or "none"})',
            f'  frames in          {self.frames_in}' + self._gaps_note(),
            f'  odometry out       {self.odometry_out}' + self._origins_note(),
            f'  dropped            {sum(self.dropped.values())} ({dropped})',
            f'  copied             {copied}' + (
                f'; not {self.not_copied} (the output odometry\'s topic: --odom-topic names '
                f'another)' if self.not_copied else ''),
            *([f'  unreadable         {unreadable} (counted by the bag\'s metadata, not read: '
               f'damaged storage, or a metadata.yaml that counts too many)']
              if self.unreadable else []),
            f'  speed messages     {self.speed_messages}' + (
                f' ({self.speed_errors} refused, the first {self.speed_error})'
                if self.speed_errors else ''),
            f'  camera info errors {self.camera_info_errors}',
            f'  camera             {self.focal or "unknown"}',
            *([f'  first pass         {self.first_pass}'] if self.first_pass else []),
            *(['  carry it over      '
               + ' '.join(f'--set {k}={v:g}' for k, v in self.carry.items())
               + " (this camera's next drive starts from this focal length; the node: -p "
               + ' -p '.join(f'{k}:={v:g}' for k, v in self.carry.items()) + ')']
              if self.carry else []),
            *([f'  scale              {self.scale}'] if self.scale else []),
            f'  step lengths       {sources}'
            + ('' if self.road_top_ups is None else f' (road top-ups {self.road_top_ups}'
               + self._pixels_note() + ')')
            + self._unit_note(),
            f'  wall time          {self.wall_time:.2f} s'
            + (' (both passes)' if self.first_pass else ''),
            f'  throughput         {self.throughput:.1f} frames/s',
        ]
        if self.tum:
            lines.append(f'  TUM trajectory     {self.tum}{self.tum_note}')
        return '\n'.join(lines)

    def _gaps_note(self) -> str:
        """Frames missing from the image stamps (lost before the recording), if any."""
        if not self.gaps:
            return ''
        unreadable = self.unreadable.get(self.image_topic, 0)
        also = ('; the unreadable image leaves one too' if unreadable == 1 else
                f'; the {unreadable} unreadable images leave gaps too' if unreadable else '')
        return (f' ({plural(self.missing_frames, "frame")} missing in '
                f'{plural(self.gaps, "gap")} of the stamps{also})')

    def _pixels_note(self) -> str:
        """The ground steps from the road's pixels and the scans that found none (`'; ...'`,
        empty if neither)."""
        return pixels_note(self.image_road_steps or 0, self.image_road_misses,
                           self.image_road_examples)

    def _unit_note(self) -> str:
        """Steps without a metric length, said in words (a user test: 'unit 50' alone read
        like a success)."""
        note = unit_note(self.scale_sources)
        return f' ({note})' if note else ''

    def _origins_note(self) -> str:
        """What the odometry count holds beyond estimated motion: the origin(s), and why
        nothing else (``why_none``)."""
        notes = []
        if self.origins:
            notes.append("the first frame's among them, at the origin" if self.origins == 1
                         else f"{self.origins} first frames' of keyframe chains among them, at "
                              f"the origin")
        if self.why_none:
            notes.append(f'no motion: {self.why_none}' if self.origins else self.why_none)
        return f' ({"; ".join(notes)})' if notes else ''


def _own_intrinsics(config: PlanarVoConfig) -> str:
    """Why a camera model from CameraInfo would not be used (``''`` if it would): configured
    intrinsics (``camera.fx > 0``) or the focal self-calibration (``camera.estimate_focal``),
    as in the node."""
    if config.camera.fx > 0:
        return f'camera.fx is configured ({config.camera.fx:g} px)'
    if config.camera.estimate_focal:
        return 'camera.estimate_focal is on'
    return ''


def _read_speeds(bag: BagReader, topic: str) -> tuple[list[int], list[float], int, str]:
    """Speed samples (stamp ns, m/s) of a speed topic, sorted by stamp, and the messages
    refused (a non-finite or implausible velocity: skipped, counted and the first one logged, as
    the node does; a user test: one NaN sample of a long drive aborted its replay) with the
    first one's reason."""
    samples, refused, first = [], 0, ''
    for item in iter_messages(bag, topic, SPEED_TYPES, role='speed_topic'):
        try:
            samples.append((item.stamp_ns, speed_from_message(item.msg)))
        except InputError as err:
            refused += 1
            if refused == 1:
                first = f'at {item.stamp_ns} ns: {err}'
                log.warning("speed_topic '%s': message %s (skipped; further ones are counted in "
                            'the summary)', topic, first)
    samples.sort(key=lambda s: s[0])
    return [s[0] for s in samples], [s[1] for s in samples], refused, first


FIRST_FRAME = DropReason.FIRST_FRAME.value


def _count_drop(dropped: Counter[str], reason: str, frame: CameraFrame, message: str,
                first: dict[str, str]) -> None:
    """Count a frame without odometry under `reason`. The first of each kind says why (and
    its message is kept in ``first``), the summary counts them all: a bag of 10,000
    undecodable images logs one line, not 10,000."""
    dropped[reason] += 1
    first.setdefault(reason, message)
    if dropped[reason] == 1:
        log.warning('frame %d (%d ns) dropped, %s: %s (further %s frames are counted in the '
                    'summary)', frame.index, frame.stamp_ns, reason, message, reason)


def replay_bag(in_path: str | Path, out_path: str | Path, processor: FrameProcessor, *,
               image_topic: str | None = None, camera_info_topic: str | None = None,
               speed_topic: str | None = None, copy_topics: Iterable[str] | None = None,
               tum_path: str | Path | None = None, storage: str = 'mcap',
               odom_topic: str = '/odom', odom_frame: str = 'odom',
               base_frame: str = 'base_link', progress: bool = True,
               two_pass: bool = False) -> ReplaySummary:
    """Replay a bag's images through `processor` and write its odometry to a new bag.

    Args:
        in_path: input bag (directory, ``.mcap`` or ``.db3``).
        out_path: output bag directory; must not exist.
        processor: see `FrameProcessor`.
        image_topic, camera_info_topic: see `planar_vo.io.iter_camera_frames` (auto-detected
            when None).
        speed_topic: ``TwistStamped``/``Odometry`` topic whose speed (norm of the linear
            velocity) is fed with ``add_speed``; None feeds none.
        copy_topics: topics copied unchanged; None copies every topic of a `COPY_TYPES` type
            (except one named like `odom_topic`).
        tum_path: also write the odometry as a TUM file (``timestamp tx ty tz qx qy qz qw``,
            header stamps with full ns precision); must not exist.
        storage: output storage, ``'mcap'`` or ``'sqlite3'``.
        odom_topic, odom_frame, base_frame: the output odometry topic and frame ids.
        progress: show a progress bar on stderr.
        two_pass: with a `VisualOdometry` self-calibrating its focal length
            (``camera.estimate_focal``), a first pass over every frame calibrates it, and the
            odometry written is a second pass that uses that calibration (focal length and
            uncertainty) from the first frame on (`VisualOdometry.start_from_first_pass`).
            Offline only: the first frames' odometry then depends on later frames.

    Returns:
        A `ReplaySummary`.

    Raises:
        BagError: input missing/corrupt/ambiguous, an image topic without messages, output or
            TUM path exists, the input found
            corrupt mid-way, or the output bag cannot be written (a full disk).
        OutputError: the TUM file cannot be written.

    Whatever stops the replay (an error, SIGINT/SIGTERM as ``KeyboardInterrupt``), the output
    bag holds everything written so far as a complete bag, or is removed when it cannot be
    finished; the TUM file is written from the poses computed so far; and the exception carries
    notes saying exactly what was kept. Neither output is ever left truncated.
    """
    from tqdm import tqdm

    start = time.perf_counter()
    if not (isinstance(odom_topic, str) and odom_topic.startswith('/') and len(odom_topic) > 1
            and not any(c.isspace() for c in odom_topic)):
        raise BagError(f"odom_topic: expected an absolute topic name ('/odom'), got "
                       f'{odom_topic!r}')
    if odom_topic == GROUND_TRUTH_TOPIC:
        # (a user test: the odometry then passed for the ground truth in eval)
        raise BagError(f"odom_topic: '{odom_topic}' is the ground truth's topic; name the "
                       f'odometry otherwise')
    if not str(out_path).strip():
        raise BagError('out: an empty path; expected the folder to write the bag to')
    out_path = Path(out_path)
    source = Path(os.path.realpath(Path(in_path).expanduser()))
    if source.is_file() and (source.parent / 'metadata.yaml').is_file():
        source = source.parent                  # a bag given by its storage file (a review)
    if source.is_dir() and source in Path(os.path.realpath(out_path.expanduser())).parents:
        # (a user test: the output went into the input bag's folder, which eval and fleet
        # refuse: a bag folder holds one bag)
        raise BagError(f"out: '{out_path}' lies inside the input bag '{in_path}'; choose a "
                       f'folder outside it')
    if tum_path is not None:
        tum = Path(tum_path)
        if tum.exists():
            raise BagError(f"tum: '{tum_path}' already exists; refusing to overwrite it "
                           f'(remove it or choose another path)')
        if tum.resolve() == out_path.resolve():
            raise BagError(f"tum: '{tum_path}' is also the output bag's path")
        folder = tum.parent
        if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
            # Found now, not after the whole replay.
            raise OutputError(f"tum: cannot write '{tum_path}' (its folder '{folder}' does not "
                              f'exist or is not writable)')
    config = getattr(processor, 'config', None)
    if two_pass and not (isinstance(config, PlanarVoConfig)
                         and hasattr(processor, 'start_from_first_pass')):
        raise ConfigError('two_pass: expected a VisualOdometry (a first pass calibrates its '
                          'focal length for the second)')
    if two_pass and not config.camera.estimate_focal:
        raise ConfigError("two_pass: the first pass self-calibrates the focal length: give --set "
                          "camera.estimate_focal=true (with the bag's CameraInfo, or camera.fx, "
                          'there is nothing to calibrate)')
    own = _own_intrinsics(config) if isinstance(config, PlanarVoConfig) else ''
    if own and camera_info_topic is not None:
        raise ConfigError(f"camera_info_topic: '{camera_info_topic}' would not be used: {own} "
                          f'(the bag\'s CameraInfo is then ignored, as in the node); drop one '
                          f'of the two')
    summary = ReplaySummary(str(in_path), str(out_path), None if tum_path is None else
                            str(tum_path))
    writer = OdometryBagWriter(out_path, storage=storage, topic=odom_topic,
                               odom_frame=odom_frame, base_frame=base_frame)
    writer.custom_data = provenance(config if isinstance(config, PlanarVoConfig) else None,
                                    input=str(Path(in_path).resolve()), odom_topic=odom_topic)
    with open_bag(in_path) as bag:
        image_topic, info_topic = resolve_camera_topics(bag, image_topic, camera_info_topic)
        if not bag.count(image_topic):
            raise BagError(f"image_topic: '{image_topic}' in '{in_path}' has no messages; "
                           f'messages per topic: {bag.describe_topics(counts=True)}')
        summary.image_topic, summary.camera_info_topic = image_topic, info_topic
        summary.partial_input = bag_custom_data(in_path).get(PARTIAL_KEY, '')
        if summary.partial_input:
            log.warning('%s: an import cut short, %s', in_path, summary.partial_input)
            # passed on, so that eval and fleet rows of the odometry say it too
            writer.custom_data[PARTIAL_KEY] = summary.partial_input
        if own and info_topic is not None:
            # As the node, which then does not subscribe to CameraInfo at all: the configured
            # intrinsics (or the self-calibration) are what the user asked for.
            summary.camera_info_unused = own
            log.info('camera info %s not used: %s', info_topic, own)
            info_topic = None
        if copy_topics is None:
            copy = [t for t in bag.topics_of_type(*COPY_TYPES) if t != odom_topic]
            if odom_topic in bag.topics:
                # Said (a user test: a bag's wheel odometry on /odom vanished without a word).
                summary.not_copied = odom_topic
                log.warning("input topic %s not copied: it is the output odometry's topic "
                            '(--odom-topic names another)', odom_topic)
        else:
            copy = [bag.require_topic('copy_topics', t) for t in copy_topics]
        if odom_topic in copy:
            raise BagError(f"copy_topics: '{odom_topic}' is the output odometry topic; it "
                           f'cannot also be copied')
        stamps_ns, speeds = [], []
        if speed_topic is not None:
            summary.speed_topic = speed_topic
            stamps_ns, speeds, summary.speed_errors, summary.speed_error = _read_speeds(
                bag, speed_topic)
        next_speed = 0
        dropped: Counter[str] = Counter()
        first: dict[str, str] = {}
        sources: Counter[str] = Counter()
        poses = _Poses()
        # 16-bit grey images as the processor's configuration reads them (camera.mono16_bits).
        shift = config.camera.mono16_bits - 8 if isinstance(config, PlanarVoConfig) else 8
        rectified = isinstance(config, PlanarVoConfig) and config.camera.rectified
        if two_pass:
            try:
                summary.first_pass = _first_pass(bag, image_topic, processor, stamps_ns,
                                                 speeds, shift, progress)
                # What made the odometry (a user test: two passes could not be told from one
                # in the bag nor in eval's metrics.json).
                writer.custom_data['planar_vo.first_pass'] = summary.first_pass
            except BaseException as err:   # noqa: BLE001 - noted and re-raised, interrupts too
                err.add_note(f"in the first pass (--two-pass): nothing was written to "
                             f"'{out_path}'")
                raise
        decoder = CameraFrameDecoder(bag, image_topic, info_topic, mono16_shift=shift,
                                     rectified=rectified)
        # VisualOdometry takes an undecodable image's error (`VisualOdometry.process`).
        from planar_vo.pipeline import VisualOdometry
        takes_errors = isinstance(processor, VisualOdometry)
        decoder.prime()
        odometry = (config if isinstance(config, PlanarVoConfig) else PlanarVoConfig()).odometry
        gaps = GapCounter(odometry.max_frame_gap, odometry.max_time_jump_back)
        warned_gap = False
        bar = tqdm(total=bag.count(image_topic), desc='replay', unit='frame', file=sys.stderr,
                   disable=not progress, leave=False)

        def stopped(err: BaseException) -> None:
            # The bag kept from a replay stopped early says so, as an import's (a user test: an
            # interrupted replay could not be told from a complete one), and eval warns.
            if str(err).startswith('out:'):
                return                                     # (nothing is kept then)
            why = 'interrupted' if isinstance(err, KeyboardInterrupt) else 'stopped by an error'
            # (the odometry messages, as the stop's line counts them: a user test found the
            # frames read, one more, beside it)
            done = (f'odometry for {writer.count} of {bag.count(image_topic)} frames (the '
                    f'replay was {why})')
            marks = [summary.partial_input, done]
            writer.custom_data[PARTIAL_KEY] = '; '.join(m for m in marks if m)
            _record_focal(writer, processor)

        writer.on_stop = stopped
        try:
            with writer:
                for topic in copy:
                    writer.copy_topic(bag, topic)
                copy_set = set(copy)
                for message in bag.messages([image_topic, *([info_topic] if info_topic else []),
                                             *copy]):
                    if message.topic in copy_set:
                        writer.write_raw(message.topic, message.log_time_ns, message.rawdata)
                    frame = decoder.feed(message)
                    if frame is None:
                        continue
                    summary.frames_in += 1
                    bar.update(1)
                    if frame.bad_stamp:
                        # Not a time at all: the pipeline does not see it; it fills a slot
                        # of the stamps' interval it came in.
                        gaps.refused()
                        _count_drop(dropped, BAD_STAMP, frame, frame.error, first)
                        continue
                    gap = gaps.note(frame.stamp_ns)
                    if gap is not None and gap.rate_change is None and not warned_gap:
                        warned_gap = True
                        log.warning('frame %d (%d ns): a gap of %.0f ms in the image stamps '
                                    '(about %s missing at %.1f Hz; further gaps are counted in '
                                    'the summary)', frame.index, frame.stamp_ns,
                                    gap.interval_ns / 1e6, plural(gap.missing, 'frame'),
                                    1e9 / gap.period_ns)
                    image = frame.image
                    if image is None:
                        if not takes_errors:
                            _count_drop(dropped, BAD_IMAGE, frame, frame.error, first)
                            continue
                        # The pipeline counts it towards lost tracking, as the node's does.
                        image = ImageError(frame.error)
                    fed = _feed_speeds(processor, stamps_ns, speeds, next_speed,
                                       frame.stamp_ns)
                    summary.speed_messages += fed - next_speed
                    next_speed = fed
                    result = processor.process(image, frame.stamp, frame.camera)
                    reason = None if result.ok else getattr(result.reason, 'value',
                                                            str(result.reason))
                    if result.has_odometry:
                        with deferred_interrupts():    # the bag and the TUM poses agree
                            writer.write(frame.stamp_ns, result.pose, result.pose_covariance,
                                         result.twist, result.twist_covariance,
                                         log_time_ns=frame.log_time_ns)
                            poses.add(frame.stamp_ns, result.pose, bool(result.ok))
                    if result.ok:
                        sources[str(getattr(result, 'scale_source', 'unknown'))] += 1
                    elif reason == FIRST_FRAME:
                        summary.origins += 1
                        log.debug('frame %d (%d ns): %s, the origin', frame.index,
                                  frame.stamp_ns, result.message)
                    else:
                        _count_drop(dropped, reason, frame, result.message, first)
                    log.debug('frame %d (%d ns): %s', frame.index, frame.stamp_ns,
                              reason or 'odometry')
                _record_focal(writer, processor)
        except BaseException as err:   # noqa: BLE001 - noted and re-raised, interrupts too
            if tum_path is not None:
                err.add_note(poses.save(tum_path))
            if not str(err).startswith('out:'):
                # What was replayed before the input stopped it (a user test: a bag corrupt
                # mid-way printed no counts, and the fleet's row said 0 frames where 20 had
                # odometry); not when the output failed (nothing may be kept then).
                summary.gaps, summary.missing_frames = gaps.gaps, gaps.missing
                _fill(summary, processor, writer, copy, dropped, first, sources, decoder, start)
                err.replay_summary = summary
            raise
        finally:
            bar.close()
        # Messages the index counts that reading skipped (a damaged MCAP chunk): counted, so
        # that every image in the bag has odometry or a reason.
        summary.unreadable = dict(bag.unread)
        summary.gaps, summary.missing_frames = gaps.gaps, gaps.missing
        lost = bag.unread.get(image_topic, 0)
        if lost:
            summary.frames_in += lost
            dropped[UNREADABLE] += lost
            first[UNREADABLE] = (f'{plural(lost, "image message")} that the bag indexes '
                                 f'could not be read (damaged storage)')
        if bag.unread:
            log.warning("bag '%s': %s indexed but unreadable (damaged storage, skipped by the "
                        'reader)', in_path, ', '.join(f'{plural(n, "message")} on {t}'
                                                      for t, n in sorted(bag.unread.items())))
    summary.odometry_out = writer.count
    if tum_path is not None and summary.motion_out:
        try:
            poses.write(tum_path)
        except OutputError as err:
            err.add_note(writer.outcome)
            raise
        summary.tum_note = poses.note
    elif tum_path is not None:
        # No motion: no file (the origin alone says nothing, and a file would block the next
        # run).
        summary.tum = None
    _fill(summary, processor, writer, copy, dropped, first, sources, decoder, start)
    return summary


def _record_focal(writer: OdometryBagWriter, processor) -> None:
    """The focal length the odometry ended on, in the bag's custom data (eval's metrics.json
    then records it: a user test found it in the summary only)."""
    focal = getattr(processor, 'focal_status', None)
    if callable(focal):
        writer.custom_data['planar_vo.focal'] = focal()
    carry = getattr(processor, 'focal_carry', None)
    settings = carry() if callable(carry) else {}
    if settings:
        writer.custom_data['planar_vo.focal_carry'] = ' '.join(
            f'{k}={v:g}' for k, v in settings.items())


def _feed_speeds(processor, stamps_ns: list[int], speeds: list[float], start: int,
                 until_ns: int) -> int:
    """Feed ``processor`` the speeds from index ``start`` stamped up to ``until_ns``; returns
    the index of the next one."""
    end = max(start, bisect.bisect_right(stamps_ns, until_ns))
    for k in range(start, end):
        processor.add_speed(stamps_ns[k] / 1_000_000_000, speeds[k])
    return end


def _first_pass(bag, image_topic: str, processor, stamps_ns: list[int], speeds: list[float],
                shift: int, progress: bool) -> str:
    """`replay_bag`'s first pass (``two_pass``): a `VisualOdometry` of the processor's
    configuration over every image (with the speeds), its focal calibration finished and handed
    to ``processor``; returns the summary's line."""
    from tqdm import tqdm

    from planar_vo.pipeline import VisualOdometry

    start = time.perf_counter()
    first = VisualOdometry(processor.config)
    decoder = CameraFrameDecoder(bag, image_topic, None, mono16_shift=shift)
    decoder.prime()
    frames, next_speed = 0, 0
    with tqdm(total=bag.count(image_topic), desc='first pass', unit='frame', file=sys.stderr,
              disable=not progress, leave=False) as bar:
        for message in bag.messages([image_topic]):
            frame = decoder.feed(message)
            if frame is None:
                continue
            bar.update(1)
            frames += 1
            if frame.bad_stamp:
                continue                          # (as in the second pass: not a time at all)
            next_speed = _feed_speeds(first, stamps_ns, speeds, next_speed, frame.stamp_ns)
            first.process(frame.image if frame.image is not None else ImageError(frame.error),
                          frame.stamp, None)
    seconds = time.perf_counter() - start
    calibrations = first.focal_calibrations
    if not calibrations:
        return f'{frames} frames in {seconds:.1f} s: no image to calibrate the focal length from'
    for calibrator in calibrations:
        calibrator.finish_first_pass()
    processor.start_from_first_pass(*calibrations)
    # What each image size's calibration holds (a review and a user test: 'calibrated over all
    # of them' was said of a drive without a turn, and of the last of two image sizes).
    parts = [plural(c.pairs, 'turning pair') if c.pairs else 'no turning pair'
             for c in calibrations]
    if len(calibrations) > 1:
        parts = [f'{c.width}x{c.height}: {part}' for c, part in zip(calibrations, parts)]
    if not any(c.pairs for c in calibrations):
        return (f'{frames} frames in {seconds:.1f} s: no turning pair to calibrate the focal '
                f'length from (it stays where it starts)')
    return (f"{frames} frames in {seconds:.1f} s: {', '.join(parts)} profiled; the focal "
            f'length they give (the camera line) used from the first frame on')


def _fill(summary: ReplaySummary, processor, writer, copy, dropped, first, sources, decoder,
          start: float) -> None:
    """The summary's counts and states from the replay's state (at its end, or where a bag
    that failed mid-way stopped it)."""
    summary.odometry_out = writer.count
    summary.dropped = dict(dropped)
    if not summary.motion_out:
        worst = max(dropped, key=dropped.__getitem__, default=None)
        if worst is not None:
            summary.why_none = f'{worst}: {first[worst]}'
    summary.copied = {t: writer.counts.get(t, 0) for t in copy}
    summary.camera_info_errors = decoder.camera_errors
    status = getattr(processor, 'focal_status', None)
    summary.focal = status() if callable(status) else ''
    carry = getattr(processor, 'focal_carry', None)
    summary.carry = carry() if callable(carry) else {}
    scale = getattr(processor, 'scale_status', None)
    summary.scale = scale() if callable(scale) else ''
    summary.scale_sources = dict(sources)
    top_ups = getattr(processor, 'road_top_ups', None)
    summary.road_top_ups = top_ups if isinstance(top_ups, int) else None
    pixels = getattr(processor, 'image_road_steps', None)
    summary.image_road_steps = pixels if isinstance(pixels, int) else None
    misses = getattr(processor, 'image_road_misses', None)
    summary.image_road_misses = dict(misses) if isinstance(misses, dict) else {}
    examples = getattr(processor, 'image_road_examples', None)
    summary.image_road_examples = dict(examples) if isinstance(examples, dict) else {}
    summary.wall_time = time.perf_counter() - start


class _Poses:
    """The odometry poses written so far, for the TUM file."""

    def __init__(self) -> None:
        self.stamps_ns: list[int] = []
        self.poses: list[np.ndarray] = []
        self.moved = False              # a pose beyond the origin's (an estimated motion)
        # Poses before the stamps last jumped back (a looped bag): a TUM file holds one time
        # base, the latest (a user test: the whole write failed on the repeated stamps).
        self.earlier = 0
        # Poses published at stamps found ahead of their time (the odometry moved them back):
        # left out, the file's stamps increase (a user test: 21 poses before one were dropped
        # as a looped bag's).
        self.ahead = 0

    def add(self, stamp_ns: int, pose: np.ndarray, motion: bool) -> None:
        if self.stamps_ns and stamp_ns <= self.stamps_ns[-1]:
            later = len(self.stamps_ns) - bisect.bisect_left(self.stamps_ns, stamp_ns)
            if later <= GAP_WATCH and later < len(self.stamps_ns):
                del self.stamps_ns[-later:], self.poses[-later:]
                self.ahead += later
            else:
                self.earlier += len(self.stamps_ns)
                self.stamps_ns, self.poses = [], []
        self.stamps_ns.append(stamp_ns)
        self.poses.append(np.asarray(pose, dtype=np.float64))
        self.moved = self.moved or motion

    @property
    def note(self) -> str:
        """What the TUM file leaves out, if anything (empty otherwise)."""
        notes = []
        if self.earlier:
            notes.append(f'the {len(self.poses)} poses after the stamps last jumped back; the '
                         f'bag holds all {len(self.poses) + self.earlier}')
        if self.ahead:
            notes.append(f'without {plural(self.ahead, "pose")} published at stamps ahead of '
                         f'their time, which the bag holds')
        return f' ({"; ".join(notes)})' if notes else ''

    def write(self, path: str | Path) -> None:
        """Write them as a TUM file (complete or absent; `OutputError` if it cannot be)."""
        from planar_vo.core.trajectory import Trajectory
        from planar_vo.tools.evaluation.files import write_tum

        write_tum(path, Trajectory.from_poses(np.array(self.stamps_ns, dtype=np.int64),
                                              np.array(self.poses).reshape(-1, 4, 4)))

    def save(self, path: str | Path) -> str:
        """`write`, after a failure or an interruption: a note saying what became of the file
        (not written without a motion, as after a complete replay: the origin alone says
        nothing, and the file would only block the next run)."""
        if not self.moved:
            return f"no motion was estimated; '{path}' was not written"
        try:
            self.write(path)
        except OutputError as err:
            return str(err)
        return f"wrote '{path}' with the {len(self.poses)} poses computed"
