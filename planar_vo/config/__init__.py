"""One configuration for every stage (`PlanarVoConfig`), mirroring ``config/planar_vo.yaml``.

- `planar_vo.config.sections`: the sections (camera, mount, frontend, voting, keyframe, scale,
  odometry, ros), frozen dataclasses validated once (`planar_vo.core.options.Options`);
- `planar_vo.config.keys`: the dotted-key view (ROS parameter names) and descriptions;
- `planar_vo.config.files`: YAML files, plain or in ROS parameter-file form.

The node maps ROS parameters onto it, the CLI maps flags and ``--config FILE`` onto it, and the
library takes the section it needs.
"""

from __future__ import annotations

from planar_vo.config import files, keys, sections
from planar_vo.config.files import (  # noqa: F401
    build_config,
    load_config,
    parse_set,
    read_config,
    to_ros_yaml,
)
from planar_vo.config.keys import describe, flatten, ranges  # noqa: F401
from planar_vo.config.sections import *  # noqa: F401,F403 - the sections in their __all__

__all__ = [*sections.__all__, *keys.__all__, *files.__all__]
