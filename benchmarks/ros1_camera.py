"""A ROS 1 camera stand-in written with rospy (run it with Debian's python3, not fleetslam's): publishes
sensor_msgs/Image (rgb8, a moving gradient) stamped with the wall clock, so receivers can measure latency.

    /usr/bin/python3 benchmarks/ros1_camera.py --topic /camera/rgb/image_raw --rate 30 --width 640 --height 480
"""

import argparse

import rospy
from sensor_msgs.msg import Image


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--topic", default="/camera/rgb/image_raw")
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--count", type=int, default=0, help="stop after N images (0: never)")
    args = parser.parse_args()
    rospy.init_node("ros1_camera", anonymous=True, disable_signals=False)
    pub = rospy.Publisher(args.topic, Image, queue_size=2)
    # Debian's python3 has no numpy here: a ramp twice as wide as a row, sliced at a moving offset.
    ramp = bytes(x & 255 for x in range(args.width + 256) for _ in range(3))
    rate = rospy.Rate(args.rate)
    seq = 0
    while not rospy.is_shutdown() and (args.count == 0 or seq < args.count):
        offset = 3 * (seq % 256)
        frame = ramp[offset : offset + 3 * args.width] * args.height
        msg = Image(height=args.height, width=args.width, encoding="rgb8", step=3 * args.width, data=frame)
        msg.header.frame_id = "camera_rgb_optical_frame"
        msg.header.seq = seq
        msg.header.stamp = rospy.Time.from_sec(rospy.get_time())
        pub.publish(msg)
        seq += 1
        rate.sleep()


if __name__ == "__main__":
    main()
