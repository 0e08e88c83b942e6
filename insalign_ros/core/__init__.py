"""Numerical core: pure numpy/scipy, no ROS import (Lie groups, Earth model, mechanization, types)."""
