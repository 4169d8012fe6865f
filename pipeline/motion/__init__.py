"""Motion of a rig's booms: move times, timed paths, dense clearance checks and collision-free moves."""
