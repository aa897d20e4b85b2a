"""The rail under the arm: the controller's expansion joint (device 4).

Its axis and messages, and the driver's control of it.
"""
