# The ros_node / procs fixtures and the rosproc path come from tests/conftest.py.
