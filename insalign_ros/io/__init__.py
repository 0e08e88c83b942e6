"""Data I/O: the rosbag2 contract (rosbags reader/writer), KITTI OXTS conversion, input validation. No rclpy import."""
