"""RealMan RM-65 driver: ROS-free core (``protocol/``, ``kinematics/``, ``journal/``, ``weld/``) and thin
rclpy adapters (``driver/``, ``state_publisher_node``). The controller simulator is the ``rm65_sim`` package."""
