"""Shared fixtures: seeded randomness and an isolated ROS 2 environment for subprocesses."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from ros_tools import free_domain_id

# A Fast DDS profile that announces participants quickly and often: discovery on loopback then
# takes well under a second instead of up to three. UDP on the loopback interface only, no
# shared memory: reliable image topics stalled part-way (frames published, none received for a
# minute) in about 1 of 6 full runs over Fast DDS's shared-memory transport. (The rmw's
# LOCALHOST discovery range sets its own transports, shared memory among them, over the
# profile's: the range stays SUBNET and the profile keeps the traffic on 127.0.0.1.)
FASTDDS_PROFILE = """<?xml version="1.0" encoding="UTF-8"?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>planar_vo_test_udp</transport_id>
      <type>UDPv4</type>
      <interfaceWhiteList><address>127.0.0.1</address></interfaceWhiteList>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="planar_vo_test" is_default_profile="true">
    <rtps>
      <userTransports>
        <transport_id>planar_vo_test_udp</transport_id>
      </userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
      <builtin>
        <discovery_config>
          <initialAnnouncements>
            <count>30</count>
            <period><sec>0</sec><nanosec>100000000</nanosec></period>
          </initialAnnouncements>
        </discovery_config>
      </builtin>
    </rtps>
  </participant>
</profiles>
"""


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: every test is repeatable."""
    return np.random.default_rng(20240607)


@pytest.fixture(scope='session')
def ros_env(tmp_path_factory) -> dict[str, str]:
    """Environment for ROS subprocesses: a domain id unique to this run (and free of other
    runs' shared-memory leftovers: `free_domain_id`), fast discovery, UDP on loopback only
    (`FASTDDS_PROFILE`), and the venv's bin first on PATH (so ``#!/usr/bin/env python3`` finds
    it)."""
    profile = tmp_path_factory.mktemp('dds') / 'fastdds.xml'
    profile.write_text(FASTDDS_PROFILE)
    env = dict(os.environ)
    env.update({
        'ROS_DOMAIN_ID': str(free_domain_id(1, 100)),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
        'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile),
        'FASTDDS_DEFAULT_PROFILES_FILE': str(profile),
        'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp',
        'PYTHONUNBUFFERED': '1',
        'PATH': str(Path(sys.executable).parent) + os.pathsep + os.environ.get('PATH', ''),
    })
    return env


@pytest.fixture(scope='session')
def evo_env(tmp_path_factory) -> dict[str, str]:
    """Environment for running evo (a pinned test-only tool): a private HOME for its settings."""
    if not (Path(sys.executable).parent / 'evo_ape').exists():
        pytest.fail('evo is a pinned test dependency (Makefile PINS); run `make venv`')
    home = tmp_path_factory.mktemp('evo_home')           # evo writes ~/.evo/settings.json
    return {**os.environ, 'HOME': str(home), 'MPLBACKEND': 'Agg'}
