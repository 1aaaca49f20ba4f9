"""The ROS 2 messages of one control cycle: what the run log stores and the live view streams.

:class:`CycleMessages` turns a :class:`CycleRecord` into ``(topic, message)`` pairs of
``rosbags`` message objects (types of :data:`swerve.tools.logs.bag.TOPICS`); the bag writer
serialises them into the MCAP, :mod:`swerve.tools.live` onto Foxglove channels, so the two
cannot drift apart. Parts that are the same every cycle are built once.
"""
from __future__ import annotations

from math import cos, isfinite, sin
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
        # the message classes, looked up once
        self._Float64MultiArray = T["std_msgs/msg/Float64MultiArray"]
        self._Header, self._Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
        self._JointState = T["sensor_msgs/msg/JointState"]
        self._JointTrajectory = T["trajectory_msgs/msg/JointTrajectory"]
        self._JointTrajectoryPoint = T["trajectory_msgs/msg/JointTrajectoryPoint"]
        self._Odometry = T["nav_msgs/msg/Odometry"]
        self._PoseWithCovariance = T["geometry_msgs/msg/PoseWithCovariance"]
        self._PoseStamped, self._Pose = T["geometry_msgs/msg/PoseStamped"], T["geometry_msgs/msg/Pose"]
        self._Point, self._Quaternion = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]

    def header(self, stamp_ns: int):
        """``std_msgs/Header`` at ``stamp_ns`` in the ``odom`` frame."""
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        return self._Header(stamp=self._Time(sec=sec, nanosec=nanosec), frame_id="odom")

    def messages(self, rec: CycleRecord) -> list:
        """``(topic, message)`` for one cycle, ``/swerve/cycle`` first; a pose topic whose pose
        is not finite (unknown) is left out."""
        header = self.header(rec.stamp_ns)
        out = [("/swerve/cycle", self._Float64MultiArray(layout=self._layout, data=pack(rec))),
               ("/joint_states", self._JointState(
                   header=header, name=self._joints,
                   position=np.concatenate([_NAN4, rec.meas_steer_rad]),
                   velocity=np.concatenate([rec.meas_drive_radps, _NAN4]),
                   effort=np.asarray(rec.meas_current_a, dtype=np.float64)))]
        point = self._JointTrajectoryPoint(
            positions=np.concatenate([_NAN4, rec.cmd_steer_rad]),
            velocities=np.concatenate([rec.cmd_drive_radps, _NAN4]),
            accelerations=self._empty, effort=self._empty, time_from_start=self._zero_duration)
        out.append(("/trajectory", self._JointTrajectory(header=header, joint_names=self._joints,
                                                         points=[point])))
        out.append(("/odom", self._Odometry(
            header=header, child_frame_id="base_link",
            pose=self._PoseWithCovariance(pose=self.pose(rec.est_pose), covariance=self._covariance),
            twist=self._no_twist)))
        for topic, pose in (("/reference", rec.ref_pose), ("/true_pose", rec.true_pose),
                            ("/sim_pose", rec.sim_pose)):
            x, y, th = pose.tolist()
            if isfinite(x) and isfinite(y) and isfinite(th):
                out.append((topic, self._PoseStamped(header=header, pose=self._planar(x, y, th))))
        return out

    def pose(self, pose):
        """``geometry_msgs/Pose`` of a planar pose ``(x_m, y_m, theta_rad)``."""
        x, y, th = map(float, pose)
        return self._planar(x, y, th)

    def _planar(self, x: float, y: float, th: float):
        return self._Pose(position=self._Point(x=x, y=y, z=0.0),
                          orientation=self._Quaternion(x=0.0, y=0.0, z=sin(th / 2), w=cos(th / 2)))

    def pose_stamped(self, header, pose):
        """``geometry_msgs/PoseStamped`` of a planar pose under ``header``."""
        return self._PoseStamped(header=header, pose=self.pose(pose))
