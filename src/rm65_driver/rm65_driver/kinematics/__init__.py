"""The RM-65's kinematics (modified DH, FK, IK, time law) and its robot model (URDF written and parsed)."""
