"""The planar_vo ROS 2 node (``ros2 run planar_vo planar_vo_node``), the only module importing
rclpy.

Topics (relative names, so that ``--ros-args -r image:=/camera/image_raw`` remaps them):

- subscribes ``image`` (``sensor_msgs/Image``; mono8, mono16, rgb8, bgr8, ... see
  `planar_vo.ros.messages`) or, with ``ros.image_transport: compressed``, ``image/compressed``
  (``sensor_msgs/CompressedImage``, JPEG or PNG); ``camera_info`` (``sensor_msgs/CameraInfo``)
  unless ``camera.fx > 0`` gives the intrinsics; ``speed`` (``geometry_msgs/TwistStamped``, or
  ``nav_msgs/Odometry`` with ``ros.speed_topic_type: odometry``) when ``scale.source`` is
  ``speed``. Sensor inputs use the sensor-data QoS profile.
- publishes ``odom`` (``nav_msgs/Odometry``, stamped with the image's header stamp, pose and
  twist with covariance), ``path`` (``nav_msgs/Path``, the last ``ros.path_max_length`` poses),
  ``status`` (``diagnostic_msgs/DiagnosticArray``, one per image: result, inliers, timings,
  scale source, cumulative counters) and the TF ``odom -> base_link`` when ``tf2_ros`` is
  installed and ``ros.publish_tf`` is set.

Every image yields either an odometry message or a counted `DropReason` (an image the node
cannot decode counts as ``bad_image``); each reason is logged as a specific warning at most once
per ``ros.warn_period`` seconds. Frames the transport lost never reach the node: they show up as
gaps in the image stamps and are counted as ``missing_frames``.

Parameters are the dotted keys of `planar_vo.config.PlanarVoConfig` (``voting.bins``, ...),
declared with descriptions and validated through the same config object: an invalid value at
start-up is one fatal log line and exit code 1; at run time it is rejected. Run-time changes are
applied for ``ros.publish_tf``, ``ros.path_max_length``, ``ros.warn_period``; the others are read
at start-up only.
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
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
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from planar_vo.config import PlanarVoConfig, describe, flatten
from planar_vo.core.camera import CameraModel
from planar_vo.errors import CameraModelError, ConfigError, ImageError, InputError
from planar_vo.pipeline import DropReason, FrameResult, VisualOdometry
from planar_vo.ros.messages import (
    compressed_to_array,
    image_to_array,
    odometry_message,
    speed_from_message,
    stamp_to_ns,
)

try:  # tf2_ros comes with a ROS installation; it is not on PyPI.
    from tf2_ros import TransformBroadcaster
except ImportError:  # pragma: no cover - depends on the installation
    TransformBroadcaster = None

__all__ = ['LIVE_PARAMETERS', 'PlanarVoNode', 'main']

# Parameters that may change while the node runs; the others shape subscriptions and the pipeline.
LIVE_PARAMETERS = frozenset({'ros.publish_tf', 'ros.path_max_length', 'ros.warn_period'})

# The rclpy classes of the message types `odometry_message` builds.
_MESSAGE_TYPES = {
    'nav_msgs/msg/Odometry': Odometry, 'std_msgs/msg/Header': Header,
    'builtin_interfaces/msg/Time': Time, 'geometry_msgs/msg/PoseWithCovariance': PoseWithCovariance,
    'geometry_msgs/msg/Pose': Pose, 'geometry_msgs/msg/Point': Point,
    'geometry_msgs/msg/Quaternion': Quaternion,
    'geometry_msgs/msg/TwistWithCovariance': TwistWithCovariance, 'geometry_msgs/msg/Twist': Twist,
    'geometry_msgs/msg/Vector3': Vector3,
}

# A stamp interval this many times the nominal frame period is a gap (frames lost on the way).
_GAP_FACTOR = 1.8
_PERIOD_WINDOW = 20


class WarningThrottle:
    """At most one warning per key every ``period`` seconds (monotonic clock), counting the
    ones held back so that the next emitted line can say how many were suppressed."""

    def __init__(self, period: float) -> None:
        self.period = float(period)
        self._last: dict[str, float] = {}
        self._held: Counter[str] = Counter()

    def admit(self, key: str, now: float | None = None) -> int | None:
        """None to stay quiet; else how many warnings of ``key`` were held back since the last."""
        now = time.monotonic() if now is None else now
        last = self._last.get(key)
        if last is not None and now - last < self.period:
            self._held[key] += 1
            return None
        self._last[key] = now
        return self._held.pop(key, 0)


class PlanarVoNode(Node):
    """Planar monocular visual odometry: images in, ``odom``, ``path``, ``status`` and TF out.

    Attributes:
        config: the validated `PlanarVoConfig` the node runs with.
        outcomes: images received per outcome, ``'ok'`` or a `DropReason` value.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('planar_vo', **kwargs)
        descriptions = describe()
        self._defaults = flatten(PlanarVoConfig())
        for name, default in self._defaults.items():
            # Dynamic typing: `mount.height:=2` (an integer) and `camera.distortion:=[...]` (the
            # default is an empty, untyped list) are allowed; the config object checks types.
            self.declare_parameter(name, default, ParameterDescriptor(
                description=descriptions[name], dynamic_typing=True))
        self._check_unknown_overrides()
        self.config = self._read_config()
        for name, value in flatten(self.config).items():
            self.get_logger().info(f'{name} = {value!r}')
        ros = self.config.ros

        self._vo = VisualOdometry(self.config)
        self._camera: CameraModel | None = None
        self._throttle = WarningThrottle(ros.warn_period)
        self.outcomes: Counter[str] = Counter()
        self._counters: Counter[str] = Counter()   # camera_info_errors, speed_*, gaps, ...
        self._node_time = 0.0
        self._last_stamp_ns: int | None = None
        self._intervals: deque[int] = deque(maxlen=_PERIOD_WINDOW)
        self._path: deque[PoseStamped] = deque(maxlen=ros.path_max_length or None)

        self._odom_pub = self.create_publisher(Odometry, 'odom', 10)
        self._path_pub = self.create_publisher(Path, 'path', 1)
        self._status_pub = self.create_publisher(DiagnosticArray, 'status', 10)
        self._tf = None
        self._set_tf(ros.publish_tf)

        # Sensor-data QoS (best effort) by default; `qos_overrides.<topic>.subscription.*`
        # parameters change it, e.g. to reliable for images too large for best-effort delivery.
        sensor = {'qos_profile': qos_profile_sensor_data,
                  'qos_overriding_options': QoSOverridingOptions.with_default_policies()}
        if ros.image_transport == 'compressed':
            self.create_subscription(CompressedImage, 'image/compressed', self._on_compressed,
                                     **sensor)
        else:
            self.create_subscription(Image, 'image', self._on_image, **sensor)
        self._pending: tuple | None = None
        # With estimate_focal the pipeline runs without CameraInfo: no image waits for one.
        camera = self.config.camera
        self._expects_camera_info = camera.fx <= 0 and not camera.estimate_focal
        if not self._expects_camera_info:
            self.get_logger().info('camera intrinsics from the camera.* parameters; not '
                                   'subscribing to camera_info')
        else:
            self.create_subscription(CameraInfo, 'camera_info', self._on_camera_info, **sensor)
        if self.config.scale.source == 'speed':
            speed_type = Odometry if ros.speed_topic_type == 'odometry' else TwistStamped
            self.create_subscription(speed_type, 'speed', self._on_speed, **sensor)
        self.add_on_set_parameters_callback(self._on_set_parameters)

    # -- parameters ----------------------------------------------------------------------------

    def _check_unknown_overrides(self) -> None:
        """A misspelt parameter (``voting.binz``) is an error, not silently ignored."""
        # rclpy keeps the command-line and parameter-file values it was given in this attribute;
        # names that no declaration claims are otherwise dropped without a word.
        overrides = getattr(self, '_parameter_overrides', {})
        unknown = sorted(n for n in overrides if not self.has_parameter(n)
                         and not n.startswith('qos_overrides.'))
        if unknown:
            message = (f'unknown parameter(s) {", ".join(unknown)}: expected planar_vo '
                       f'parameters such as {", ".join(list(self._defaults)[:3])}, ... (see '
                       f'config/planar_vo.yaml)')
            self.get_logger().fatal(f'invalid parameters: {message}')
            raise ConfigError(message)

    def _config_value(self, name: str, value: Any) -> Any:
        """A parameter value in the form the config expects."""
        if isinstance(self._defaults[name], list):
            # ROS has no typed empty list: a parameter file's `[]` arrives as "not set".
            return [] if value is None else list(value)
        return value

    def _flat_parameters(self) -> dict[str, Any]:
        return {name: self._config_value(name, self.get_parameter(name).value)
                for name in self._defaults}

    def _read_config(self) -> PlanarVoConfig:
        try:
            return PlanarVoConfig.from_flat(self._flat_parameters())
        except ConfigError as err:
            self.get_logger().fatal(f'invalid parameters: {err}')
            raise

    def _on_set_parameters(self, params: list) -> SetParametersResult:
        """Validate a run-time change through the config object; apply the live ones."""
        ours = [p for p in params if p.name in self._defaults]   # not e.g. use_sim_time
        if not ours:
            return SetParametersResult(successful=True)
        flat = self._flat_parameters()
        flat.update({p.name: self._config_value(p.name, p.value) for p in ours})
        try:
            config = PlanarVoConfig.from_flat(flat)
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        before, after = flatten(self.config), flatten(config)
        fixed = sorted(p.name for p in ours
                       if p.name not in LIVE_PARAMETERS and after[p.name] != before[p.name])
        if fixed:
            return SetParametersResult(
                successful=False,
                reason=f'{", ".join(fixed)}: read at start-up only (restart the node to change '
                       f'it); run-time changes: {", ".join(sorted(LIVE_PARAMETERS))}')
        ros = config.ros
        if ros.path_max_length != self.config.ros.path_max_length:
            self._path = deque(self._path, maxlen=ros.path_max_length or None)
        self._throttle.period = ros.warn_period
        if ros.publish_tf != self.config.ros.publish_tf:
            self._set_tf(ros.publish_tf)
        self.config = config
        return SetParametersResult(successful=True)

    def _set_tf(self, enabled: bool) -> None:
        if not enabled:
            self._tf = None
        elif TransformBroadcaster is None:
            self.get_logger().info('ros.publish_tf: tf2_ros is not installed (it comes with ROS, '
                                   'not PyPI); the odom -> base_link transform is not broadcast, '
                                   'odom and path are still published')
        elif self._tf is None:
            self._tf = TransformBroadcaster(self)

    # -- inputs --------------------------------------------------------------------------------

    def _on_image(self, msg: Image) -> None:
        self._image(msg, image_to_array)

    def _on_compressed(self, msg: CompressedImage) -> None:
        self._image(msg, compressed_to_array)

    def _image(self, msg: Image | CompressedImage, decode) -> None:
        """Until the first CameraInfo has arrived, an image waits in one slot for it: a driver
        publishes both with the same stamp but DDS does not order two topics, so the first image
        may arrive first. It runs when the CameraInfo comes, or as soon as another image does
        (then counted ``no_camera_info``, like every image that finds no camera model)."""
        if self._camera is None and self._expects_camera_info:
            self.flush_pending()
            self._pending = (msg, decode)
            return
        self.flush_pending()
        self._frame(msg, decode)

    def flush_pending(self) -> None:
        """Process the image waiting for the first CameraInfo, if any."""
        pending, self._pending = self._pending, None
        if pending is not None:
            self._frame(*pending)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            camera = CameraModel.from_camera_info(msg)
        except CameraModelError as err:
            self._counters['camera_info_errors'] += 1
            kept = 'keeping the last valid one' if self._camera is not None else \
                'no valid camera model yet'
            self._warn('camera_info', f'ignoring camera_info: {err}; {kept}')
            return
        if camera != self._camera and self._camera is not None:
            self.get_logger().info(f'camera model changed to {camera.width}x{camera.height}, '
                                   f'fx {camera.fx:.1f}')
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

    def _frame(self, msg: Image | CompressedImage, decode) -> None:
        """One image: decode, run the pipeline, publish odometry (or count why not), status."""
        start = time.perf_counter()
        stamp_ns = stamp_to_ns(msg.header.stamp)
        self._note_gap(stamp_ns)
        odom = None
        try:
            result = self._vo.process(decode(msg), stamp_ns / 1e9, self._camera)
            if result.ok:
                odom = self._odometry(msg.header, result)    # InputError if the pose is not finite
        except ImageError as err:
            result = self._dropped(stamp_ns, DropReason.BAD_IMAGE, str(err))
        except Exception as err:  # noqa: BLE001 - a bug in the pipeline must not stop the node
            result = self._dropped(stamp_ns, DropReason.PIPELINE_ERROR,
                                   f'{type(err).__name__}: {err}')
        self.outcomes['ok' if result.ok else result.reason.value] += 1
        if result.ok:
            self._publish(odom)
        else:
            self._report_drop(stamp_ns, result)
        node_time = time.perf_counter() - start
        self._node_time += node_time
        self._publish_status(msg.header, result, node_time)

    def _dropped(self, stamp_ns: int, reason: DropReason, message: str) -> FrameResult:
        """A frame the node drops before or after the pipeline (no pose to report)."""
        return FrameResult(stamp=stamp_ns / 1e9, ok=False, pose=self._vo.pose.copy(),
                           pose_covariance=np.full((6, 6), np.nan), reason=reason,
                           message=message)

    def _note_gap(self, stamp_ns: int) -> None:
        """Count frames lost before reaching the node (an interval far above the usual one)."""
        last = self._last_stamp_ns
        if last is not None and stamp_ns <= last:
            return                  # duplicated or out of order: the pipeline counts it
        self._last_stamp_ns = stamp_ns
        if last is None:
            return
        dt = stamp_ns - last
        if len(self._intervals) >= 3:
            period = float(np.median(self._intervals))
            if dt > _GAP_FACTOR * period:
                missing = max(1, round(dt / period) - 1)
                self._counters['gaps'] += 1
                self._counters['missing_frames'] += missing
                self._warn('gap', f'gap of {dt / 1e6:.0f} ms in the image stamps before '
                                  f'{_format_stamp(stamp_ns)} (about {missing} frame(s) missing at '
                                  f'{1e9 / period:.1f} Hz); odometry bridges it')
                return          # the gap does not update the nominal period
        self._intervals.append(dt)

    # -- outputs -------------------------------------------------------------------------------

    def _odometry(self, header, result: FrameResult) -> Odometry:
        """The odometry message of an updated frame, stamped with the image's stamp."""
        ros = self.config.ros
        return odometry_message(_MESSAGE_TYPES, stamp_to_ns(header.stamp), result.pose,
                                odom_frame=ros.odom_frame, base_frame=ros.base_frame,
                                pose_covariance=result.pose_covariance, twist=result.twist,
                                twist_covariance=result.twist_covariance)

    def _publish(self, odom: Odometry) -> None:
        """Odometry, the path (when someone listens) and the TF."""
        self._odom_pub.publish(odom)
        pose = PoseStamped()
        pose.header = odom.header
        pose.pose = odom.pose.pose
        self._path.append(pose)
        if self._path_pub.get_subscription_count() > 0:   # a long path is costly to build
            path = Path()
            path.header = odom.header
            path.poses = list(self._path)
            self._path_pub.publish(path)
        if self._tf is not None:
            tf = TransformStamped()
            tf.header = odom.header
            tf.child_frame_id = odom.child_frame_id
            t, p = tf.transform.translation, odom.pose.pose.position
            t.x, t.y, t.z = p.x, p.y, p.z
            tf.transform.rotation = odom.pose.pose.orientation
            self._tf.sendTransform(tf)

    def _report_drop(self, stamp_ns: int, result: FrameResult) -> None:
        if result.reason is DropReason.FIRST_FRAME:
            self.get_logger().info(f'{_format_stamp(stamp_ns)}: first frame of the keyframe '
                                   f'chain ({result.message})')
            return
        self._warn(result.reason.value, f'frame {_format_stamp(stamp_ns)} dropped, '
                                        f'{result.reason.value}: {result.message}')

    def _publish_status(self, header, result: FrameResult, node_time: float) -> None:
        """One `DiagnosticStatus` per image: this frame's outcome and the running counters."""
        status = DiagnosticStatus()
        status.name = f'{self.get_name()}: visual odometry'
        status.hardware_id = header.frame_id
        if result.ok or result.reason is DropReason.FIRST_FRAME:
            status.level = DiagnosticStatus.OK
        elif result.reason is DropReason.PIPELINE_ERROR:
            status.level = DiagnosticStatus.ERROR
        else:
            status.level = DiagnosticStatus.WARN
        key = 'ok' if result.ok else result.reason.value
        status.message = key if not result.message else f'{key}: {result.message}'
        values = {
            'stamp_ns': stamp_to_ns(header.stamp),
            'result': key,
            'keyframe': result.keyframe,
            'scale_source': result.scale_source if result.ok else '',
            'correspondences': result.num_correspondences,
            'inliers': result.num_inliers,
            'alpha_rad': result.alpha,
            'beta_rad': result.beta,
            'frames': sum(self.outcomes.values()),
            'odometry_out': self.outcomes['ok'],
            'dropped': sum(v for k, v in self.outcomes.items() if k != 'ok'),
        }
        for reason in DropReason:
            values[f'dropped.{reason.value}'] = self.outcomes[reason.value]
        for name in ('camera_info_errors', 'speed_messages', 'speed_errors', 'gaps',
                     'missing_frames'):
            values[name] = self._counters[name]
        for stage, seconds in result.timings.items():
            values[f'time_ms.{stage}'] = round(seconds * 1e3, 3)
        values['time_ms.node'] = round(node_time * 1e3, 3)
        status.values = [KeyValue(key=k, value=_format_value(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = header.stamp
        array.header.frame_id = header.frame_id
        array.status = [status]
        self._status_pub.publish(array)

    def _warn(self, key: str, message: str) -> None:
        held = self._throttle.admit(key)
        if held is None:
            return
        if held:
            message += f' ({held} more {key} warning(s) suppressed in the last ' \
                       f'{self._throttle.period:g} s)'
        self.get_logger().warning(message)

    def summary(self) -> str:
        """One line: frames in, odometry out, drops per reason, other counters, mean time."""
        frames = sum(self.outcomes.values())
        drops = {k: v for k, v in sorted(self.outcomes.items()) if k != 'ok' and v}
        dropped = ', '.join(f'{k} {v}' for k, v in drops.items()) or 'none'
        mean = f'{1e3 * self._node_time / frames:.1f} ms' if frames else 'n/a'
        return (f'summary: {frames} frames in, {self.outcomes["ok"]} odometry out, '
                f'{sum(drops.values())} dropped ({dropped}); '
                f'{self._counters["missing_frames"]} frames missing in '
                f'{self._counters["gaps"]} gaps; '
                f'{self._counters["camera_info_errors"]} camera_info errors; '
                f'{self._counters["speed_messages"]} speed messages; mean {mean} per frame')


def _format_stamp(stamp_ns: int) -> str:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return f'{sec}.{nsec:09d}'


def _format_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return 'nan' if math.isnan(value) else f'{value:.6g}'
    return str(value)


def main(args: list[str] | None = None) -> int:
    """Entry point (Jazzy idiom: init, spin in try, try_shutdown in finally).

    Returns 0 after SIGINT or SIGTERM (rclpy.init installs handlers for both), 1 when the
    parameters are invalid.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = PlanarVoNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # rclpy's signal handler shuts the context down from outside the executor. When that
        # lands while the executor builds its wait set, rclpy raises RCLError (a RuntimeError)
        # rather than ExternalShutdownException, a known race: after a shutdown it is the same
        # clean stop; with the context still valid it is a real error.
        if rclpy.ok():
            raise
    except ConfigError:
        return 1            # the fatal line naming the parameter is already logged
    finally:
        if node is not None:
            try:
                node.flush_pending()            # counted like any frame; publishing may fail
            except Exception:  # noqa: BLE001 - shutting down: the count matters, not the publish
                pass
            name, summary = node.get_name(), node.summary()
            node.destroy_node()
            # Logged after the node is gone: a signal has already shut the context down, and
            # the node's logger would then fail to forward the line to /rosout.
            rclpy.logging.get_logger(name).info(summary)
        rclpy.try_shutdown()
    return 0
