"""The simulated inspection plant (MuJoCo): procedural hall, diff-drive robots, Kinect-like RGB-D, TUM export.

Import submodules directly (``fleetslam.sim.plant``, ``fleetslam.sim.camera``, ...); MuJoCo is only loaded by
the modules that need it.
"""
