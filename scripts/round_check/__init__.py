"""The independent round checker (``python scripts/check_round.py``): a round's files judged with code
of its own (numpy forward kinematics from the boom YAML, its own segment and tunnel distances, a
certified time sweep), sharing nothing with ``pipeline`` but the composed settings (Hydra).

Modules, one job each: :mod:`.errors` (input errors, exit 2), :mod:`.boom` (a boom from its YAML:
kinematics, bodies, lever-arm bounds), :mod:`.distance` (segment-segment and horseshoe distances),
:mod:`.profile` (a tunnel of any cross-section: the profile CSV read and validated, a capsule's clearance
to each of its surface kinds), :mod:`.navigation` (the plan frame's transform: a pose given, or the rigid
fit of measured points), :mod:`.settings` (the rig, tunnel, navigation, safety and motion from the
composed config), :mod:`.files` (reading and validating the trajectory, round table, round JSON and
plan), :mod:`.sweep` (certified clearances over time), :mod:`.rules` (row checks: limits, speeds, park,
holes, makespan), :mod:`.actions` (the actions, interlocks and zones files), :mod:`.execute`, :mod:`.episodes`,
:mod:`.certify` (a planned round's robustness certified exactly, for any drilling durations),
:mod:`.executed` (the executed round under drawn durations, and a draws file), :mod:`.realised` (a
realised set at its own times), :mod:`.cli` (the command).
"""
