"""ROS-free algorithm and physics cores (numpy / scipy / torch only)."""
