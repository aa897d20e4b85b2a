"""What every package of the cell shares, in the lowest package (it imports none of ours):
rotations and rigid transforms (``rotations``), the frame names of REP 105 (``frames``), strict JSON
(``strict_json``), TF messages (``tf_io``), the node boilerplate -- QoS, parameters, diagnostics,
stamps, ``spin_node`` (``ros_io``) --, the cell's state vocabulary (``vocabulary``) and the hand-eye
transform a node uses (``hand_eye_in_use``, ``hand_eye_ros``)."""
