"""A small arm with primitive collision elements and a scene around it, for the collision tests."""

from __future__ import annotations

from pathlib import Path

ARM_URDF = """<?xml version="1.0"?>
<robot name="three_link">
  <link name="world"/>
  <joint name="base_weld" type="fixed"><parent link="world"/><child link="base"/></joint>
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
  </inertial><collision><origin xyz="0 0 0.02"/><geometry><cylinder radius="0.08" length="0.04"/></geometry>
  </collision></link>
  <joint name="yaw" type="revolute"><parent link="base"/><child link="post"/><axis xyz="0 0 1"/>
    <origin xyz="0 0 0.05"/><limit lower="-3" upper="3" effort="50" velocity="5"/></joint>
  <link name="post"><inertial><origin xyz="0 0 0.15"/><mass value="1"/>
    <inertia ixx="0.008" iyy="0.008" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.15"/><geometry><capsule radius="0.04" length="0.2"/></geometry></collision></link>
  <joint name="shoulder" type="revolute"><parent link="post"/><child link="upper"/><axis xyz="0 1 0"/>
    <origin xyz="0 0 0.3"/><limit lower="-2.5" upper="2.5" effort="40" velocity="5"/></joint>
  <link name="upper"><inertial><origin xyz="0 0 0.15"/><mass value="0.8"/>
    <inertia ixx="0.006" iyy="0.006" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.12"/><geometry><capsule radius="0.03" length="0.16"/></geometry></collision>
    <collision><origin xyz="0 0 0.3"/><geometry><sphere radius="0.045"/></geometry></collision></link>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><axis xyz="0 1 0"/>
    <origin xyz="0 0 0.3"/><limit lower="-2.8" upper="2.8" effort="20" velocity="5"/></joint>
  <link name="fore"><inertial><origin xyz="0 0 0.12"/><mass value="0.5"/>
    <inertia ixx="0.003" iyy="0.003" izz="0.0005" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.12"/><geometry><capsule radius="0.025" length="0.14"/></geometry></collision>
    <collision><origin xyz="0 0 0.25"/><geometry><sphere radius="0.035"/></geometry></collision></link>
  <joint name="tip_joint" type="fixed"><parent link="fore"/><child link="tip"/><origin xyz="0 0 0.25"/></joint>
  <link name="tip"/>
</robot>
"""

SCENE = """
[[scene]]
name = "table"
type = "box"
size = [0.5, 0.6, 0.04]
pose = [0.45, 0.0, 0.2, 0.0, 0.0, 0.0]

[[scene]]
name = "ball"
type = "sphere"
radius = 0.05
pose = [0.3, 0.25, 0.55, 0.0, 0.0, 0.0]

[[scene]]
name = "pole"
type = "capsule"
radius = 0.03
length = 0.5
pose = [-0.3, 0.2, 0.4, 0.3, 0.0, 0.0]
"""

START = {"yaw": 0.2, "shoulder": 0.6, "elbow": 0.9}


def arm_file(folder: Path) -> Path:
    """The arm's URDF written into ``folder``."""
    path = folder / "three_link.urdf"
    path.write_text(ARM_URDF)
    return path
