"""The driver node (`ros2 run rm65_driver driver`): parameters, shared state, state publishing, services."""
