"""Scenario simulators: analytic trajectories -> exact IMU by inverse navigation, sensor error models. No ROS import."""
