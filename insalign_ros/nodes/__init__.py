"""Thin rclpy nodes: messages <-> core calls, parameters, QoS, diagnostics."""
