"""Alignment estimators, all implementing insalign_ros.filters.base.AlignmentCore. No ROS import."""
