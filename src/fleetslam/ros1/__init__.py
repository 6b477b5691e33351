"""ROS 1 without ROS: the master's XML-RPC API and TCPROS in the standard library, messages via rosbags' Noetic store.

Used by ``fleetslam bridge ros1``; nothing here imports rospy or any ROS 1 package.
"""
