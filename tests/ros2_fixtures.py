#!/usr/bin/env python3
"""ROS 2 messages serialised and read by an independent CDR implementation (rosbags), for
tests/ros2_io.rs.

  ros2_fixtures.py write DIR   write DIR/*.cdr and DIR/expected.json (what each message holds)
  ros2_fixtures.py read DIR    decode the DIR/out_*.cdr files terranav wrote; print them as JSON
  ros2_fixtures.py hashes      print the Jazzy RIHS01 type hashes as JSON
"""
import json
import math
import struct
import sys
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)
# velodyne_msgs is not in rosbags' stores: its two definitions as the ROS 2 package has them.
TS.register({
    **get_types_from_msg("builtin_interfaces/Time stamp\nuint8[1206] data\n", "velodyne_msgs/msg/VelodynePacket"),
    **get_types_from_msg("std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets\n", "velodyne_msgs/msg/VelodyneScan"),
})
T = TS.types
TYPES = [
    "sensor_msgs/msg/PointCloud2",
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/Imu",
    "sensor_msgs/msg/NavSatFix",
    "geometry_msgs/msg/Twist",
    "tf2_msgs/msg/TFMessage",
    "geometry_msgs/msg/QuaternionStamped",
    "velodyne_msgs/msg/VelodyneScan",
]


def header(sec, nsec, frame):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame)


def vec3(x, y, z):
    return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def quat(x, y, z, w):
    return T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)


def cloud(layout, big):
    """A 2x3 organised cloud in a driver's layout; point 4 is NaN (is_dense false)."""
    PF = T["sensor_msgs/msg/PointField"]
    pts = [(1.0, 2.0, 3.0), (-4.0, 5.5, 0.25), (10.0, -0.5, 1.5), (float("nan"), 0.0, 0.0), (0.125, 0.25, -2.0), (7.0, 8.0, 9.0)]
    e = ">" if big else "<"
    if layout == "velodyne":  # x y z intensity (f32), ring (u16), time (f32 s)
        fields = [PF(name="x", offset=0, datatype=7, count=1), PF(name="y", offset=4, datatype=7, count=1),
                  PF(name="z", offset=8, datatype=7, count=1), PF(name="intensity", offset=12, datatype=7, count=1),
                  PF(name="ring", offset=16, datatype=4, count=1), PF(name="time", offset=18, datatype=7, count=1)]
        step = 22
        rows = [struct.pack(e + "ffffHf", *p, 10.0 * i, i % 16, 0.01 * i) for i, p in enumerate(pts)]
    else:  # ouster: x y z (f64 here, to cover float64), t (u32 ns), reflectivity, ring as "channel"
        fields = [PF(name="x", offset=0, datatype=8, count=1), PF(name="y", offset=8, datatype=8, count=1),
                  PF(name="z", offset=16, datatype=8, count=1), PF(name="t", offset=24, datatype=6, count=1),
                  PF(name="reflectivity", offset=28, datatype=4, count=1), PF(name="channel", offset=30, datatype=4, count=1)]
        step = 32
        rows = [struct.pack(e + "dddIHH", *p, 1_000_000 * i, 7, 60 + i) for i, p in enumerate(pts)]
    data = np.frombuffer(b"".join(rows), dtype=np.uint8)
    msg = T["sensor_msgs/msg/PointCloud2"](header=header(1700000000, 500000000, "os_sensor" if layout == "ouster" else "velodyne"),
                                          height=2, width=3, fields=fields, is_bigendian=big, point_step=step,
                                          row_step=3 * step, data=data, is_dense=False)
    finite = [(i, p) for i, p in enumerate(pts) if all(math.isfinite(v) for v in p)]
    exp = {"stamp_s": 1700000000.5, "points": [list(p) for _, p in finite], "dropped": 1}
    if layout == "velodyne":
        exp.update(intensity=[10.0 * i for i, _ in finite], ring=[i % 16 for i, _ in finite], time=[0.01 * i for i, _ in finite])
    else:
        exp.update(intensity=None, ring=[60 + i for i, _ in finite], time=[1e-3 * i for i, _ in finite])
    return msg, exp


def write(d):
    d.mkdir(parents=True, exist_ok=True)
    expected = {}

    def put(name, msg, typename, exp, big=False):
        (d / f"{name}.cdr").write_bytes(bytes(TS.serialize_cdr(msg, typename, little_endian=not big)))
        expected[name] = exp

    for layout in ("velodyne", "ouster"):
        for big in (False, True):
            msg, exp = cloud(layout, big)
            put(f"cloud_{layout}_{'be' if big else 'le'}", msg, "sensor_msgs/msg/PointCloud2", exp, big)
    cov36 = np.zeros(36)
    odom = T["nav_msgs/msg/Odometry"](
        header=header(12, 250000000, "odom"), child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=1.5, y=-2.0, z=0.1), orientation=quat(0.0, 0.0, 0.6, 0.8)), covariance=cov36),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
            linear=vec3(0.7, 0.0, 0.0), angular=vec3(0.0, 0.0, -0.2)), covariance=cov36))
    put("odom", odom, "nav_msgs/msg/Odometry", {"stamp_s": 12.25, "position": [1.5, -2.0, 0.1], "orientation": [0, 0, 0.6, 0.8], "v": 0.7, "w": -0.2})
    cov9 = np.zeros(9)
    imu = T["sensor_msgs/msg/Imu"](header=header(13, 0, "imu_link"), orientation=quat(0, 0, 0, 1), orientation_covariance=cov9,
                                   angular_velocity=vec3(0.01, -0.02, 0.3), angular_velocity_covariance=cov9,
                                   linear_acceleration=vec3(0.1, 0.2, 9.81), linear_acceleration_covariance=cov9)
    put("imu", imu, "sensor_msgs/msg/Imu", {"stamp_s": 13.0, "gyro": [0.01, -0.02, 0.3], "accel": [0.1, 0.2, 9.81]})
    fix = T["sensor_msgs/msg/NavSatFix"](header=header(14, 0, "gps"), status=T["sensor_msgs/msg/NavSatStatus"](status=2, service=1),
                                         latitude=41.574965910, longitude=-93.750571901, altitude=246.719,
                                         position_covariance=np.array([0.0004, 0, 0, 0, 0.0004, 0, 0, 0, 0.0009]), position_covariance_type=2)
    put("fix", fix, "sensor_msgs/msg/NavSatFix", {"stamp_s": 14.0, "lat": 41.574965910, "lon": -93.750571901, "alt": 246.719, "status": "Gbas"})
    tf = T["tf2_msgs/msg/TFMessage"](transforms=[T["geometry_msgs/msg/TransformStamped"](
        header=header(0, 0, "base_link"), child_frame_id="velodyne",
        transform=T["geometry_msgs/msg/Transform"](translation=vec3(0.2, 0.0, 0.6), rotation=quat(0, 0, 0, 1)))])
    put("tf", tf, "tf2_msgs/msg/TFMessage", {"parent": "base_link", "child": "velodyne", "t": [0.2, 0.0, 0.6]})
    put("twist", T["geometry_msgs/msg/Twist"](linear=vec3(0.5, 0, 0), angular=vec3(0, 0, 0.25)), "geometry_msgs/msg/Twist", {"v": 0.5, "w": 0.25})
    (d / "expected.json").write_text(json.dumps(expected))


def read(d):
    out = {}
    for name, typename in [("twist", "geometry_msgs/msg/Twist"), ("odom", "nav_msgs/msg/Odometry"), ("imu", "sensor_msgs/msg/Imu"),
                           ("fix", "sensor_msgs/msg/NavSatFix"), ("cloud", "sensor_msgs/msg/PointCloud2"), ("tf", "tf2_msgs/msg/TFMessage")]:
        m = TS.deserialize_cdr((d / f"out_{name}.cdr").read_bytes(), typename)
        if name == "twist":
            out[name] = [m.linear.x, m.angular.z]
        elif name == "odom":
            out[name] = [m.header.stamp.sec, m.header.stamp.nanosec, m.child_frame_id, m.pose.pose.position.x, m.twist.twist.linear.x]
        elif name == "imu":
            out[name] = [m.header.frame_id, m.angular_velocity.z, m.linear_acceleration.z]
        elif name == "fix":
            out[name] = [int(m.status.status), m.latitude, m.longitude, m.altitude]
        elif name == "cloud":
            names = [f.name for f in m.fields]
            raw = bytes(m.data)
            xyz = [list(struct.unpack_from("<fff", raw, i * m.point_step)) for i in range(m.width * m.height)]
            out[name] = [names, m.point_step, xyz]
        else:
            t = m.transforms[0]
            out[name] = [t.header.frame_id, t.child_frame_id, t.transform.translation.z]
    print(json.dumps(out))


if __name__ == "__main__":
    cmd = sys.argv[1]
    if cmd == "write":
        write(Path(sys.argv[2]))
    elif cmd == "read":
        read(Path(sys.argv[2]))
    elif cmd == "hashes":
        print(json.dumps({t: TS.hash_rihs01(t) for t in TYPES}))
