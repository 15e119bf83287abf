"""The planar_vo ROS 2 node (``ros2 run planar_vo planar_vo_node``), the only module importing
rclpy.

Topics (relative names, so that ``--ros-args -r image:=/camera/image_raw`` remaps them):

- subscribes ``image`` (``sensor_msgs/Image``; mono8, mono16, rgb8, bgr8, ... see
  `planar_vo.ros.messages`) or, with ``ros.image_transport: compressed``, ``image/compressed``
  (``sensor_msgs/CompressedImage``, JPEG or PNG); ``camera_info`` (``sensor_msgs/CameraInfo``)
  unless ``camera.fx > 0`` gives the intrinsics; ``speed`` (``geometry_msgs/TwistStamped``, or
  ``nav_msgs/Odometry`` with ``ros.speed_topic_type: odometry``) when ``scale.source`` is
  ``speed``. Sensor inputs use the sensor-data QoS profile; the speed topic keeps
  `SPEED_QUEUE_DEPTH` samples, so that none is lost while an image is being processed.
- publishes ``odom`` (``nav_msgs/Odometry``, stamped with the image's header stamp, pose and
  twist with covariance), ``path`` (``nav_msgs/Path``: decimated by ``ros.path_spacing``, at
  most ``ros.path_max_length`` poses, at most once per ``ros.path_period``, so that its cost
  per frame is bounded), ``status`` (``diagnostic_msgs/DiagnosticArray``, one per image:
  result, tracking state, scale source, focal length, inliers, timings, counters), the
  aggregated ``/diagnostics`` every ``ros.diagnostics_period`` seconds, and the TF
  ``odom -> base_link`` when ``tf2_ros`` is installed and ``ros.publish_tf`` is set.
- serves ``~/reset`` (``std_srvs/Trigger``): pose back to the origin, a new keyframe chain from
  the next image, the counters kept.

Every image yields either an odometry message or a counted `DropReason` (an image the node
cannot decode counts as ``bad_image``); the first image after start-up or ``~/reset`` yields
the origin's odometry and is counted as ``first_frames``; each reason and cause (the message,
numbers aside; a few causes per reason) is logged as a specific warning at most once per
``ros.warn_period`` seconds, and every change of the tracking state is logged once. Frames
the transport lost, or the node's full queue dropped, never reach the node: they show up as
gaps in the image stamps and are counted as ``missing_frames`` (those dropped while the node
was busy as ``missing_behind`` too); a clock glitch or a jump back of the stamps (a looped
bag) is not a gap.

Parameters are the dotted keys of `planar_vo.config.PlanarVoConfig` (``voting.bins``, ...),
declared with descriptions, ranges and read-only flags, and validated through the same config
object: an invalid value at start-up is one fatal log line and exit code 1; at run time it is
rejected. `LIVE_PARAMETERS` may change at run time; the others are read at start-up only.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import logging
import math
import os
import re
import signal
import sys
import textwrap
import time
from collections import Counter, deque
from collections.abc import Sequence
from pathlib import Path as FilePath
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseStamped,
    PoseWithCovariance,
    Quaternion,
    TransformStamped,
    Twist,
    TwistStamped,
    TwistWithCovariance,
    Vector3,
)
from nav_msgs.msg import Odometry, Path
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSPolicyKind,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from planar_vo.config import PlanarVoConfig, describe, flatten, ranges
from planar_vo.core.camera import CameraModel
from planar_vo.errors import (
    CameraModelError,
    ConfigError,
    ImageError,
    InputError,
    one_line,
    plural,
)
from planar_vo.pipeline import DropReason, FrameResult, TrackingState, VisualOdometry
from planar_vo.pipeline.clock import GapCounter, Stamp
from planar_vo.pipeline.road_image import pixels_note
from planar_vo.pipeline.types import unit_note
from planar_vo.pipeline.threads import limit_blas_threads
from planar_vo.ros.messages import (
    compressed_to_array,
    image_to_array,
    odometry_message,
    speed_from_message,
    stamp_problem,
    stamp_to_ns,
)
from planar_vo.early_stops import pending_stop

try:  # tf2_ros comes with a ROS installation; it is not on PyPI.
    from tf2_ros import TransformBroadcaster
except ImportError:  # pragma: no cover - depends on the installation
    TransformBroadcaster = None

__all__ = ['LIVE_PARAMETERS', 'SPEED_QUEUE_DEPTH', 'PlanarVoNode', 'main', 'ros_arguments',
           'usage']

# Parameters that may change while the node runs; the others shape subscriptions and the pipeline
# and are declared read-only.
LIVE_PARAMETERS = frozenset({'ros.publish_tf', 'ros.path_max_length', 'ros.path_spacing',
                             'ros.path_period', 'ros.warn_period', 'ros.image_timeout'})

# Speed samples kept by the subscription while the single-threaded executor processes an image:
# 5 s of a 100 Hz wheel-speed topic, far longer than any frame takes (16-65 ms with the default
# front-end, 4-11 s with asift). Only the queue's depth differs from the sensor-data profile.
SPEED_QUEUE_DEPTH = 500


def sensor_qos(depth: int | None = None) -> QoSProfile:
    """A new profile with the sensor-data policies (best effort, volatile, keep last), of
    ``depth`` or the sensor-data depth. New each time: rclpy writes the ``qos_overrides``
    parameters into the profile a subscription is created with, and sharing one (let alone
    rclpy's module-level ``qos_profile_sensor_data``) would carry one topic's overrides to the
    others."""
    return QoSProfile(history=qos_profile_sensor_data.history,
                      depth=qos_profile_sensor_data.depth if depth is None else depth,
                      reliability=qos_profile_sensor_data.reliability,
                      durability=qos_profile_sensor_data.durability)


# The rclpy classes of the message types `odometry_message` builds.
_MESSAGE_TYPES = {
    'nav_msgs/msg/Odometry': Odometry, 'std_msgs/msg/Header': Header,
    'builtin_interfaces/msg/Time': Time, 'geometry_msgs/msg/PoseWithCovariance': PoseWithCovariance,
    'geometry_msgs/msg/Pose': Pose, 'geometry_msgs/msg/Point': Point,
    'geometry_msgs/msg/Quaternion': Quaternion,
    'geometry_msgs/msg/TwistWithCovariance': TwistWithCovariance, 'geometry_msgs/msg/Twist': Twist,
    'geometry_msgs/msg/Vector3': Vector3,
}

_INT64_MAX = 2 ** 63 - 1
# Images that may wait for the first CameraInfo: the one it was published with may come after
# the next images on a loaded machine (DDS does not order two topics); none waits longer than
# _CAMERA_INFO_WAIT seconds (then its status is published, counted no_camera_info; the timer
# that releases them when no image comes runs five times as often: 0.6 s at most).
_PENDING_IMAGES = 3
_CAMERA_INFO_WAIT = 0.5
# Numbers in a drop's message (stamps, sizes): not part of its cause; at most this many causes
# per reason are rate-limited apart (`_report_drop`).
_NUMBER = re.compile(r'\d+(?:\.\d+)?')
_CAUSES = 4
# An image whose callback starts within this share of the camera's frame interval (and this
# many seconds) after the node's last callback ended was waiting in the queue: the node runs
# back to back (`_waited`).
_QUEUED_SHARE, _QUEUED_MAX_S = 0.1, 0.002
_monotonic = time.monotonic            # the waiting images' clock (tests replace it)
# The focal length is logged again when it moved by this share since the last line (the
# self-calibration's progress: a handful of lines in a turn, none while it holds still).
_FOCAL_LOG_CHANGE = 0.02
# The no-image warning has a timer of its own, of period ``ros.image_timeout``, restarted by every
# image (the diagnostics tick, once per ``ros.diagnostics_period``, was late by up to a period),
# rather than a poll. It fires when no image came for a whole period; this slack absorbs the two
# clocks' rounding (an image that raced it is well inside).
_IMAGE_WATCH_SLACK = 0.005
# The outcome of a frame whose odometry is the origin (counted apart from the drops).
_FIRST_FRAME = DropReason.FIRST_FRAME.value


class _BadStamp(Exception):
    """An image's header stamp is no ROS time (`stamp_problem`): a ``bad_stamp`` frame."""


def _with_odometry(outcomes: Counter[str]) -> int:
    """Frames of ``outcomes`` that gave an odometry message: a motion or the origin."""
    return outcomes['ok'] + outcomes[_FIRST_FRAME]


def _drops(outcomes: Counter[str]) -> dict[str, int]:
    """The counts of ``outcomes`` without odometry, by reason."""
    return {k: v for k, v in sorted(outcomes.items()) if k not in ('ok', _FIRST_FRAME) and v}


# The QoS policies the subscriptions let `qos_overrides.*` change (rclpy's defaults and the
# durability: a CameraInfo published once, latched, needs a transient-local reliable
# subscription; a user test found it never received), and the values rclpy knows.
_QOS_KINDS = (*QoSOverridingOptions.with_default_policies().policy_kinds,
              QoSPolicyKind.DURABILITY)
_QOS_POLICIES = tuple(kind.name.lower() for kind in _QOS_KINDS)
_QOS_POLICY_VALUES = {
    policy: tuple(name.lower() for name in enum.__members__ if name != 'UNKNOWN')
    for policy, enum in (('history', HistoryPolicy), ('reliability', ReliabilityPolicy),
                         ('durability', DurabilityPolicy))}
# The parameters `usage` lists (the parameter file has them all).
_MAIN_PARAMETERS = ('scale.source', 'mount.height', 'mount.pitch', 'camera.fx',
                    'camera.estimate_focal', 'camera.nominal_fov', 'camera.nominal_fov_std',
                    'ros.image_transport', 'ros.publish_tf',
                    'ros.odom_frame', 'ros.base_frame')


class WarningThrottle:
    """At most one warning per key every ``period`` seconds (monotonic clock), counting the
    ones held back so that the next emitted line can say how many were suppressed."""

    def __init__(self, period: float) -> None:
        self.period = float(period)
        self._last: dict[str, float] = {}
        self._held: Counter[str] = Counter()

    def admit(self, key: str, now: float | None = None, count: bool = True) -> int | None:
        """None to stay quiet; else how many warnings of ``key`` were held back since the last
        (``count`` False: a restated condition, not an event, is not counted)."""
        now = time.monotonic() if now is None else now
        last = self._last.get(key)
        if last is not None and now - last < self.period:
            if count:
                self._held[key] += 1
            return None
        self._last[key] = now
        return self._held.pop(key, 0)


class PlanarVoNode(Node):
    """Planar monocular visual odometry: images in, ``odom``, ``path``, ``status``,
    ``/diagnostics`` and TF out, ``~/reset`` served.

    Args:
        parameter_files: the ``--params-file`` files of the command line, to warn about a file
            that set nothing for this node (keyed on another node name).
        command_line_parameters: the names given with ``-p`` (they do not count as set by a
            file), each with the ``--params-file`` files given after it (`ros_arguments`).
        **kwargs: `rclpy.node.Node` arguments (``context``, ``parameter_overrides``, ...).

    Attributes:
        config: the validated `PlanarVoConfig` the node runs with.
        outcomes: images received per outcome, ``'ok'`` or a `DropReason` value.
        tracking: the tracking state after the last image (or the reset).
    """

    def __init__(self, *, parameter_files: Sequence[str] = (),
                 command_line_parameters: dict[str, list[str]] | Sequence[str] = (),
                 **kwargs: Any) -> None:
        super().__init__('planar_vo', **kwargs)
        self._defaults = flatten(PlanarVoConfig())
        self._check_unknown_overrides()
        # Validated before declaring (the declared values are these), so that a bad value is
        # reported in the config's words rather than as rclpy's range error.
        self.config = self._checked_config({
            name: param.value for name, param in self._parameter_overrides.items()
            if name in self._defaults})
        self._declare_parameters()
        self._log_parameters()
        given = (command_line_parameters if isinstance(command_line_parameters, dict)
                 else {name: [] for name in command_line_parameters})
        self._check_parameter_files(parameter_files, given)
        ros = self.config.ros

        self._vo = VisualOdometry(self.config)
        self._mono16_shift = self.config.camera.mono16_bits - 8
        self._camera: CameraModel | None = None
        self._throttle = WarningThrottle(ros.warn_period)
        self.outcomes: Counter[str] = Counter()
        self._counters: Counter[str] = Counter()   # camera_info_errors, speed_*, gaps, ...
        self.tracking = self._vo.tracking
        self._node_time = 0.0
        odometry = self.config.odometry
        self._gaps = GapCounter(odometry.max_frame_gap, odometry.max_time_jump_back)
        self._causes: dict[str, set[str]] = {}    # drop causes rate-limited apart, per reason
        # When the last image callback ended, and whether the image of this one was already
        # waiting then (`_image`): the node is the bottleneck, frames are dropped from its
        # subscription queue.
        self._callback_end: float | None = None
        self._queued = False
        self._last_frame_time = 0.0
        self._path: deque[PoseStamped] = deque(maxlen=ros.path_max_length)
        self._path_tip: PoseStamped | None = None     # the latest pose, when not kept
        self._path_published = -math.inf
        self._path_header = None         # the header of a path not published yet
        self._last_result: FrameResult | None = None
        self._focal_logged: tuple[float, str] | None = None     # px, source last logged
        self._last_frame_id = ''
        self._period: Counter[str] = Counter()           # outcomes since the last diagnostics
        self._period_scale: Counter[str] = Counter()     # scale sources of its odometry
        self._scale_total: Counter[str] = Counter()      # the same over the whole run
        self._period_time: list[float] = []
        self._period_behind = 0          # frames dropped unprocessed in the period (`_note_gap`)
        self._started = self._last_image = time.monotonic()

        self._odom_pub = self.create_publisher(Odometry, 'odom', 10)
        self._path_pub = self.create_publisher(Path, 'path', 1)
        self._status_pub = self.create_publisher(DiagnosticArray, 'status', 10)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._tf = None                  # set up after every check: a bad parameter is one line

        # Sensor-data QoS (best effort) by default; `qos_overrides.<topic>.subscription.*`
        # parameters change it, e.g. to reliable for images too large for best-effort delivery.
        # rclpy writes the overrides into the profile it is given: every subscription gets its
        # own (a reliable image must not make the speed subscription reliable too).
        overriding = QoSOverridingOptions(_QOS_KINDS)
        self._check_qos_values()
        if ros.image_transport == 'compressed':
            self._image_sub = self.create_subscription(
                CompressedImage, 'image/compressed', self._on_compressed,
                qos_profile=sensor_qos(), qos_overriding_options=overriding)
        else:
            self._image_sub = self.create_subscription(
                Image, 'image', self._on_image, qos_profile=sensor_qos(),
                qos_overriding_options=overriding)
        self._pending: list[tuple] = []       # images waiting for the first CameraInfo
        self._images_seen = 0                 # images received (the CameraInfo wait's grace)
        # With estimate_focal the pipeline runs without CameraInfo: no image waits for one.
        camera = self.config.camera
        self._expects_camera_info = camera.fx <= 0 and not camera.estimate_focal
        self._camera_info_sub = None
        self._wait_timer = None
        if self._expects_camera_info:
            self._camera_info_sub = self.create_subscription(
                CameraInfo, 'camera_info', self._busy(self._on_camera_info),
                qos_profile=sensor_qos(), qos_overriding_options=overriding)
            # Releases images that waited too long when no further image comes to do it.
            self._wait_timer = self.create_timer(
                _CAMERA_INFO_WAIT / 5, self._busy(self._release_overdue),
                clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._speed_sub = None
        if self.config.scale.source == 'speed':
            speed_type = Odometry if ros.speed_topic_type == 'odometry' else TwistStamped
            self._speed_sub = self.create_subscription(
                speed_type, 'speed', self._busy(self._on_speed),
                qos_profile=sensor_qos(SPEED_QUEUE_DEPTH), qos_overriding_options=overriding)
        self._check_qos_names()
        self.create_service(Trigger, '~/reset', self._busy(self._on_reset))
        # Steady time: diagnostics and the no-image warning go on when a simulated clock stops.
        self.create_timer(ros.diagnostics_period, self._busy(self._on_diagnostics_timer),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._silence_reported = False
        self._image_watch = self._watch_timer(ros.image_timeout)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._set_tf(ros.publish_tf)
        self.get_logger().info(self._start_line())

    # -- parameters ----------------------------------------------------------------------------

    def _check_unknown_overrides(self) -> None:
        """A misspelt parameter (``voting.binz``) is an error, not silently ignored."""
        # rclpy keeps the command-line and parameter-file values it was given in this attribute;
        # names that no declaration claims are otherwise dropped without a word.
        unknown = sorted(n for n in self._parameter_overrides
                         if n not in self._defaults and not self.has_parameter(n)
                         and not n.startswith('qos_overrides.'))
        if unknown:
            near = list(dict.fromkeys(m for n in unknown for m in difflib.get_close_matches(
                n, list(self._defaults), n=3)))                # the closest first
            hint = (f'did you mean {", ".join(near)}?' if near else
                    f'expected planar_vo parameters such as '
                    f'{", ".join(list(self._defaults)[:3])}, ...')
            self._fatal(f'unknown parameter(s) {", ".join(unknown)}: {hint} (see '
                        f'config/planar_vo.yaml)')

    def _qos_overrides(self) -> dict[str, Any]:
        return {name: param.value for name, param in self._parameter_overrides.items()
                if name.startswith('qos_overrides.')}

    def _check_qos_values(self) -> None:
        """A ``qos_overrides.*`` value that rclpy cannot use is one fatal line (rclpy raises
        deep in the subscription's creation, or rcl fails on a negative depth)."""
        for name, value in self._qos_overrides().items():
            policy = name.rpartition('.')[2]
            allowed = _QOS_POLICY_VALUES.get(policy)
            if allowed is not None and str(value).lower() not in allowed:
                self._fatal(f'{name}: {value!r} is not a {policy} policy (expected one of '
                            f'{", ".join(allowed)})')
            if policy == 'depth' and (type(value) is not int or value < 1):
                self._fatal(f'{name}: {value!r} is not a queue depth (expected an integer of at '
                            f'least 1)')

    def _check_qos_names(self) -> None:
        """A ``qos_overrides.*`` name that no subscription declared (a misspelt topic or
        policy, a publisher) is an error: rclpy would ignore it without a word."""
        unknown = sorted(n for n in self._qos_overrides() if not self.has_parameter(n))
        # One for an input this configuration does not subscribe to (CameraInfo with
        # camera.fx set, the speed without scale.source speed, the other image transport) is
        # only unused (a user test: a launch file that always sets the CameraInfo's QoS failed
        # with camera.fx set).
        idle = set(self.resolve_topic_name(t) for t in _INPUTS) - set(self.listened_topics())
        unused = [n for n in unknown if _override_topic(n) in idle]
        if unused:
            self.get_logger().warning(
                f'QoS override(s) {", ".join(unused)} not used: this configuration does not '
                f'subscribe to {", ".join(sorted({_override_topic(n) for n in unused}))}')
            unknown = [n for n in unknown if n not in unused]
        if unknown:
            self._fatal(f'unknown QoS override(s) {", ".join(unknown)}: expected qos_overrides.'
                        f'<topic>.subscription.<{"|".join(_QOS_POLICIES)}> for a topic the '
                        f'node subscribes to ({", ".join(self.listened_topics())})')

    def _fatal(self, message: str) -> None:
        self.get_logger().fatal(f'invalid parameters: {message}')
        raise ConfigError(message)

    def _declare_parameters(self) -> None:
        """Every config key, with its description, range (`planar_vo.config.ranges`) and
        read-only flag (all but `LIVE_PARAMETERS`)."""
        descriptions, allowed = describe(), ranges()
        for name, default in self._defaults.items():
            descriptor = ParameterDescriptor(
                description=descriptions[name], read_only=name not in LIVE_PARAMETERS,
                # Dynamic typing: `mount.height:=2` (an integer) and `camera.distortion:=[...]`
                # (the default is an empty, untyped list) are allowed; the config checks types.
                dynamic_typing=True)
            bounds = allowed.get(name)
            if bounds is not None and (bounds.low is not None or bounds.high is not None):
                # ROS ranges are closed: an open bound is shown closed, the constraint in words
                # (`ros2 param describe`: 'more than 0', 'a positive height in metres'), and
                # the config object refuses the bound itself with its own message.
                if bounds.low_open or bounds.high_open:
                    descriptor.additional_constraints = f'expected {bounds}'
                if isinstance(default, int):
                    descriptor.integer_range = [IntegerRange(
                        from_value=int(bounds.low if bounds.low is not None else -_INT64_MAX),
                        to_value=int(bounds.high if bounds.high is not None else _INT64_MAX),
                        step=0)]
                else:
                    descriptor.floating_point_range = [FloatingPointRange(
                        from_value=float(bounds.low if bounds.low is not None else -math.inf),
                        to_value=float(bounds.high if bounds.high is not None else math.inf),
                        step=0.0)]
            self.declare_parameter(name, default, descriptor)

    def _config_value(self, name: str, value: Any) -> Any:
        """A parameter value in the form the config expects."""
        if isinstance(self._defaults[name], list):
            # ROS has no typed empty list: a parameter file's `[]` arrives as "not set".
            return [] if value is None else list(value)
        return value

    def _parameter_values(self) -> dict[str, Any]:
        return {name: self.get_parameter(name).value for name in self._defaults}

    def _config_from(self, values: dict[str, Any]) -> PlanarVoConfig:
        """The config of the defaults updated with the parameter ``values``.

        Raises:
            ConfigError: an invalid value or combination.
        """
        flat = dict(self._defaults)
        flat.update({name: self._config_value(name, value) for name, value in values.items()})
        return PlanarVoConfig.from_flat(flat)

    def _checked_config(self, values: dict[str, Any]) -> PlanarVoConfig:
        """`_config_from`, with one fatal line if invalid."""
        try:
            return self._config_from(values)
        except ConfigError as err:
            self.get_logger().fatal(f'invalid parameters: {err}')
            raise

    def _log_parameters(self) -> None:
        """Every parameter at DEBUG; the INFO start line names the ones that differ."""
        for name, value in flatten(self.config).items():
            self.get_logger().debug(f'{name} = {value!r}')

    def _start_line(self) -> str:
        """One INFO line: topics, the scale and what it rests on (the camera height), the
        parameters set away from the defaults and the QoS overrides given."""
        changed = {k: v for k, v in flatten(self.config).items() if v != self._defaults[k]}
        settings = ', '.join(f'{k} = {v!r}' for k, v in changed.items()) or 'all defaults'
        qos = ', '.join(f'{k} = {v!r}' for k, v in sorted(self._qos_overrides().items()))
        camera = (self._camera_info_sub.topic_name if self._camera_info_sub is not None else
                  'camera.* parameters' if self.config.camera.fx > 0 else 'self-calibration')
        return (f'listening on {self._image_sub.topic_name} (intrinsics from {camera}); scale: '
                f'{self._vo.scale_status()}; {len(self._defaults)} parameters, '
                f'{len(changed)} set: {settings}' + (f'; QoS overrides: {qos}' if qos else '')
                + ' (the others: ros2 param dump, or DEBUG logs)')

    def _check_parameter_files(self, files: Sequence[str], given: dict[str, list[str]]
                               ) -> None:
        """Warn about a parameter file that set nothing for this node: rcl silently skips a
        file keyed on another node name (``planar_vo:`` for a node renamed ``front_vo``); and
        about a ``-p`` value that a later ``--params-file`` replaced (rcl applies the arguments
        in order: ``-p mount.height:=1.65 --params-file planar_vo.yaml`` runs with the file's
        height). ``given``: the ``-p`` names, each with the files after it (`ros_arguments`)."""
        me = (self.get_name(), self.get_fully_qualified_name().lstrip('/'))

        def ours(node: str) -> bool:
            """A -p prefix or a file's node key that names this node (empty, /** or its
            name)."""
            node = node.strip('/')
            return node in ('', '**', *me) or node.rsplit('/', 1)[-1] == me[0]

        # The -p names for this node (a NODE: prefix naming another node sets nothing here).
        given = {key.rpartition(':')[2]: later for key, later in given.items()
                 if ours(key.rpartition(':')[0])}
        applied = set(self._parameter_overrides) - set(given)
        entries = {path: _parameter_file_entries(path) for path in files}
        for path in files:
            keys, names = entries[path]
            # Only names no -p sets tell whether rcl applied the file to this node.
            names = names - set(given)
            if names and not names & applied:
                self.get_logger().warning(
                    f'parameter file {path} set nothing for this node '
                    f'{self.get_fully_qualified_name()}: its parameters are keyed on '
                    f'{", ".join(keys)}; key them on /** (any node) or on '
                    f'{self.get_fully_qualified_name()}')
        for name, later in given.items():
            replaced = [path for path in later
                        if name in entries[path][1] and any(map(ours, entries[path][0]))]
            if replaced and name in self._parameter_overrides:
                self.get_logger().warning(
                    f'-p {name} was replaced by the value in {replaced[-1]}, given after it '
                    f'({name} = {_format_value(self._parameter_overrides[name].value)}): put '
                    f'--params-file before -p')

    def _on_set_parameters(self, params: list) -> SetParametersResult:
        """Validate a run-time change through the config object; apply the live ones (rclpy has
        already refused read-only parameters and values outside the declared ranges)."""
        ours = [p for p in params if p.name in self._defaults]   # not e.g. use_sim_time
        if not ours:
            return SetParametersResult(successful=True)
        try:
            config = self._config_from({**self._parameter_values(),
                                        **{p.name: p.value for p in ours}})
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        ros = config.ros
        watch = None
        if ros.image_timeout != self.config.ros.image_timeout:
            # The new timer first: if it cannot be made, nothing changes (a review: the other
            # live values were applied before the refusal).
            try:
                watch = self._watch_timer(ros.image_timeout)
            except Exception as err:      # noqa: BLE001 - rclpy's own (TypeError, RCLError)
                return SetParametersResult(successful=False, reason=f'ros.image_timeout: '
                                                                    f'{one_line(err)}')
        if ros.path_max_length != self.config.ros.path_max_length:
            self._path = deque(self._path, maxlen=ros.path_max_length)
        self._throttle.period = ros.warn_period
        if ros.publish_tf != self.config.ros.publish_tf:
            self._set_tf(ros.publish_tf)
        if watch is not None:
            self.destroy_timer(self._image_watch)
            self._image_watch = watch
        self.config = config
        return SetParametersResult(successful=True)

    def _set_tf(self, enabled: bool) -> None:
        if not enabled:
            self._tf = None
        elif TransformBroadcaster is None:
            self.get_logger().warning('ros.publish_tf: tf2_ros is not installed (ROS package '
                                      'tf2_ros_py; it is not on PyPI); the odom -> base_link '
                                      'transform is not broadcast, odom and path are still '
                                      'published')
        elif self._tf is None:
            self._tf = TransformBroadcaster(self)

    # -- inputs --------------------------------------------------------------------------------

    def _on_image(self, msg: Image) -> None:
        self._image(msg, functools.partial(image_to_array, mono16_shift=self._mono16_shift))

    def _on_compressed(self, msg: CompressedImage) -> None:
        self._image(msg, functools.partial(compressed_to_array,
                                           mono16_shift=self._mono16_shift))

    def _image(self, msg: Image | CompressedImage, decode) -> None:
        """Until the first CameraInfo has arrived, images wait for it (at most
        ``_PENDING_IMAGES``, the oldest counted ``no_camera_info`` when another arrives): a driver
        publishes both with the same stamp, but DDS does not order two topics, so an image may
        arrive before its CameraInfo, and on a loaded machine the next image may too. When the
        first CameraInfo comes (`_on_camera_info`), the images stamped at or after it and the
        newest one before it run with it; older waiting images are counted ``no_camera_info``,
        like every image that finds no camera model. Nothing waits for a CameraInfo that nobody
        publishes: once ``_PENDING_IMAGES`` images have come (the grace for discovering the
        driver's CameraInfo publisher after its image publisher), an image with no CameraInfo
        publisher on the graph is counted at once, its status published with it. Nor for one
        that never comes: no image waits much longer than ``_CAMERA_INFO_WAIT`` seconds
        (`_release_overdue`, by the next image or a timer)."""
        begin = time.perf_counter()
        try:
            self._queued = self._waited(begin)
            self._take_image(msg, decode)
        finally:
            self._queued = False
            self._callback_end = time.perf_counter()

    def _busy(self, callback):
        """``callback`` noting when it ended (`_waited`: the node's other callbacks, a
        CameraInfo with every image, run between two images' and keep it busy too; a review:
        counted as idle time, they hid a node falling behind a 60 Hz camera)."""
        @functools.wraps(callback)
        def noted(*args):
            try:
                return callback(*args)
            finally:
                self._callback_end = time.perf_counter()
        return noted

    def _waited(self, now: float) -> bool:
        """Whether this image was already waiting when the node's last callback ended: the
        time between them is a small share (`_QUEUED_SHARE`) of the camera's frame interval,
        and under `_QUEUED_MAX_S` (a bag played faster than its stamps: the interval in
        wall-clock time is shorter), so the node runs back to back and frames beyond its queue's
        depth are dropped."""
        period = self._gaps.period_ns
        if self._callback_end is None or period is None:
            return False
        return now - self._callback_end < min(_QUEUED_SHARE * period * 1e-9, _QUEUED_MAX_S)

    def _take_image(self, msg: Image | CompressedImage, decode) -> None:
        """`_image` (the callback's timing apart)."""
        self._last_image = time.monotonic()
        self._silence_reported = False
        self._image_watch.reset()                       # a whole timeout from now
        self._images_seen += 1
        if self._camera is None and self._expects_camera_info:
            if (self._images_seen > _PENDING_IMAGES
                    and not self.count_publishers(self._camera_info_sub.topic_name)):
                try:
                    self.flush_pending()
                finally:
                    self._frame(msg, decode)
                return
            self._release_overdue()
            if len(self._pending) >= _PENDING_IMAGES:
                self._frame(*self._pending.pop(0)[:2])
            self._pending.append((msg, decode, _monotonic()))
            return
        self.flush_pending()
        self._frame(msg, decode)

    def flush_pending(self) -> None:
        """Process the images waiting for the first CameraInfo, if any, in arrival order. Each
        is counted before it is published, and every one is processed even if publishing one
        raises (at shutdown); the first such error is raised after the last."""
        pending, self._pending = self._pending, []
        error = None
        for item in pending:
            try:
                self._frame(*item[:2])
            except Exception as err:  # noqa: BLE001 - re-raised below, after the others
                error = error or err
        if error is not None:
            raise error

    def _release_pending(self, info_stamp_ns: int) -> None:
        """The first CameraInfo (stamp ``info_stamp_ns``) has arrived, before its camera model
        is set: the waiting images older than the newest one stamped before it never get one
        (counted ``no_camera_info`` now); the rest wait for `flush_pending`."""
        stamps = [stamp_to_ns(item[0].header.stamp) for item in self._pending]
        before = [k for k, s in enumerate(stamps) if s < info_stamp_ns]
        stale = set(before[:-1])
        for k in sorted(stale):
            self._frame(*self._pending[k][:2])
        self._pending = [item for k, item in enumerate(self._pending) if k not in stale]

    def _release_overdue(self) -> None:
        """Process (counted ``no_camera_info``) the waiting images that arrived more than
        ``_CAMERA_INFO_WAIT`` seconds ago: a CameraInfo publisher that never publishes must not
        hold every status back (`_image`)."""
        if self._camera is not None or not self._pending:
            return
        deadline = _monotonic() - _CAMERA_INFO_WAIT
        while self._pending and self._pending[0][2] <= deadline:
            self._frame(*self._pending.pop(0)[:2])

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            # Plausible intrinsics only; rectified images: P.
            camera = CameraModel.from_camera_info(msg, rectified=self.config.camera.rectified)
        except CameraModelError as err:
            self._counters['camera_info_errors'] += 1
            kept = 'keeping the last valid one' if self._camera is not None else \
                'no valid camera model yet'
            # Rate-limited per reason (its words, the numbers left out): a new reason is said
            # at once (a user test: fx = 50 px after a principal point outside the image was
            # counted without a word).
            reason = re.sub(r'[-+]?\d[\d.eE+-]*', '#', re.sub(r"'[^']*'", "'*'", str(err)))[:80]
            self._warn(f'camera_info {reason}', f'ignoring camera_info: {err}; {kept}',
                       label='camera_info')
            return
        if self._camera is None and self._pending:
            self._release_pending(stamp_to_ns(msg.header.stamp))
        if self._wait_timer is not None:
            self.destroy_timer(self._wait_timer)    # nothing waits once there is a camera
            self._wait_timer = None
        if camera != self._camera and self._camera is not None:
            # Rate-limited: two drivers publishing on one topic change it every message.
            self._counters['camera_changes'] += 1
            old = self._camera
            change = (f'the image moves up to {old.pixel_shift(camera):.3g} px'
                      if old.size == camera.size else
                      f'size {old.width}x{old.height} -> {camera.width}x{camera.height}')
            self._warn('camera_model', f'camera model changed to {camera.width}x'
                                       f'{camera.height}, fx {camera.fx:.1f}: {change}')
        self._camera = camera
        self.flush_pending()

    def _on_speed(self, msg: TwistStamped | Odometry) -> None:
        try:
            self._vo.add_speed(stamp_to_ns(msg.header.stamp) / 1e9, speed_from_message(msg))
        except InputError as err:
            self._counters['speed_errors'] += 1
            self._warn('speed', f'ignoring speed message: {err}')
            return
        self._counters['speed_messages'] += 1

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        """``~/reset``: pose back to the origin, a new keyframe chain, the counters kept."""
        self._vo.reset()
        self._clear_path()
        self._counters['resets'] += 1
        before, self.tracking = self.tracking, self._vo.tracking
        response.success = True
        response.message = ('pose reset to the origin; the next image starts a new keyframe '
                            'chain; counters kept')
        self.get_logger().info(f'reset by ~/reset: {response.message} (tracking state '
                               f'{before.value} -> {self.tracking.value})')
        return response

    def _frame(self, msg: Image | CompressedImage, decode) -> None:
        """One image: decode, run the pipeline, publish odometry (or count why not), status."""
        start = time.perf_counter()
        stamp_ns = stamp_to_ns(msg.header.stamp)
        self._last_frame_id = msg.header.frame_id
        odom = None
        problem = stamp_problem(msg.header.stamp)
        try:
            if problem:
                # Not a time at all (a user test: nanosec 4e9 read as 4 s later): the pipeline
                # does not see it; it fills a slot of the stamps' interval it came in.
                self._gaps.refused()
                raise _BadStamp(problem)
            self._note_gap(stamp_ns)
            try:
                image = decode(msg)
            except ImageError as err:
                # To the pipeline all the same: it counts towards lost tracking (a user test:
                # after five undecodable frames the stale keyframe cost five good ones).
                image = err
            result = self._vo.process(image, Stamp(stamp_ns), self._camera)
            if result.has_odometry:                          # a motion, or the origin
                odom = self._odometry(msg.header, result)    # InputError if the pose is not finite
        except _BadStamp as err:
            result = self._dropped(stamp_ns, DropReason.BAD_STAMP, str(err))
        except ImageError as err:
            result = self._dropped(stamp_ns, DropReason.BAD_IMAGE, str(err))
        except Exception as err:  # noqa: BLE001 - a bug in the pipeline must not stop the node
            result = self._dropped(stamp_ns, DropReason.PIPELINE_ERROR,
                                   f'{type(err).__name__}: {err}')
        if result.reason is DropReason.NO_CAMERA_INFO and self._camera is None:
            result = dataclasses.replace(result, message=result.message + self._info_hint())
        key = 'ok' if result.ok else result.reason.value
        self.outcomes[key] += 1
        self._period[key] += 1
        if result.ok:
            self._period_scale[result.scale_source] += 1
            self._scale_total[result.scale_source] += 1
        self._note_tracking(stamp_ns, result)
        path_time = 0.0
        if result.has_odometry:
            path_time = self._publish(odom)
        if not result.ok:
            self._report_drop(stamp_ns, result)
        node_time = time.perf_counter() - start
        self._node_time += node_time
        self._last_frame_time = node_time
        self._period_time.append(node_time)
        self._last_result = result
        focal = self._note_focal()
        self._publish_status(msg.header, result, node_time, path_time, focal)

    def _info_hint(self) -> str:
        """Why no CameraInfo came, as far as the graph tells (a user test: a latched CameraInfo
        the default QoS does not receive left only "no camera intrinsics yet")."""
        sub = self._camera_info_sub
        if sub is None:
            return ''
        topic = sub.topic_name
        publishers = self.get_publishers_info_by_topic(topic)
        if not publishers:
            return f'; no publisher on {topic}'
        if self._counters['camera_info_errors']:
            return f'; every CameraInfo on {topic} so far was refused (see the warning)'
        latched = any(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                      for p in publishers)
        hint = (f'; {len(publishers)} publisher(s) on {topic} but no message arrived')
        if latched:
            hint += (f' (it publishes latched: subscribe with -p qos_overrides.{topic}.'
                     f'subscription.durability:=transient_local -p qos_overrides.{topic}.'
                     f'subscription.reliability:=reliable)')
        return hint

    def _note_focal(self) -> str:
        """Log the focal length when its source changes (a self-calibration says at the first
        frame that it runs on a provisional focal length, and when it adopts one) or when it
        moved by `_FOCAL_LOG_CHANGE` since the last line (the calibration's progress in a
        turn, a few lines). Returns the focal status line (for the status message)."""
        status = self._vo.focal_status()
        px, _, source = self._vo.focal_length()
        last = self._focal_logged
        moved = math.isfinite(px) and last is not None and math.isfinite(last[0]) and \
            abs(px / last[0] - 1.0) >= _FOCAL_LOG_CHANGE
        if last is None or source != last[1] or moved:
            self._focal_logged = (px, source)
            self.get_logger().info(status)
        return status

    def _dropped(self, stamp_ns: int, reason: DropReason, message: str) -> FrameResult:
        """A frame the node drops before or after the pipeline (no pose to report)."""
        return FrameResult(stamp=stamp_ns / 1e9, ok=False, pose=self._vo.pose.copy(),
                           pose_covariance=np.full((6, 6), np.nan), reason=reason,
                           message=message, tracking=self._vo.tracking)

    def _note_gap(self, stamp_ns: int) -> None:
        """Count frames lost before reaching the node (`GapCounter`: an interval far above the
        usual one; a clock glitch, a looped bag or a new frame rate are none)."""
        gap = self._gaps.note(stamp_ns, busy=self._queued)
        self._counters['gaps'], self._counters['missing_frames'] = (self._gaps.gaps,
                                                                    self._gaps.missing)
        self._counters['missing_behind'] = self._gaps.behind
        if gap is None:
            return
        if gap.behind:
            self._period_behind += gap.missing
            took, period = 1e3 * self._last_frame_time, gap.period_ns / 1e6
            if took < period:
                # Faster than the stamps say (a live test: a recording played 6 times fast read
                # 'an image took 21 ms here, the camera sends one every 104 ms').
                why = (f'an image took {took:.0f} ms here, less than the {period:.0f} ms '
                       f'between the images\' stamps: they come faster than their stamps (a '
                       f'recording played faster than real time? ros2 bag play --rate)')
            else:
                why = (f'an image took {took:.0f} ms here, the camera sends one every '
                       f"{period:.0f} ms; lower the camera's frame rate (a throttle), the "
                       f"front-end's work (frontend.max_correspondences) or the load on this "
                       f'core')
            self._warn('behind', f'the node falls behind the camera: about {gap.missing} '
                                 f'frame(s) before {_format_stamp(stamp_ns)} were dropped from '
                                 f'its subscription queue unprocessed ({why}); odometry bridges '
                                 f'the gaps')
            return
        self._warn('gap', f'gap of {gap.interval_ns / 1e6:.0f} ms in the image stamps before '
                          f'{_format_stamp(stamp_ns)} (about {gap.missing} frame(s) missing at '
                          f'{1e9 / gap.period_ns:.1f} Hz); odometry bridges it')
        change = gap.rate_change
        if change is not None:
            self.get_logger().info(
                f'image rate changed from {change.before_hz:.1f} to {change.after_hz:.1f} Hz: '
                f'the last {GapCounter.RATE_CHANGE_GAPS} intervals were the new rate, not lost '
                f'frames (taken off the gap counts)')

    def _note_tracking(self, stamp_ns: int, result: FrameResult) -> None:
        """One log line per change of the tracking state (warnings for lost and reinitialised);
        a reset of the pipeline (time jumped back) also restarts the path."""
        state = result.tracking
        if state is self.tracking:
            return
        before, self.tracking = self.tracking, state
        self._counters['tracking_changes'] += 1
        if result.reason is DropReason.TIME_JUMP_BACK:
            self._clear_path()
        why = 'ok' if result.ok else f'{result.reason.value}: {result.message}'
        line = (f'tracking state {before.value} -> {state.value} at '
                f'{_format_stamp(stamp_ns)} ({why})')
        if state in (TrackingState.LOST, TrackingState.REINITIALISED):
            self.get_logger().warning(line)
        else:
            self.get_logger().info(line)

    # -- outputs -------------------------------------------------------------------------------

    def _odometry(self, header, result: FrameResult) -> Odometry:
        """The odometry message of an updated frame, stamped with the image's stamp."""
        ros = self.config.ros
        return odometry_message(_MESSAGE_TYPES, stamp_to_ns(header.stamp), result.pose,
                                odom_frame=ros.odom_frame, base_frame=ros.base_frame,
                                pose_covariance=result.pose_covariance, twist=result.twist,
                                twist_covariance=result.twist_covariance)

    def _publish(self, odom: Odometry) -> float:
        """Odometry, the path (when due and someone listens) and the TF; returns the seconds
        spent on the path."""
        self._odom_pub.publish(odom)
        start = time.perf_counter()
        pose = PoseStamped()
        pose.header = odom.header
        pose.pose = odom.pose.pose
        self._add_to_path(pose)
        self.publish_path(odom.header)
        path_time = time.perf_counter() - start
        if self._tf is not None:
            tf = TransformStamped()
            tf.header = odom.header
            tf.child_frame_id = odom.child_frame_id
            t, p = tf.transform.translation, odom.pose.pose.position
            t.x, t.y, t.z = p.x, p.y, p.z
            tf.transform.rotation = odom.pose.pose.orientation
            self._tf.sendTransform(tf)
        return path_time

    def _add_to_path(self, pose: PoseStamped) -> None:
        """Keep ``pose`` when it lies ``ros.path_spacing`` from the last pose kept; else it
        becomes the path's tip (the path always ends at the latest pose)."""
        spacing = self.config.ros.path_spacing
        if self._path and spacing > 0.0:
            a, b = self._path[-1].pose.position, pose.pose.position
            if math.hypot(b.x - a.x, b.y - a.y) < spacing:
                self._path_tip = pose
                return
        self._path.append(pose)
        self._path_tip = None

    def _clear_path(self) -> None:
        self._path.clear()
        self._path_tip = None
        self._path_published = -math.inf
        self._path_header = None

    def path_poses(self) -> list[PoseStamped]:
        """The poses the next ``path`` message carries."""
        return list(self._path) + ([self._path_tip] if self._path_tip is not None else [])

    def publish_path(self, header, *, force: bool = False) -> bool:
        """Publish the path if someone listens and ``ros.path_period`` seconds of image time
        have passed since the last one (or ``force``); returns whether it was published.

        Image time rather than wall time: the cost per frame is then the same live and in a
        bag played fast. A message costs about 10 us per pose, so with at most
        ``ros.path_max_length`` poses (500: about 5 ms) once per second (every 10 frames at
        10 Hz) the path costs about 0.5 ms per frame however long the drive."""
        stamp = stamp_to_ns(header.stamp) / 1e9
        self._path_header = header
        if self._path_pub.get_subscription_count() == 0 or (
                not force and abs(stamp - self._path_published) < self.config.ros.path_period):
            return False
        path = Path()
        path.header = header
        path.poses = self.path_poses()
        self._path_pub.publish(path)
        self._path_published = stamp
        self._path_header = None
        return True

    def _report_drop(self, stamp_ns: int, result: FrameResult) -> None:
        if result.reason is DropReason.FIRST_FRAME:
            self.get_logger().info(f'{_format_stamp(stamp_ns)}: first frame of the keyframe '
                                   f'chain ({result.message}); odometry at the origin')
            return
        # Rate-limited per reason and cause (the message up to its first ';', numbers aside:
        # stamps, sizes; what follows is the state it left, 'tracking lost: ...'): a new
        # cause of the same reason is logged at once (a user test: six images of an
        # unsupported encoding after a zero-size one were never named in the log); beyond
        # `_CAUSES` causes per reason (messages that differ in more than numbers) the reason's
        # own limit holds.
        reason = result.reason.value
        cause = _NUMBER.sub('#', result.message.split(';', 1)[0])[:120]
        causes = self._causes.setdefault(reason, set())
        if cause in causes or len(causes) < _CAUSES:
            causes.add(cause)
            key = f'{reason}: {cause}'
        else:
            key = reason
        self._warn(key, f'frame {_format_stamp(stamp_ns)} dropped, {reason}: '
                        f'{result.message}', reason)

    def _focal_values(self, line: str | None = None) -> dict[str, Any]:
        """``focal_px``, ``focal_std_px``, ``focal_source`` (`VisualOdometry.focal_length`: the
        focal length the status line describes) and ``focal`` (that line, or ``line`` when the
        caller has it)."""
        px, std, source = self._vo.focal_length()
        if source == 'unknown' and self._camera is not None and self._vo.camera is None:
            # A CameraInfo before any frame used it; not one the frames could not use (a
            # review: a model of another size than the images was named the source here).
            px, std, source = self._camera.fx, 0.0, 'camera_info'
        if source == 'unknown':
            px = std = 'n/a'        # not NaN and infinity, read as a fault (a review)
        return {'focal_px': px, 'focal_std_px': std, 'focal_source': source,
                'focal': self._vo.focal_status() if line is None else line}

    def _counts(self) -> dict[str, Any]:
        """The running totals, shared by ``status`` and ``/diagnostics``."""
        values: dict[str, Any] = {
            'frames': sum(self.outcomes.values()),
            'odometry_out': self.odometry_out,
            'first_frames': self.outcomes[_FIRST_FRAME],
            'dropped': sum(_drops(self.outcomes).values()),
        }
        for reason in DropReason:
            if reason.value != _FIRST_FRAME:
                values[f'dropped.{reason.value}'] = self.outcomes[reason.value]
        for name in ('camera_info_errors', 'camera_changes', 'speed_messages', 'speed_errors',
                     'gaps', 'missing_frames', 'missing_behind', 'resets', 'tracking_changes'):
            values[name] = self._counters[name]
        return values

    def _publish_status(self, header, result: FrameResult, node_time: float,
                        path_time: float, focal: str) -> None:
        """One `DiagnosticStatus` per image: this frame's outcome and the running counters."""
        status = DiagnosticStatus()
        status.name = f'{self.get_name()}: visual odometry'
        status.hardware_id = self.get_fully_qualified_name()     # as on /diagnostics
        if result.has_odometry:
            status.level = DiagnosticStatus.OK
        elif result.reason is DropReason.PIPELINE_ERROR:
            status.level = DiagnosticStatus.ERROR
        else:
            status.level = DiagnosticStatus.WARN
        key = 'ok' if result.ok else result.reason.value
        status.message = key if not result.message else f'{key}: {result.message}'
        if result.ok and result.scale_source == 'unit' and self.config.scale.source != 'unit':
            # A step of unknown length (no metric step to hold): say so (a user test: the
            # first steps of a fast drive were 'ok' at 1 m each).
            status.level = DiagnosticStatus.WARN
            status.message += (f'; a unit step: no metric length from scale.source '
                               f'{self.config.scale.source} or the fallback '
                               f'{self.config.scale.fallback}')
        values = {
            'stamp_ns': stamp_to_ns(header.stamp),
            'result': key,
            'tracking': result.tracking.value,
            'keyframe': result.keyframe,
            # Every frame names its scale source: 'none' when it produced no step.
            'scale_source': result.scale_source if result.ok else 'none',
            'scale_from': result.scale_from if result.ok else '',
            **self._focal_values(focal),
            'correspondences': result.num_correspondences,
            'inliers': result.num_inliers,
            'alpha_rad': result.alpha,
            'beta_rad': result.beta,
            **self._counts(),
        }
        for stage, seconds in result.timings.items():
            values[f'time_ms.{stage}'] = round(seconds * 1e3, 3)
        values['time_ms.path'] = round(path_time * 1e3, 3)
        values['time_ms.node'] = round(node_time * 1e3, 3)
        status.values = [KeyValue(key=k, value=_format_value(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = header.stamp
        array.header.frame_id = header.frame_id
        array.status = [status]
        self._status_pub.publish(array)

    def listened_topics(self) -> list[str]:
        """The resolved (remapped) names of the input topics."""
        return [sub.topic_name for sub in (self._image_sub, self._camera_info_sub,
                                           self._speed_sub) if sub is not None]

    def _watch_timer(self, timeout: float):
        """The no-image timer (`_on_image_watch`), on the steady clock (it goes on when a
        simulated clock stops)."""
        return self.create_timer(timeout, self._busy(self._on_image_watch),
                                 clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _on_image_watch(self) -> None:
        """The no-image warning as soon as ``ros.image_timeout`` passes without an image (the
        timer's period; every image restarts it); while the silence lasts, the diagnostics tick
        repeats it (rate-limited by ``ros.warn_period``)."""
        silent = time.monotonic() - self._last_image
        if not self._silence_reported and \
                silent >= self.config.ros.image_timeout - _IMAGE_WATCH_SLACK:
            self._silence_reported = True
            self._warn_no_image(silent)

    def _warn_no_image(self, silent: float) -> None:
        image_topic = self._image_sub.topic_name
        publishers = self.count_publishers(image_topic)
        # (restated every ros.warn_period while the silence lasts, its length growing; a user
        # test: 'suppressed' counted the diagnostics ticks' restatements as warnings)
        self._warn('no_image', f'no image for {silent:.1f} s on {image_topic} '
                               f'({publishers} publisher(s)); listening on '
                               f'{", ".join(self.listened_topics())}; check the remapping '
                               f'(-r image:=...) and the QoS', count=False)

    def _on_diagnostics_timer(self) -> None:
        """``/diagnostics``: the state and rates since the last message, for
        ``diagnostic_aggregator`` (its analyzers group by the status name, e.g. ``startswith:
        ['planar_vo']`` or ``contains: ['visual odometry']``); warns when images stop."""
        now = time.monotonic()
        silent = now - self._last_image
        timeout = self.config.ros.image_timeout
        image_topic = self._image_sub.topic_name
        if silent >= timeout:
            self._silence_reported = True
            self._warn_no_image(silent)
        if self._path_header is not None and silent >= self.config.ros.path_period:
            # The end of a stopped stream (while images arrive, ros.path_period paces the path).
            self.publish_path(self._path_header, force=True)
        frames = sum(self._period.values())
        period = self.config.ros.diagnostics_period
        status = DiagnosticStatus()
        status.name = f'{self.get_name()}: visual odometry'
        status.hardware_id = self.get_fully_qualified_name()
        state = self.tracking
        if silent >= timeout:
            status.level = DiagnosticStatus.WARN
            status.message = f'no image for {silent:.1f} s on {image_topic}'
        elif self._period[DropReason.PIPELINE_ERROR.value]:
            status.level = DiagnosticStatus.ERROR
            status.message = f'{state.value}; pipeline errors'
        elif frames and not _with_odometry(self._period):
            # Images arrive but none gives odometry (say, a driver switched to an encoding the
            # node cannot read): the tracking state may still say tracking.
            reason, count = max(self._period.items(), key=lambda kv: kv[1])
            status.level = DiagnosticStatus.WARN
            status.message = (f'{state.value}; no odometry from {frames} images in the last '
                              f'{period:g} s ({reason}: {count})')
        elif frames >= 4 and 2 * _with_odometry(self._period) <= frames:
            # Half the images or more give none (a user test: every other frame undecodable
            # was OK, 'tracking; 10.0 images/s').
            reason, count = max(_drops(self._period).items(), key=lambda kv: kv[1])
            status.level = DiagnosticStatus.WARN
            status.message = (f'{state.value}; odometry from {_with_odometry(self._period)} '
                              f'of {frames} images in the last {period:g} s ({reason}: '
                              f'{count})')
        elif self._period_behind:
            status.level = DiagnosticStatus.WARN
            status.message = (f'{state.value}; falling behind the camera: '
                              f'{self._period_behind} images dropped unprocessed in the last '
                              f'{period:g} s ({frames / period:.1f} images/s processed)')
        elif (unscaled := self._unscaled_period()) is not None:
            status.level = DiagnosticStatus.WARN
            status.message = f'{state.value}; {unscaled}'
            # (unit steps beside metric ones warned apart: one key held the other back, a
            # review)
            self._warn('unit_steps' if 'unit step' in unscaled.split('(')[0] else 'scale',
                       unscaled)
        elif not frames and self._pending:
            # Images came and wait for the first CameraInfo (a user test: '0.0 images/s; no
            # image for 0.0 s').
            status.level = DiagnosticStatus.WARN
            status.message = (f'{state.value}; {len(self._pending)} image(s) waiting for the '
                              f'first CameraInfo on {self._camera_info_sub.topic_name}')
        else:
            status.level = (DiagnosticStatus.OK if state is TrackingState.TRACKING
                            else DiagnosticStatus.WARN)
            status.message = f'{state.value}; {frames / period:.1f} images/s'
            if not frames:
                # Not yet a warning (a slow camera), but not silently OK either.
                status.message += (f'; no image for {silent:.1f} s (a warning at '
                                   f'ros.image_timeout, {timeout:g} s)')
        last = self._last_result
        values = {
            'tracking': state.value,
            'images_per_s': frames / period,
            'odometry_per_s': _with_odometry(self._period) / period,
            # No image in the period: no time to report (a user test: 'nan' read as a fault).
            'mean_time_ms': 1e3 * float(np.mean(self._period_time)) if frames else 'n/a',
            'max_time_ms': 1e3 * max(self._period_time) if frames else 'n/a',
            'seconds_since_image': silent,
            'image_topic': image_topic,
            'listening_on': ' '.join(self.listened_topics()),
            'scale_source': (last.scale_source if last.ok else 'none') if last else 'none',
            'road_top_ups': self._vo.road_top_ups,
            'image_road_steps': self._vo.image_road_steps,
            'image_road_misses': sum(self._vo.image_road_misses.values()),
            **self._focal_values(),
            'path_poses': len(self._path) + (self._path_tip is not None),
            **{f'period.{k}': v for k, v in sorted(self._period.items())},
            **self._counts(),
        }
        status.values = [KeyValue(key=k, value=_format_value(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diagnostics_pub.publish(array)
        self._period.clear()
        self._period_scale.clear()
        self._period_time.clear()
        self._period_behind = 0

    def _unscaled_period(self) -> str | None:
        """Why the odometry of the last diagnostics period had no step from the configured
        scale source (only fallbacks: held or unit steps) or unit steps beside its steps, or
        None when it had neither (or stood still). A speed topic whose samples never cover the
        image stamps (another clock) is named as such."""
        source = self.config.scale.source
        scales = self._period_scale
        if source == 'unit' or not scales:
            return None
        used = ', '.join(f'{k} {v}' for k, v in sorted(scales.items()))
        if scales[source] or scales['stationary']:
            if scales['unit']:
                # Steps of unknown length beside metric ones (a drive's start before its first
                # metric step; a user test: the period said OK with 6 of 8 unit steps).
                return (f'{plural(scales["unit"], "unit step")} (no metric length) in the '
                        f'last {self.config.ros.diagnostics_period:g} s (steps: {used})')
            return None
        line = (f'no step from scale.source {source} in the last '
                f'{self.config.ros.diagnostics_period:g} s (steps: {used})')
        if source == 'speed':
            received = self._counters['speed_messages']
            line += (f'; {received} speed messages so far, none covering the image stamps '
                     f'(check the speed topic\'s stamps and clock)' if received else
                     f'; no speed message received on {self._speed_sub.topic_name}'
                     + self._speed_type_mismatch())
        return line

    def _speed_type_mismatch(self) -> str:
        """The publishers of the speed topic whose type is not the subscribed one, and the
        ``ros.speed_topic_type`` that reads them ('' when there is none): a type mismatch
        delivers nothing and says nothing (a user test: an Odometry topic with the default
        twist type)."""
        topic = self._speed_sub.topic_name
        wanted = self._speed_sub.msg_type.__module__.split('.')[0]
        wanted = f'{wanted}/msg/{self._speed_sub.msg_type.__name__}'
        others = sorted({info.topic_type for info in self.get_publishers_info_by_topic(topic)
                         if info.topic_type != wanted})
        if not others:
            return ''
        hint = {'nav_msgs/msg/Odometry': ' (-p ros.speed_topic_type:=odometry reads it)',
                'geometry_msgs/msg/TwistStamped': ' (-p ros.speed_topic_type:=twist reads it)'}
        return (f": its publishers' type is {', '.join(others)}, not {wanted}"
                + ''.join(hint.get(t, '') for t in others))

    def _warn(self, key: str, message: str, label: str | None = None,
              count: bool = True) -> None:
        """`message` at warning level, rate-limited per ``key`` (``ros.warn_period``); the
        note of the ones held back names ``label`` (default: the key); ``count`` False for a
        condition restated while it lasts (not events to count as suppressed)."""
        held = self._throttle.admit(key, count=count)
        if held is None:
            return
        if held:
            message += f' ({held} more {label or key} warning(s) suppressed in the last ' \
                       f'{self._throttle.period:g} s)'
        self.get_logger().warning(message)

    @property
    def odometry_out(self) -> int:
        """Images that gave an odometry message so far (a motion, or the origin)."""
        return _with_odometry(self.outcomes)

    def summary(self) -> str:
        """One line: frames in, odometry out, drops per reason, other counters, mean time."""
        frames = sum(self.outcomes.values())
        drops = _drops(self.outcomes)
        dropped = ', '.join(f'{k} {v}' for k, v in drops.items()) or 'none'
        mean = f'{1e3 * self._node_time / frames:.1f} ms' if frames else 'n/a'
        origins = self.outcomes[_FIRST_FRAME]
        among = (f' ({origins} at the origin among them: the first frame of each keyframe '
                 f'chain)' if origins else '')
        return (f'summary: {frames} frames in, {self.odometry_out} odometry out'
                f'{among}, '
                f'{sum(drops.values())} dropped ({dropped}); '
                f'{self._counters["missing_frames"]} frames missing in '
                f'{self._counters["gaps"]} gaps'
                + (f' ({self._counters["missing_behind"]} dropped unprocessed: the node fell '
                   f'behind the camera)' if self._counters["missing_behind"] else '') + '; '
                f'{self._counters["camera_info_errors"]} camera_info errors; '
                f'{self._counters["speed_messages"]} speed messages'
                + (f' ({self._counters["speed_errors"]} refused)'
                   if self._counters["speed_errors"] else '') + '; '
                f'{self._counters["resets"]} resets; mean {mean} per frame; '
                f'step lengths {self._steps_note()}; '
                f'{self._vo.focal_status()}' + self._carry_note())

    def _steps_note(self) -> str:
        """The odometry's step lengths by source, with the ground steps from the road's pixels
        and that scan's misses (as the replay summary's line)."""
        vo = self._vo
        note = pixels_note(vo.image_road_steps, vo.image_road_misses, vo.image_road_examples)
        sources = ', '.join(f'{k} {v}' for k, v in sorted(self._scale_total.items())) or 'none'
        if self.config.scale.source != 'unit' and self._scale_total['unit']:
            note += '; ' + unit_note(self._scale_total)
        return sources + (f' ({note[2:]})' if note else '')

    def _carry_note(self) -> str:
        """The self-calibrated focal length as the parameters that start this camera's next
        run from it (`VisualOdometry.focal_carry`), or ''."""
        carry = self._vo.focal_carry()
        if not carry:
            return ''
        return ('; the next run of this camera starts from it with '
                + ' '.join(f'-p {k}:={v:g}' for k, v in carry.items()))


def _parameter_file_entries(path: str) -> tuple[list[str], set[str]]:
    """The node keys of a ROS parameter file and the dotted names of all its parameters (empty
    when it cannot be read: rcl has reported that already)."""
    import yaml

    try:
        data = yaml.safe_load(FilePath(path).read_text(encoding='utf-8'))
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return [], set()
    keys: list[str] = []
    names: set[str] = set()

    def flat(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                flat(f'{prefix}.{k}' if prefix else str(k), v)
        else:
            names.add(prefix)

    def walk(prefix: str, value: Any) -> None:
        if not isinstance(value, dict):
            return
        for k, v in value.items():
            if k == 'ros__parameters':
                keys.append(prefix or '/')
                flat('', v)
            else:
                walk(f'{prefix}/{k}'.replace('//', '/') if prefix else str(k), v)

    walk('', data)
    return keys, names


def _format_stamp(stamp_ns: int) -> str:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return f'{sec}.{nsec:09d}'


def _format_value(value: Any) -> str:
    """A status value's text; a number that is not there (NaN: a dropped frame's motion) is
    'n/a', like the focal length's (a user test: 'nan' read as a fault)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return 'n/a' if math.isnan(value) else f'{value:.6g}'
    return str(value)


def ros_arguments(argv: Sequence[str]) -> tuple[list[str], dict[str, list[str]]]:
    """The ``--params-file`` files and the names set with ``-p [NODE:]NAME:=VALUE`` inside
    the ``--ros-args`` sections of ``argv`` (with the node prefix, if any); each name with the
    files that come after its ``-p`` (rcl applies the arguments in order, so such a file's
    value wins)."""
    files: list[str] = []
    names: dict[str, list[str]] = {}
    ros, items = False, iter(argv)
    for arg in items:
        if arg == '--ros-args':
            ros = True
        elif arg == '--':
            ros = False
        elif ros and arg == '--params-file':
            files.append(next(items, ''))
            for later in names.values():
                later.append(files[-1])
        elif ros and arg in ('-p', '--param'):
            names[next(items, '').partition(':=')[0]] = []
    return files, names


# The node's input topics (before remapping); `listened_topics` are those a configuration uses.
_INPUTS = ('image', 'image/compressed', 'camera_info', 'speed')


def _override_topic(name: str) -> str:
    """The topic of a ``qos_overrides.<topic>.subscription.<policy>`` parameter name."""
    return name.removeprefix('qos_overrides.').rpartition('.subscription.')[0]


def _rcl_error_line(err: Exception) -> str:
    """rcl's argument error on one line, without its C source locations; its unknown-argument
    error, which says only the list (``['--foo']``; a user test), in words."""
    if type(err).__name__ == 'UnknownROSArgsError':
        return (f'unknown ROS argument(s) {str(err)} after --ros-args (-r FROM:=TO, -p '
                f'NAME:=VALUE, --params-file FILE, --log-level LEVEL; planar_vo_node --help '
                f'shows them)')
    text = ' '.join(str(err).split())
    text = text.removeprefix('failed to initialize rcl: ')
    return text.split(', at /')[0].rstrip('.,') or 'invalid ROS arguments'


def _installed_parameter_file() -> str:
    try:
        from ament_index_python.packages import get_package_share_directory

        share = FilePath(get_package_share_directory('planar_vo'))
    except Exception:  # noqa: BLE001 - no ament index (a plain pip install): the venv's share
        share = FilePath(sys.prefix) / 'share' / 'planar_vo'
    return str(share / 'config' / 'planar_vo.yaml')


def usage() -> str:
    """``planar_vo_node --help``: remaps, the parameter file, the main parameters."""
    defaults, descriptions = flatten(PlanarVoConfig()), describe()
    lines = [
        'usage: ros2 run planar_vo planar_vo_node [--help] [--ros-args [-r FROM:=TO ...]',
        '           [--params-file FILE] [-p NAME:=VALUE ...] [--log-level LEVEL]]',
        '       planar_vo_node [--help] [--ros-args ...]   (the same, without the ros2 command: '
        'a venv)',
        '',
        'Planar monocular visual odometry (Hajder and Barath 1AC + voting): images in, odometry '
        'out.',
        '',
        'topics and services (relative names: remap them with -r):',
        '  image              sensor_msgs/Image in; -r image:=/camera/image_raw',
        '  image/compressed   sensor_msgs/CompressedImage in (-p ros.image_transport:=compressed);',
        '                     -r image/compressed:=/camera/image_raw/compressed',
        '  camera_info        sensor_msgs/CameraInfo in (not with camera.fx > 0 or '
        'camera.estimate_focal)',
        '  speed              geometry_msgs/TwistStamped or nav_msgs/Odometry in '
        '(scale.source: speed)',
        '  odom, path         nav_msgs/Odometry, nav_msgs/Path out; TF odom -> base_link',
        '  status             diagnostic_msgs/DiagnosticArray out, one per image',
        '  /diagnostics       diagnostic_msgs/DiagnosticArray out, every '
        'ros.diagnostics_period s',
        '  ~/reset            std_srvs/srv/Trigger: pose back to the origin, counters kept',
        '',
        f'parameter file (every parameter, its default and description):\n  '
        f'{_installed_parameter_file()}',
        '',
        'main parameters (ros2 param describe shows every one with its range):',
    ]
    for name in _MAIN_PARAMETERS:
        # As ROS parameters are typed: true/false, not Python's True/False (a user test).
        value = defaults[name]
        shown = str(value).lower() if isinstance(value, bool) else repr(value)
        lines += textwrap.wrap(f'{name} (default {shown}): {descriptions[name]}', 96,
                               initial_indent='  ', subsequent_indent='      ')
    lines += [
        '',
        'example:',
        '  ros2 run planar_vo planar_vo_node --ros-args \\',
        f'      --params-file {_installed_parameter_file()} \\',
        '      -r image:=/camera/image_raw -r camera_info:=/camera/camera_info \\',
        '      -p mount.height:=1.65',
        '  (rcl applies the arguments in order: -p after --params-file overrides the file)',
    ]
    return '\n'.join(lines)


class _StopRequest:
    """SIGINT and SIGTERM only set a flag, which the spin loop checks between callbacks.

    rclpy's own handlers (``SignalHandlerOptions.ALL``) stop a node in two racing ways: they
    shut the context down from a signal-handling thread and wake the executor once, and the
    chained Python handler raises ``KeyboardInterrupt`` wherever the main thread happens to be.
    When the wake-up lands before the shutdown, the executor finds nothing to do and waits
    again, now without a deadline: the node keeps running until a second signal. Here nothing
    is asynchronous: the executor waits at most `POLL` seconds, and the loop ends after the
    callback in progress. A second Ctrl-C during the clean-up only sets the flag again; `done`
    then ignores the signals for the interpreter's exit, which would otherwise restore the
    default handlers and let one more kill the process (exit code -2 after a clean stop).
    """

    POLL = 0.1

    def __init__(self) -> None:
        self.signal: int | None = None
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)
        # One that came before (while the node was imported: `planar_vo.ros.startup`); read
        # after the handlers are in place, so that none falls between (a review).
        self.signal = pending_stop()

    def _handle(self, signum: int, frame: Any) -> None:
        self.signal = signum

    @staticmethod
    def done() -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)


class _RosLogHandler(logging.Handler):
    """Forwards the library's `logging` records (tilt calibration, time jumps, ...) to the
    node's logger, so that they reach the console and ``/rosout`` like the node's own lines.

    Each library module logs through a child of the node's logger named after it
    (``[planar_vo.pipeline.calibration.tilt]``, inheriting the node's level), so the module
    stands where ROS puts a logger's name, not in the text (a user test: ``[planar_vo]:
    planar_vo.pipeline...: ...``)."""

    def __init__(self, logger) -> None:
        super().__init__()
        self._logger = logger
        self._children: dict[str, Any] = {}

    def logger_for(self, name: str):
        """The node logger's child for the library logger ``name`` (the node's own logger for
        the package's root logger)."""
        child = name.removeprefix('planar_vo').lstrip('.')
        if not child:
            return self._logger
        if child not in self._children:
            self._children[child] = self._logger.get_child(child)
        return self._children[child]

    def emit(self, record: logging.LogRecord) -> None:
        logger = self.logger_for(record.name)
        message = record.getMessage()
        if record.levelno >= logging.ERROR:
            logger.error(message)
        elif record.levelno >= logging.WARNING:
            logger.warning(message)
        elif record.levelno >= logging.INFO:
            logger.info(message)
        else:
            logger.debug(message)


def _stray_arguments(argv: Sequence[str]) -> list[str]:
    """The arguments after the program name that are neither ROS arguments (inside a
    ``--ros-args`` section) nor ``--help``; none when rcl cannot parse the ROS arguments
    (`rclpy.init` then says why)."""
    from rclpy.utilities import remove_ros_args

    try:
        rest = remove_ros_args(list(argv))
    except RuntimeError:                    # rclpy's RCLError, as in `main`
        return []
    return [a for a in rest[1:] if a not in ('-h', '--help')]


def main(args: list[str] | None = None) -> int:
    """Entry point: ``--help`` prints `usage`; otherwise init, spin until SIGINT or SIGTERM,
    clean up (Jazzy idiom: try_shutdown in finally).

    Returns 0 after SIGINT or SIGTERM, 1 when the parameters are invalid. The entry point of
    a process: SIGINT and SIGTERM are ignored once it returns (the process is exiting).
    """
    argv = sys.argv if args is None else args
    ros_start = argv.index('--ros-args') if '--ros-args' in argv else len(argv)
    if {'-h', '--help'} & set(argv[1:ros_start]):
        try:
            print(usage(), flush=True)
        except OSError as err:
            # A reader that stopped early (`planar_vo_node --help | head`): the rest goes
            # nowhere; a stdout that cannot be written (/dev/full): one line. Either way
            # Python's flush at exit must not fail on it again (user tests: tracebacks).
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            if not isinstance(err, BrokenPipeError):
                print(f'planar_vo_node: cannot write the help to stdout: {err}', file=sys.stderr)
                return 1
        return 0
    stray = _stray_arguments(argv)
    if stray:
        # Outside --ros-args rcl ignores them: the node would start on its defaults (a user
        # test ran `planar_vo_node -p mount.height:=1.65` at the default 1.5 m).
        print(f"planar_vo_node: unexpected argument(s) {' '.join(stray)!r} outside --ros-args:"
              f' the node takes its parameters, remappings and parameter files after '
              f'--ros-args (planar_vo_node --ros-args -p mount.height:=1.65); '
              f'planar_vo_node --help lists them', file=sys.stderr)
        return 1
    stop = _StopRequest()
    limit_blas_threads()        # idle OpenBLAS workers busy-wait: one thread is faster here
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as err:         # rclpy's RCLError: rcl could not parse --ros-args
        stop.done()
        print(f'planar_vo_node: {_rcl_error_line(err)}', file=sys.stderr)
        return 1
    library_log = logging.getLogger('planar_vo')
    node = executor = handler = None
    try:
        files, names = ros_arguments(argv)
        node = PlanarVoNode(parameter_files=files, command_line_parameters=names)
        handler = _RosLogHandler(node.get_logger())
        library_log.addHandler(handler)
        library_log.setLevel(logging.INFO)
        library_log.propagate = False
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while stop.signal is None and rclpy.ok():
            executor.spin_once(timeout_sec=_StopRequest.POLL)
    except ExternalShutdownException:
        pass
    except ConfigError:
        return 1            # the fatal line naming the parameter is already logged
    finally:
        if handler is not None:
            library_log.removeHandler(handler)
            library_log.propagate = True
        if executor is not None:
            executor.shutdown()
        if node is not None:
            try:
                node.flush_pending()            # counted like any frame; publishing may fail
            except Exception:  # noqa: BLE001 - shutting down: the count matters, not the publish
                pass
            node.get_logger().info(node.summary())
            node.destroy_node()
        rclpy.try_shutdown()
        stop.done()
    return 0


if __name__ == '__main__':      # python -m planar_vo.ros.node: as the planar_vo_node executable
    sys.exit(main())
