"""The boom and its world: D-H kinematics, rotations, the tunnel profile, clearances."""
