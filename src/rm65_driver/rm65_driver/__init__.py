"""RealMan RM-65 driver: ROS-free core (protocol, kinematics, simulator, client, journal, safety,
weld sequence) and a thin rclpy adapter (``driver_node``)."""
