"""Motion of a rig's booms: move times, timed profiles (and, later, collision-free moves)."""
