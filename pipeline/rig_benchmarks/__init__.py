"""Benchmarks of the product side: the moves of a rig (`moves.py`), the round over faces x rigs
(`round_faces.py`), the joint CP-SAT model against the routing (`joint_vs_routing.py`).

The study's own benchmarks (the IK solvers and the peers, the exported models' latency) stay in its
layers (`pipeline/evaluation/solver_benchmark.py`, `peer_timing.py`, `pipeline/deploy/latency.py`): a study
stage never imports the product side. docs/benchmarks.md names every benchmark with its command.
"""
