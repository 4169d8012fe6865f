"""Executing a planned round by events (docs/reference.md, section 8): actions, the conflicts of their sweeps, the
interlocks that make any drilling durations safe, the execution rule, and Monte Carlo draws.

- :mod:`~pipeline.events.actions`: a timeline as each boom's actions; the actions and interlocks
  files (written and read back with validation);
- :mod:`~pipeline.events.conflicts`: which pairs of actions of two booms can come within d_boom at
  any relative timing (certified over each action's whole sweep);
- :mod:`~pipeline.events.graph`: the dependency graph (topological order, cycles, reduction);
- :mod:`~pipeline.events.interlocks`: the robust construction (order every conflicting pair);
- :mod:`~pipeline.events.rule`: the execution rule over a batch of drilling-time draws;
- :mod:`~pipeline.events.draws`: the draws and their summary;
- :mod:`~pipeline.events.robust_round`: the schedule stage's hook (interlocks, draws, one realised round);
- :mod:`~pipeline.events.trajectory`: an executed round's trajectory from the planned file's rows;
- :mod:`~pipeline.events.executed_files`: an executed round's round table, summary pieces, draws file;
- :mod:`~pipeline.events.interrupt`: a hole that cannot be finished, and the round handed on.
"""
