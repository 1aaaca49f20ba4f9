"""The ROS 2 messages of one control cycle: what the run log stores and the live view streams.

:class:`CycleMessages` turns a :class:`CycleRecord` into ``(topic, message)`` pairs of
``rosbags`` message objects (types of :data:`swerve.tools.logs.bag.TOPICS`); the bag writer
serialises them into the MCAP, :mod:`swerve.tools.live` onto Foxglove channels, so the two
cannot drift apart. Parts that are the same every cycle are built once.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .record import CYCLE_SIZE, CycleRecord, pack

_NAN4 = np.full(4, np.nan)


class CycleMessages:
    """Message builder for one typestore (``rosbags.typesys`` store) and joint names (8)."""

    def __init__(self, typestore, joints: Sequence[str]):
        self._ts = typestore
        self._joints = list(joints)
        T = typestore.types
        self._layout = T["std_msgs/msg/MultiArrayLayout"](
            dim=[T["std_msgs/msg/MultiArrayDimension"](label="cycle_record_v1", size=CYCLE_SIZE,
                                                       stride=CYCLE_SIZE)],
            data_offset=0)
        nan3 = T["geometry_msgs/msg/Vector3"](x=np.nan, y=np.nan, z=np.nan)
        self._no_twist = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=nan3, angular=nan3), covariance=np.zeros(36))
        self._zero_duration = T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
        self._empty = np.empty(0)
        self._covariance = np.zeros(36)

    def header(self, stamp_ns: int):
        """``std_msgs/Header`` at ``stamp_ns`` in the ``odom`` frame."""
        T = self._ts.types
        ns = int(stamp_ns)
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
            frame_id="odom")

    def messages(self, rec: CycleRecord) -> list:
        """``(topic, message)`` for one cycle, ``/swerve/cycle`` first; a pose topic whose pose
        is not finite (unknown) is left out."""
        T = self._ts.types
        header = self.header(rec.stamp_ns)
        out = [("/swerve/cycle", T["std_msgs/msg/Float64MultiArray"](layout=self._layout, data=pack(rec)))]
        out.append(("/joint_states", T["sensor_msgs/msg/JointState"](
            header=header, name=self._joints,
            position=np.concatenate([_NAN4, rec.meas_steer_rad]),
            velocity=np.concatenate([rec.meas_drive_radps, _NAN4]),
            effort=np.asarray(rec.meas_current_a, dtype=np.float64))))
        point = T["trajectory_msgs/msg/JointTrajectoryPoint"](
            positions=np.concatenate([_NAN4, rec.cmd_steer_rad]),
            velocities=np.concatenate([rec.cmd_drive_radps, _NAN4]),
            accelerations=self._empty, effort=self._empty, time_from_start=self._zero_duration)
        out.append(("/trajectory", T["trajectory_msgs/msg/JointTrajectory"](
            header=header, joint_names=self._joints, points=[point])))
        out.append(("/odom", T["nav_msgs/msg/Odometry"](
            header=header, child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(rec.est_pose),
                                                           covariance=self._covariance),
            twist=self._no_twist)))
        for topic, pose in (("/reference", rec.ref_pose), ("/true_pose", rec.true_pose),
                            ("/sim_pose", rec.sim_pose)):
            if np.isfinite(pose).all():
                out.append((topic, self.pose_stamped(header, pose)))
        return out

    def pose(self, pose):
        """``geometry_msgs/Pose`` of a planar pose ``(x_m, y_m, theta_rad)``."""
        T = self._ts.types
        x, y, th = (float(v) for v in pose)
        return T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(th / 2),
                                                          w=math.cos(th / 2)))

    def pose_stamped(self, header, pose):
        """``geometry_msgs/PoseStamped`` of a planar pose under ``header``."""
        return self._ts.types["geometry_msgs/msg/PoseStamped"](header=header, pose=self.pose(pose))
