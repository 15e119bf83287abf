"""What produced an output: planar_vo's version, a digest of its source files and the settings
that differ from the defaults, recorded in the odometry bags `planar_vo replay` writes
(``metadata.yaml``'s ``custom_data``) and in the ``metrics.json`` of `planar_vo eval` (a user
test: an odometry bag evaluated later could not be traced to the camera height it ran with)."""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

__all__ = ['bag_custom_data', 'bag_information', 'code_digest', 'evaluation_provenance',
           'provenance']


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """Digest of planar_vo's own source files (as installed): results computed by other code
    are stale (a user test: a fleet rerun after an upgrade reported the old numbers)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha1()
    for path in sorted(root.rglob('*.py')):
        h.update(str(path.relative_to(root)).encode() + b'\0' + path.read_bytes() + b'\0')
    return h.hexdigest()


def provenance(config=None, **extra: str) -> dict[str, str]:
    """``planar_vo.*`` keys: the version, the source digest, the settings of ``config`` (a
    `PlanarVoConfig`) that differ from the defaults as JSON, and ``extra`` values."""
    from planar_vo import __version__

    data = {'planar_vo.version': __version__, 'planar_vo.source_digest': code_digest()}
    if config is not None:
        from planar_vo.config import PlanarVoConfig, flatten

        defaults = flatten(PlanarVoConfig())
        changed = {k: v for k, v in flatten(config).items() if defaults.get(k) != v}
        data['planar_vo.settings'] = json.dumps(changed, sort_keys=True, default=str)
    data.update({f'planar_vo.{k}': str(v) for k, v in extra.items()})
    return data


def bag_information(path: str | Path) -> dict:
    """The ``rosbag2_bagfile_information`` of a bag folder's ``metadata.yaml`` (empty for a
    single storage file or an unreadable one)."""
    import yaml

    try:
        info = yaml.safe_load((Path(path) / 'metadata.yaml').read_text(encoding='utf-8'))
        data = info['rosbag2_bagfile_information']
    except (OSError, yaml.YAMLError, TypeError, KeyError):
        return {}
    return data if isinstance(data, dict) else {}


def bag_custom_data(path: str | Path) -> dict[str, str]:
    """The ``custom_data`` of a bag folder's ``metadata.yaml`` (empty for none, a single
    storage file or an unreadable one)."""
    data = bag_information(path).get('custom_data') or {}
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def evaluation_provenance(estimate: str | Path) -> dict[str, dict[str, str]]:
    """``metrics.json``'s record of what evaluated (``evaluated_by``) and, when the estimate is
    a bag that says (`planar_vo replay` writes it), what produced the estimate
    (``estimate_made_by``)."""
    made = {k: v for k, v in bag_custom_data(estimate).items() if k.startswith('planar_vo.')}
    return {'evaluated_by': provenance(), **({'estimate_made_by': made} if made else {})}
