"""The round: holes allocated to booms, ordered and timed so that no two booms come closer
than d_boom at any instant; its baselines, its lower bound and its tables.

Product side, above :mod:`pipeline.motion`. Everything here works on arrays and config values
(:class:`~pipeline.round.problem.Instance`: reach, drilling times, move times, joints), so the stage
can build them from the reach table of any solver; the geometry enters only through the conflict
oracle (:mod:`pipeline.round.oracle`).
"""
