"""ROS 1 services written with rospy (run it with Debian's python3, not fleetslam's), for the bridge's tests:

- ``/ros1/trigger`` (std_srvs/Trigger): success, with a message naming rospy and the call's number;
- ``/ros1/set`` (std_srvs/SetBool): echoes ``data``; fails (the handler raises) when ``data`` is false;
- ``/ros1/slow`` (std_srvs/Trigger): answers after ``--slow`` seconds.

Its node, ``/ros1/services``, also provides rospy's own ``get_loggers`` and ``set_logger_level`` (roscpp types the
fleet does not have).

    /usr/bin/python3 tests/ros1/ros1_services.py --slow 3
"""

import argparse
import time

import rospy
from std_srvs.srv import SetBool, SetBoolResponse, Trigger, TriggerResponse


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--slow", type=float, default=3.0)
    args = parser.parse_args()
    rospy.init_node("services", anonymous=False)
    calls = []

    def on_trigger(request):
        calls.append(request)
        return TriggerResponse(success=True, message=f"from rospy, call {len(calls)}")

    def on_set(request):
        if not request.data:
            raise RuntimeError("refusing to switch off")
        return SetBoolResponse(success=True, message="switched on")

    def on_slow(request):
        time.sleep(args.slow)
        return TriggerResponse(success=True, message="late")

    rospy.Service("/ros1/trigger", Trigger, on_trigger)
    rospy.Service("/ros1/set", SetBool, on_set)
    rospy.Service("/ros1/slow", Trigger, on_slow)
    rospy.spin()


if __name__ == "__main__":
    main()
