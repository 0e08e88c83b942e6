"""Command-line tools (insalign-demo, insalign-align, insalign-simulate, insalign-kitti2bag)."""
