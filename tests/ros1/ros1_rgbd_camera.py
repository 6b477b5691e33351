"""A ROS 1 RGB-D camera written with rospy (run it with Debian's python3, not fleetslam's), as a Kinect driver
publishes: ``/camera/rgb/image_raw`` (rgb8), ``/camera/depth_registered/image_raw`` (32FC1, metres) and
``/camera/rgb/camera_info``, all stamped alike, from frames a test rendered into a folder (``meta.json``,
``rgb<k>.bin``, ``depth<k>.bin``), played forwards then backwards so the motion has no jump.

    /usr/bin/python3 tests/ros1/ros1_rgbd_camera.py FOLDER --rate 5
"""

import argparse
import json
import os

import rospy
from sensor_msgs.msg import CameraInfo, Image


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("folder")
    parser.add_argument("--rate", type=float, default=5.0)
    args = parser.parse_args()
    with open(os.path.join(args.folder, "meta.json")) as file:
        meta = json.load(file)
    w, h, count = meta["width"], meta["height"], meta["count"]
    frames = []
    for k in range(count):
        rgb_file, depth_file = (os.path.join(args.folder, f"{kind}{k}.bin") for kind in ("rgb", "depth"))
        with open(rgb_file, "rb") as rgb, open(depth_file, "rb") as depth:
            frames.append((rgb.read(), depth.read()))
    order = list(range(count)) + list(range(count - 2, 0, -1))
    rospy.init_node("kinect", anonymous=True)
    rgb_pub = rospy.Publisher("/camera/rgb/image_raw", Image, queue_size=5)
    depth_pub = rospy.Publisher("/camera/depth_registered/image_raw", Image, queue_size=5)
    info_pub = rospy.Publisher("/camera/rgb/camera_info", CameraInfo, queue_size=5)
    cal = meta["K"]
    info = CameraInfo(width=w, height=h, distortion_model="plumb_bob", D=[0.0] * 5, K=cal)
    info.R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    info.P = [*cal[:3], 0.0, *cal[3:6], 0.0, *cal[6:], 0.0]
    rate = rospy.Rate(args.rate)
    seq = 0
    while not rospy.is_shutdown():
        rgb, depth = frames[order[seq % len(order)]]
        info.header.seq = seq
        info.header.stamp = rospy.Time.now()
        info.header.frame_id = "camera_rgb_optical_frame"
        info_pub.publish(info)
        rgb_pub.publish(Image(header=info.header, height=h, width=w, encoding="rgb8", step=3 * w, data=rgb))
        depth_pub.publish(Image(header=info.header, height=h, width=w, encoding="32FC1", step=4 * w, data=depth))
        seq += 1
        rate.sleep()


if __name__ == "__main__":
    main()
