"""Configuration: defaults mirror config/planar_vo.yaml, validation names the bad key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from planar_vo.config import (
    PlanarVoConfig,
    VotingConfig,
    build_config,
    describe,
    flatten,
    load_config,
    read_config,
    to_ros_yaml,
)
from planar_vo.core.options import Options
from planar_vo.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def test_yaml_file_mirrors_dataclass_defaults():
    assert load_config(ROOT / 'config' / 'planar_vo.yaml') == PlanarVoConfig()
    # The shipped file is exactly the generated one (regenerate with to_ros_yaml()).
    assert (ROOT / 'config' / 'planar_vo.yaml').read_text() == to_ros_yaml()


def test_the_robot_localization_recipe_fuses_the_twist_of_the_remapped_odometry():
    """Not the pose in differential mode (a user test): robot_localization derives that
    velocity's covariance from the poses', which grow with the distance driven."""
    import yaml

    params = yaml.safe_load((ROOT / 'config' / 'robot_localization_ekf.yaml').read_text())
    params = params['ekf_filter_node']['ros__parameters']
    fused = [i for i, on in enumerate(params['odom1_config']) if on]
    assert fused == [6, 7, 11]                       # vx, vy, vyaw
    assert params['odom1_differential'] is False and params['odom1'] == '/vo/odom'
    assert '-r odom:=/vo/odom' in (ROOT / 'README.md').read_text()


def test_generated_yaml_round_trips(tmp_path):
    config = PlanarVoConfig.from_dict({'voting': {'bins': 360}, 'camera': {
        'distortion_model': 'plumb_bob', 'distortion': [0.1, -0.05, 0.0, 0.0, 0.01]}})
    path = tmp_path / 'p.yaml'
    path.write_text(to_ros_yaml(config))
    assert load_config(path) == config


def test_every_parameter_has_a_description():
    docs = describe()
    assert set(docs) == set(flatten(PlanarVoConfig()))
    assert all(docs.values())
    # Whole sentences: a continuation line reading 'word: ...' is not a new entry (a review:
    # two descriptions ended at 'standing' and at 'one standard deviation of the').
    assert all(v.endswith(('.', ')')) for v in docs.values()), \
        [k for k, v in docs.items() if not v.endswith(('.', ')'))]
    assert docs['keyframe.stationary_parallax'].endswith('standing still: zero motion is output '
                                                         'and no keyframe is made.')


def test_a_continuation_line_naming_a_field_is_text():
    @dataclasses.dataclass(frozen=True)
    class Section(Options):
        """A section.

        Attributes:
            height: the camera's height above the road; with
                depth: set, the depth below it counts too.
            depth: how deep.
        """

        height: float = 1.0
        depth: float = 0.0

    docs = describe(Section)
    assert docs == {'height': "the camera's height above the road; with depth: set, the "
                              'depth below it counts too.',
                    'depth': 'how deep.'}


def test_flat_round_trip():
    config = PlanarVoConfig().replace(voting=VotingConfig(bins=360))
    flat = flatten(config)
    assert flat['voting.bins'] == 360
    assert PlanarVoConfig.from_flat(flat) == config


def test_plain_nested_yaml(tmp_path):
    path = tmp_path / 'c.yaml'
    path.write_text('voting:\n  bins: 180\nmount:\n  height: 1.65\n')
    config = load_config(path)
    assert config.voting.bins == 180 and config.mount.height == 1.65


def test_dotted_keys_as_ros_parameter_files_may_write_them(tmp_path):
    """ROS 2 accepts ``voting.bins: 360`` under ros__parameters as well as nested sections;
    so does `load_config`, mixed with nested ones; a parameter given twice is refused."""
    path = tmp_path / 'c.yaml'
    path.write_text('/**:\n  ros__parameters:\n    voting.bins: 360\n    mount:\n'
                    '      height: 1.65\n    mount.estimate_tilt: false\n')
    config = load_config(path)
    assert (config.voting.bins, config.mount.height, config.mount.estimate_tilt) == \
        (360, 1.65, False)
    path.write_text('voting.bins: 360\nvoting:\n  bins: 180\n')
    with pytest.raises(ConfigError, match=r'voting.bins: given twice'):
        load_config(path)
    path.write_text('voting.bins.x: 1\nvoting:\n  bins: 180\n')
    with pytest.raises(ConfigError, match=r'voting.bins'):
        load_config(path)


def test_exponents_without_a_dot_are_numbers_as_in_ros_parameter_files(tmp_path):
    """PyYAML (YAML 1.1) reads 2e-2 as text; ROS 2 reads it as a double."""
    path = tmp_path / 'c.yaml'
    path.write_text('camera:\n  focal_tolerance: 2e-2\nvoting:\n  point_noise: 1.5e-3\n')
    config = load_config(path)
    assert (config.camera.focal_tolerance, config.voting.point_noise) == (0.02, 0.0015)
    with pytest.raises(ConfigError, match=r"mount.height: expected float, got str '1.6 m'"):
        PlanarVoConfig.from_dict({'mount': {'height': '1.6 m'}})


def test_int_is_accepted_for_float_but_not_bool_for_int():
    assert PlanarVoConfig.from_dict({'mount': {'height': 2}}).mount.height == 2.0
    with pytest.raises(ConfigError, match=r'voting.bins: expected int, got bool True'):
        PlanarVoConfig.from_dict({'voting': {'bins': True}})


@pytest.mark.parametrize(('data', 'match'), [
    ({'voting': {'binz': 3}}, r'unknown configuration key\(s\) voting.binz; known keys: '
                              r'affine_noise, '
     r'ambiguity_ratio, bins'),
    ({'votes': {}}, r'unknown configuration key\(s\) votes'),
    ({'voting': {'bins': 'x'}}, r"voting.bins: expected int, got str 'x'"),
    ({'voting': {'bins': 10}}, r'voting.bins: expected in \[36, 100000\], got 10'),
    ({'mount': {'height': -1.0}}, r'mount.height: expected a height above the ground of '
                                  r'0.01-100 m, got -1.0'),
    # (a user test: 1e-300 m ran into positions of 1e-299 m with a numpy warning)
    ({'mount': {'height': 1e-300}}, r'mount.height: expected a height above the ground of '),
    ({'frontend': {'method': 'sift'}}, r"frontend.method: expected one of \['flow', 'klt', "
                                       r"'asift'\], got 'sift'"),
    ({'camera': {'distortion': [0.1, 'a']}}, r"camera.distortion\[1\]: expected float"),
    ({'ros': {'odom_frame': 'x', 'base_frame': 'x'}}, r'ros.base_frame: expected a frame id '
     r'other than odom_frame'),
    # tf2 refuses a leading slash; whitespace makes ids that look alike differ
    ({'ros': {'odom_frame': '/odom'}}, r"ros.odom_frame: expected a frame id without a leading "
                                       r"slash or whitespace, e.g. odom, got '/odom'"),
    ({'ros': {'base_frame': 'base link'}}, r"ros.base_frame: expected a frame id without"),
    ({'ros': {'odom_frame': ' odom'}}, r"ros.odom_frame: expected a frame id without"),
    ({'ros': {'odom_frame': ''}}, r"ros.odom_frame: expected a frame id without"),
    ({'camera': {'mono16_bits': 17}}, r'camera.mono16_bits: expected an integer number of bits '
                                      r'in 8..16, got 17'),
    # checked with the configuration, not frame by frame in the pipeline
    ({'camera': {'distortion_model': 'plumb_bob', 'distortion': [0.1]}},
     r"camera.distortion: expected 5 coefficients for distortion_model 'plumb_bob' \(or 4: "
     r"k3 = 0\) \(more only if the extra ones are 0\), or none for no distortion, got "
     r"\(0.1,\)"),
    ({'camera': {'distortion_model': 'rational_polynomial', 'distortion': [0.1] * 8 + [0.2]}},
     r"camera.distortion: expected 8 coefficients for distortion_model 'rational_polynomial' "
     r"\(more only if the extra ones are 0\), or none for no distortion, got"),
    ({'camera': {'distortion': [0.1, 0.0]}},
     r"camera.distortion: expected 0 coefficients for distortion_model 'none'"),
    ({'voting': 3}, r'voting: expected a mapping, got int'),
    # a YAML integer of 400 digits is a Python int: a ConfigError, not OverflowError
    ({'mount': {'height': 10**400}}, r'mount.height: expected float, got an int of 1329 bits '
                                     r'\(beyond float64\)'),
    ({'voting': {'bins': 2**64}}, r'voting.bins: expected int, got one of 65 bits \(at most 64\)'),
    ({'camera': {'distortion': [0.1, -10**400]}},
     r'camera.distortion\[1\]: expected float, got an int of 1329 bits'),
    ({'scale': {'speed_max_gap': 0.0}}, r'scale.speed_max_gap: expected a positive duration'),
    ({'scale': {'ground_point_std': -1.0}}, r'scale.ground_point_std: expected a positive'),
    ({'mount': {'tilt_wobble_std': 0.5}}, r'mount.tilt_wobble_std: expected an angle in'),
    ({'camera': {'focal_min_blocks': 8, 'focal_max_blocks': 4}},
     r'camera.focal_max_blocks: expected at least focal_min_blocks'),
    ({'camera': {'focal_steps': 0.0}},
     r'camera.focal_steps: expected work steps per frame in \(0, 100\]'),
    # contradictions a user test found silently resolved
    ({'camera': {'estimate_focal': True, 'rectified': True}},
     r'camera.rectified: expected false when the camera model does not come from CameraInfo '
     r'\(estimate_focal or fx configured\): it says how a CameraInfo is read, got True'),
    ({'camera': {'fx': 700.0, 'rectified': True}}, r'camera.rectified: expected false when'),
    ({'camera': {'focal_tolerance': 0.05}},
     r'camera.focal_tolerance: expected its default without estimate_focal \(a setting of the '
     r'focal self-calibration\), got 0.05'),
    ({'camera': {'estimate_focal': True, 'fx': 707.1}},
     r'camera.estimate_focal: expected false with fx configured \(707.1 px: the focal length '
     r'is known; fx = 0 self-calibrates it\), got True'),
    ({'camera': {'nominal_fov': 1.5708}},
     r'camera.nominal_fov: expected 0 without estimate_focal \(it is where the focal '
     r'self-calibration starts\), got 1.5708'),
    ({'camera': {'estimate_focal': True, 'nominal_fov': 0.3}},
     r'camera.nominal_fov: expected 0 \(unknown\) or a horizontal field of view of 0.4-2.2 rad '
     r'\(23-126 deg, the range the focal calibration searches\), got 0.3'),
    # (a user test: degrees, and a 143-degree dashcam, got only 'a horizontal field of view')
    ({'camera': {'estimate_focal': True, 'nominal_fov': 90.0}},
     # (and a rectilinear lens's range first: a user test got the fisheye's alone)
     r'camera.nominal_fov: expected 0 \(unknown\) or a horizontal field of view in radians '
     r'\(90 deg is 1.5708\): 0.4-2.2 rad, through a fisheye lens \(distortion_model '
     r'equidistant\) up to 4 rad, 229 deg, got 90.0'),
    ({'camera': {'estimate_focal': True, 'nominal_fov': 2.5}},
     r'camera.nominal_fov: .*wider: a fisheye lens, distortion_model equidistant\), got 2.5'),
    ({'camera': {'estimate_focal': True, 'nominal_fov': 0.3, 'distortion_model': 'equidistant',
                 'distortion': [0.0] * 4}},
     r'camera.nominal_fov: expected 0 \(unknown\) or a horizontal field of view of 0.4-4 rad '
     r'\(23-229 deg, the range the focal calibration searches through a fisheye lens\), '
     r'got 0.3'),
    ({'camera': {'fy': 700.0}}, r'camera.fy: expected 0 while fx is 0 \(fy is used with fx '
                                r'only'),
    ({'camera': {'cx': -10.0}}, r'camera.cx: expected cx, cy >= 0 \(0 = the image centre\), '
                                r'got -10.0'),
])
def test_invalid_values_are_reported_with_their_key(data, match):
    with pytest.raises(ConfigError, match=match):
        PlanarVoConfig.from_dict(data)


def test_from_flat_needs_a_mapping():
    # (a user test: None gave a TypeError from dict())
    with pytest.raises(ConfigError, match=r'^config: expected a mapping of dotted keys, got '
                                          r'NoneType$'):
        PlanarVoConfig.from_flat(None)


def test_config_is_frozen():
    config = PlanarVoConfig()
    with pytest.raises(AttributeError):
        config.voting = VotingConfig()  # type: ignore[misc]


def test_load_config_errors(tmp_path):
    with pytest.raises(ConfigError, match=r'cannot read configuration'):
        load_config(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('voting: [1, 2\n')
    with pytest.raises(ConfigError, match=r'not valid YAML'):
        load_config(bad)
    wrong = tmp_path / 'wrong.yaml'
    wrong.write_text('planar_vo:\n  ros__parameters:\n    voting:\n      bins: 1\n')
    with pytest.raises(ConfigError, match=r'wrong.yaml: voting.bins: expected in \[36, 100000\]'):
        load_config(wrong)
    other = tmp_path / 'other.yaml'
    other.write_text('/other_node:\n  ros__parameters:\n    mount:\n      height: 1.2\n')
    with pytest.raises(ConfigError, match=r"other.yaml: a ROS parameter file for /other_node, "
                                          r"not for this node; key its parameters on 'planar_vo' "
                                          r"\(with or without a namespace\) or '/\*\*'"):
        load_config(other)
    for key in ('/car/planar_vo', '/**/planar_vo', 'planar_vo', '/**'):
        other.write_text(f'/other_node:\n  ros__parameters:\n    mount:\n      height: 3.0\n'
                         f'{key}:\n  ros__parameters:\n    mount:\n      height: 1.2\n')
        assert load_config(other).mount.height == 1.2, key


def test_ranges_are_declared_once_and_checked_by_the_config():
    from planar_vo.config import ranges
    from planar_vo.core.options import Range

    declared = ranges()
    assert declared['mount.height'] == Range(0.01, 100.0,
                                             expected='a height above the ground of 0.01-100 m')
    assert str(declared['camera.focal_tolerance']) == 'in (0, 1)'
    assert str(declared['frontend.max_correspondences']) == 'in [1, 30000]'
    assert str(declared['ros.path_max_length']) == 'in [1, 1000000]'
    fov = declared['camera.nominal_fov']                    # up to a fisheye's widest
    assert (fov.low, fov.high, fov.low_open, fov.high_open) == (0.0, 4.0, False, False)
    assert 'ros.odom_frame' not in declared and 'scale.source' not in declared
    defaults = flatten(PlanarVoConfig())
    # Every declared range holds its default, and a value just outside it is refused with the
    # range's own words.
    for key, allowed in declared.items():
        assert defaults[key] in allowed, key
        if allowed.low is not None:
            below = allowed.low if allowed.low_open else allowed.low - 1
            with pytest.raises(ConfigError, match=rf'^{key}: expected '):
                PlanarVoConfig.from_flat({key: below})
    with pytest.raises(ConfigError, match=r'ros.path_spacing: expected a non-negative distance'):
        PlanarVoConfig.from_flat({'ros.path_spacing': -0.5})
    with pytest.raises(ConfigError, match=r'mount.x: expected a finite offset \(m\), got inf'):
        PlanarVoConfig.from_flat({'mount.x': float('inf')})
    # Relations between fields stay in validate().
    with pytest.raises(ConfigError, match=r'frontend.patch_stride: expected between 1 and '
                                          r'patch_radius pixels, got 12'):
        PlanarVoConfig.from_flat({'frontend.patch_stride': 12})


def test_descriptions_are_plain_text():
    assert not [k for k, v in describe().items() if '`' in v]
    assert describe()['ros.image_transport'] == "'raw' (image) or 'compressed' (image/compressed)."


def test_parameter_file_keyed_on_any_node_and_old_files_still_load(tmp_path):
    text = to_ros_yaml()
    assert '\n/**:\n  ros__parameters:\n' in text
    old = tmp_path / 'old.yaml'
    old.write_text(to_ros_yaml(PlanarVoConfig.from_flat({'voting.bins': 360}),
                               node_name='planar_vo'))
    assert '\nplanar_vo:\n  ros__parameters:\n' in old.read_text()
    assert load_config(old).voting.bins == 360


@pytest.mark.parametrize(('changes', 'match'), [
    ({'bins': '720'}, r"bins: expected int, got str '720'"),
    ({'bins': 720.5}, r'bins: expected int, got float 720.5'),
    ({'bins': True}, r'bins: expected int, got bool True'),
    ({'inlier_chi2': 'x'}, r"inlier_chi2: expected float, got str 'x'"),
    ({'method': 'foo'}, r"method: expected one of \['histogram', 'ransac'\], got 'foo'"),
])
def test_options_built_directly_check_their_types(changes, match):
    """Not only `from_dict`: an options object built in code refuses a wrong type or choice
    at once (before, the estimator failed later with a plain TypeError, or ran the default
    method for an unknown one); numpy numbers count as numbers."""
    import numpy as np

    from planar_vo.core.robust import VotingConfig

    with pytest.raises(ConfigError, match=match):
        VotingConfig(**changes)
    typed = VotingConfig(bins=np.int64(360), inlier_chi2=np.float32(12.5), kernel_bins=2)
    assert type(typed.bins) is int and typed.bins == 360
    assert type(typed.inlier_chi2) is float and typed.inlier_chi2 == 12.5
    assert type(typed.kernel_bins) is float
    with pytest.raises(ConfigError, match='voting: expected VotingConfig, got dict'):
        PlanarVoConfig(voting={'bins': 360})


def test_a_file_and_its_sets_are_validated_together_and_a_refusal_names_its_cause():
    """`build_config`: the file's settings with the sets over them (a user test: a file that
    needed a --set was refused on its own); a refusal names the file, the set, or both (a
    review: every refusal named both)."""
    fov = {'camera.nominal_fov': 1.5708}                      # needs estimate_focal
    config = build_config(fov, {'camera.estimate_focal': True}, 'f.yaml')
    assert config.camera.nominal_fov == 1.5708 and config.camera.estimate_focal
    with pytest.raises(ConfigError, match=r'^f.yaml: camera.nominal_fov: expected 0 without'):
        build_config(fov, {'voting.bins': 720}, 'f.yaml')    # the file's own fault
    with pytest.raises(ConfigError, match=r'^set: voting.bins: expected in \[36'):
        build_config({'mount.height': 1.6}, {'voting.bins': 1}, 'f.yaml')
    with pytest.raises(ConfigError, match=r'^set: bins 1: voting.bins: expected in \[36'):
        build_config(fov, {'camera.estimate_focal': True, 'voting.bins': 1}, 'f.yaml',
                     label='bins 1')                         # the sets' fault, whatever the file
    # The file alone fails on its blocks, the set fixes them and uncovers the field of view.
    both = {'camera.nominal_fov': 1.5708, 'camera.focal_min_blocks': 40}
    with pytest.raises(ConfigError, match=r'^f.yaml with --set: camera.nominal_fov: expected 0 '
                                          r'without estimate_focal'):
        build_config(both, {'camera.focal_max_blocks': 50}, 'f.yaml')


def test_a_key_given_twice_in_a_file_is_refused(tmp_path):
    """PyYAML keeps the later of two equal keys without a word (a user test: a file with two
    `height:` lines ran on the second); the file is refused instead, naming the line."""
    path = tmp_path / 'dup.yaml'
    path.write_text('mount:\n  height: 1.65\n  pitch: 0.01\n  height: 1.7\n')
    for read in (load_config, read_config):
        with pytest.raises(ConfigError, match=rf"^{path} line 4: 'height' given twice in one "
                                              r'section \(the later would win without a word\)$'):
            read(path)
    path.write_text('mount: {height: 1.65}\ncamera: {fx: 500}\n')   # the same key, two sections
    assert load_config(path).mount.height == 1.65


def test_an_empty_distortion_means_all_zero_coefficients_for_any_model():
    """A user test: a fisheye's field of view needs distortion_model equidistant, which then
    refused the empty coefficient list; empty now means all-zero coefficients: no distortion
    for the pinhole models, the ideal fisheye (theta_d = theta) for equidistant
    (`test_camera_frames.py`)."""
    from planar_vo.config import CameraConfig

    camera = PlanarVoConfig.from_dict({'camera': {
        'distortion_model': 'equidistant', 'estimate_focal': True, 'nominal_fov': 3.0}}).camera
    assert camera.distortion == () and camera.coefficients == (0.0,) * 4
    assert CameraConfig(distortion_model='plumb_bob').coefficients == (0.0,) * 5
    with pytest.raises(ConfigError, match=r'camera.distortion: expected 4 coefficients'):
        PlanarVoConfig.from_dict({'camera': {'distortion_model': 'equidistant',
                                             'distortion': [0.1]}})


def test_nominal_fov_std_says_how_well_a_stated_field_of_view_is_known():
    camera = PlanarVoConfig.from_dict({'camera': {'estimate_focal': True, 'nominal_fov': 1.43,
                                                  'nominal_fov_std': 0.0175}}).camera
    assert camera.nominal_fov_std == 0.0175
    with pytest.raises(ConfigError, match=r'camera.nominal_fov_std: expected 0 without '
                                          r'nominal_fov \(it says how well that is known\)'):
        PlanarVoConfig.from_dict({'camera': {'estimate_focal': True, 'nominal_fov_std': 0.02}})
    with pytest.raises(ConfigError, match=r'camera.nominal_fov_std: expected 0 \(not said\) or '
                                          r'a standard deviation of the field of view of at '
                                          r'most 1 rad'):
        PlanarVoConfig.from_dict({'camera': {'estimate_focal': True, 'nominal_fov': 1.43,
                                             'nominal_fov_std': 2.0}})
