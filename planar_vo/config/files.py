"""Configuration files: the plain nested YAML form and the ROS 2 parameter-file form."""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

from planar_vo.config.keys import describe
from planar_vo.config.sections import PlanarVoConfig
from planar_vo.core.options import nest_dotted
from planar_vo.errors import ConfigError, one_line

__all__ = ['build_config', 'load_config', 'parse_set', 'read_config', 'to_ros_yaml']


def load_config(path: str | Path | None = None, *, node_name: str = 'planar_vo'
                ) -> PlanarVoConfig:
    """Load a configuration file (None: the defaults).

    Accepts the plain nested form and the ROS parameter-file form
    (``<node_name>: {ros__parameters: {...}}``, the node name with or without a namespace, or
    ``/**``) that ``config/planar_vo.yaml`` uses, so one file serves the node and the CLI; in
    either, dotted keys (``voting.bins: 360``) as ROS parameter files may write them.
    """
    if path is None:
        return PlanarVoConfig()
    data = _read_data(path, node_name)
    if data is None:
        return PlanarVoConfig()
    try:
        return PlanarVoConfig.from_dict(nest_dotted(data) if isinstance(data, dict) else data)
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from None


def read_config(path: str | Path | None, *, node_name: str = 'planar_vo') -> dict[str, Any]:
    """A configuration file's settings (either form of `load_config`) as dotted keys, read but
    not yet validated as a whole: a command that applies ``--set`` items over the file
    validates the result, so a file may lean on them (``camera.nominal_fov`` in the file,
    ``--set camera.estimate_focal=true`` on the command line). ``{}`` for None or an empty
    file.

    Raises:
        ConfigError: the file cannot be read, is not YAML, is a ROS parameter file for another
            node, or is not a mapping of sections (as `load_config` says it).
    """
    if path is None:
        return {}
    data = _read_data(path, node_name)
    if data is None:
        return {}
    nested = nest_dotted(data) if isinstance(data, dict) else data
    if isinstance(nested, dict):
        # A section whose settings are all commented out is empty (as `load_config` reads it).
        nested = {k: {} if v is None else v for k, v in nested.items()}
    if not (isinstance(nested, dict) and all(isinstance(v, dict) for v in nested.values())):
        load_config(path, node_name=node_name)          # raises the specific error
        raise ConfigError(f'{path}: expected sections of settings')
    return {f'{section}.{key}': value for section, values in nested.items()
            for key, value in values.items()}


def build_config(values: dict[str, Any], changes: dict[str, Any], source: str | Path | None = None,
                 label: str = '') -> PlanarVoConfig:
    """The configuration of a file's settings ``values`` (`read_config`) with ``changes``
    (``--set`` items, dotted keys) over them, validated as a whole. A refusal names its cause:
    the file ``source`` when the file alone is refused for the same reason, ``set:`` (with
    ``label``, the combination's name) when the file alone is valid or the sets alone are
    refused for the same reason, both otherwise.

    Raises:
        ConfigError: the combination is refused.
    """
    try:
        return PlanarVoConfig.from_flat({**values, **changes})
    except ConfigError as err:
        combined = str(err)
    setting = f'set: {label}: ' if label else 'set: '
    if source is None:
        raise ConfigError(setting + combined if changes else combined)
    if not changes:
        raise ConfigError(f'{source}: {combined}')

    def refusal(flat: dict[str, Any]) -> str | None:
        try:
            PlanarVoConfig.from_flat(flat)
        except ConfigError as err:
            return str(err)
        return None

    alone = refusal(values)
    if alone == combined:
        raise ConfigError(f'{source}: {combined}')
    if alone is None or refusal(changes) == combined:
        raise ConfigError(setting + combined)
    raise ConfigError(f'{source} with --{setting}{combined}')


def _read_data(path: str | Path, node_name: str) -> Any:
    """The YAML data of a configuration file: the node's ``ros__parameters`` of a ROS parameter
    file, else the whole document (None when empty). Errors name the file as given."""
    import yaml

    class UniqueKeyLoader(yaml.SafeLoader):
        """YAML's safe loader, refusing a key given twice in one mapping (PyYAML keeps the
        last without a word; a user test)."""

    def mapping(loader, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = loader.construct_object(key_node, deep=deep)
            if key in seen:
                raise ConfigError(f'{path} line {key_node.start_mark.line + 1}: {key!r} given '
                                  f'twice in one section (the later would win without a word)')
            seen.add(key)
        return yaml.SafeLoader.construct_mapping(loader, node, deep)

    UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    try:
        data = yaml.load(Path(path).read_text(encoding='utf-8'), Loader=UniqueKeyLoader)
    except OSError as err:
        raise ConfigError(f'{path}: cannot read configuration ({err.strerror})') from err
    except UnicodeDecodeError as err:
        raise ConfigError(f'{path}: not a YAML text file (byte {err.start} is not UTF-8: '
                          f'{err.object[err.start:err.start + 1]!r})') from err
    except yaml.YAMLError as err:
        raise ConfigError(f'{path}: not valid YAML ({err})') from err
    if isinstance(data, dict):
        keyed = {str(k): v for k, v in data.items()
                 if isinstance(v, dict) and 'ros__parameters' in v}
        # The node's own key, with or without a namespace ('/car/planar_vo', '/**/planar_vo'),
        # else the wildcard '/**'.
        ours = [k for k in keyed if k.rsplit('/', 1)[-1] == node_name] or \
            [k for k in keyed if k == '/**']
        if ours:
            data = keyed[ours[0]]['ros__parameters']
        elif keyed:
            raise ConfigError(f"{path}: a ROS parameter file for {', '.join(keyed)}, not for "
                              f"this node; key its parameters on '{node_name}' (with or "
                              f"without a namespace) or '/**'")
    return data


def to_ros_yaml(config: PlanarVoConfig | None = None, *, node_name: str = '/**') -> str:
    """The configuration as a commented ROS 2 parameter file (the form of
    ``config/planar_vo.yaml``, which is this function's output for the defaults).

    Keyed on ``/**`` by default, so that the file applies to the node under any name or
    namespace (``-r __node:=front_vo``, ``-r __ns:=/car``); ``node_name`` keys it on one node.
    """
    import textwrap

    import yaml

    config = PlanarVoConfig() if config is None else config
    docs = describe()
    out = ['# planar_vo parameters, in ROS 2 parameter-file form (ros2 run planar_vo',
           '#   planar_vo_node --ros-args --params-file FILE). The planar_vo command reads the',
           '# same file with --config. Mirrors planar_vo.config.PlanarVoConfig (SI units, rad).',
           '# Keyed on /** so that it applies whatever the node is named or namespaced as.',
           f'{node_name}:', '  ros__parameters:']
    for section, values in config.to_dict().items():
        out.append(f'    {section}:')
        keys = list(values)
        for i, key in enumerate(keys):
            doc = docs[f'{section}.{key}']
            if i == 0 or doc != docs[f'{section}.{keys[i - 1]}']:
                # Fields documented together (fx, fy, cx, cy) share one comment.
                group = [k for k in keys[i:] if docs[f'{section}.{k}'] == doc]
                names = ', '.join(group)
                head = f'{names}: ' if len(group) > 1 else ''
                for line in textwrap.wrap(head + doc, 86):
                    out.append(f'      # {line}')
            text = yaml.safe_dump(values[key], default_flow_style=True).strip()
            out.append(f'      {key}: {text.removesuffix("...").strip()}')
    return '\n'.join(out) + '\n'


def parse_set(item: str, keys, *, several: bool = True) -> tuple[str, list[Any]]:
    """One ``--set KEY=V1[,V2...]`` item: its dotted key (one of ``keys``) and its distinct
    values, read as YAML flow items (``360``, ``true``, ``flow``, ``[0.1, 0.2]``).
    ``several``: whether the caller takes several values (only the error text differs: a
    command that takes one value does not offer the comma form).

    Raises:
        ConfigError: malformed item, unknown key (with the closest known ones), or values that
            are not YAML.
    """
    import yaml

    key, sep, text = (part.strip() for part in item.partition('='))
    if not sep or not key or not text:
        form = 'KEY=VALUE[,VALUE...]' if several else 'KEY=VALUE'
        raise ConfigError(f"set: expected {form}, got '{item}'")
    if key not in keys:
        near = difflib.get_close_matches(key, list(keys), n=3)
        hint = f'; did you mean {", ".join(near)}?' if near else ''
        raise ConfigError(f"set: unknown configuration key '{key}'{hint}")
    try:
        values = yaml.safe_load(f'[{text}]')
    except yaml.YAMLError as err:
        raise ConfigError(f"set: cannot read the values of '{item}' ({one_line(err)})") from None
    return key, [v for i, v in enumerate(values) if v not in values[:i]]
