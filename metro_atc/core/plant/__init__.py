"""The metro line plant: vehicle dynamics, track, ATP, passengers, sensors (ROS-free)."""
