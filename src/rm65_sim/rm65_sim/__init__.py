"""RealMan RM-65 controller simulator: its TCP server, controller state, motion model and fault injection
(``ros2 run rm65_sim simulator``), and the cycle-time floor priced by its time law."""
