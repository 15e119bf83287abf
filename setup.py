"""Installs planar_vo for pip (wheel or editable) and for colcon (ament_python) alike.

`ros2 run planar_vo <exe>` looks for executables in `<prefix>/lib/planar_vo` and finds the package
through the ament index, so both are installed as `data_files`, which pip and colcon honour in the
same way (pip ignores setup.cfg `install_scripts` when it builds a wheel).
"""

from __future__ import annotations

import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'planar_vo'
HERE = Path(__file__).resolve().parent
VERSION = re.search(
    r"^__version__ = '([^']+)'", (HERE / PACKAGE / '__init__.py').read_text(), re.M
).group(1)

# Exact pins for reproducible environments live in the Makefile; these are the compatible ranges.
ROS = [
    'ros-jazzy-rclpy>=7.1,<8',
    'ros-jazzy-common-interfaces>=5.3,<6',
    'ros-jazzy-rmw-fastrtps-cpp>=8.4,<9',
]
TEST = ['pytest>=8,<10', 'evo>=1.38,<2']
# Optional benchmark peer, pinned exactly: the numbers in planar_vo/bench/results were measured
# with this version.
BENCH = ['poselib==2.0.5']
# Fleet runs (`planar_vo fleet`) on Ray; the client part for ray://host:port addresses.
FLEET = ['ray[client]>=2.60,<3']

setup(
    name=PACKAGE,
    version=VERSION,
    description='Planar visual odometry from single affine correspondences (ROS 2 Jazzy)',
    long_description=(HERE / 'README.md').read_text(encoding='utf-8'),
    long_description_content_type='text/markdown',
    license='Apache-2.0',
    python_requires='>=3.11',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', sorted(glob('config/*.yaml'))),
        (f'share/{PACKAGE}/launch', sorted(glob('resource/launch/*.launch.py'))),
        (f'lib/{PACKAGE}', sorted(glob('resource/bin/*'))),
    ],
    install_requires=[
        'setuptools',
        'numpy>=1.26,<3',
        'opencv-python-headless>=4.6,<6',
        'rosbags>=0.11,<0.12',
        'PyYAML>=6,<7',
        'tqdm>=4.66,<5',
        'threadpoolctl>=3.1,<4',
        'matplotlib>=3.8,<4',
    ],
    extras_require={'ros': ROS, 'test': TEST, 'bench': BENCH, 'fleet': FLEET},
    zip_safe=True,
    entry_points={
        'console_scripts': [
            f'{PACKAGE} = {PACKAGE}.cli:main',
            f'{PACKAGE}_node = {PACKAGE}.ros.startup:main',
        ],
    },
    classifiers=[
        'Programming Language :: Python :: 3',
        'Topic :: Scientific/Engineering :: Image Recognition',
    ],
)
