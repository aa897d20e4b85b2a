"""RealMan RM-65 driver: ROS-free core (protocol, kinematics, simulator, client, journal, safety,
weld job and sequence) and a thin rclpy adapter (``driver_node`` with ``driver_params``,
``driver_status``, ``driver_services``)."""
