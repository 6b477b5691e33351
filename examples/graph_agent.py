"""A stand-in SLAM agent configured only by the environment (FLEETSLAM_ROUTER, FLEETSLAM_AGENT,
FLEETSLAM_LISTEN), as the seed's agents were by ROS_MASTER_URI / ROS_IP / LSD_SLAM_NODE.

    FLEETSLAM_AGENT=c3po python examples/graph_agent.py --peers r2d2

The agent itself lives in the package: fleetslam.launch.example_agent.
"""

from fleetslam.launch.example_agent import main

if __name__ == "__main__":
    main()
