"""Evaluation: metrics (RMSE, convergence time, NEES), plots, aligned-flag criteria. No ROS import."""
