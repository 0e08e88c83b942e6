"""insalign_ros: strapdown INS initial alignment for ROS 2 Jazzy."""

__version__ = "0.1.0"
