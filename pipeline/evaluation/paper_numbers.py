"""What the papers report (docs/reference.md, section 6; paper 000 Table 3), for the report stage."""

# Paper 000, mean hole-seeking error (mm) and average collision rate (%).
PAPER000 = {
    "sikm": {"hole_mm_mean": 22.2, "collision_rate_pct": 6.38},
    "uikm": {"hole_mm_mean": None, "collision_rate_pct": 48.21},
    "cuikm": {"hole_mm_mean": 6.5, "collision_rate_pct": 0.62},
}

# Paper 000 Table 3: per test group, (self, wall, ground, arch) counts over 1 000 holes.
PAPER000_TABLE3 = {
    "cuikm": [(8, 0, 1, 0), (2, 0, 0, 2), (3, 0, 1, 0), (7, 1, 0, 0), (3, 0, 0, 3)],
    "uikm": [(184, 39, 25, 24), (359, 86, 19, 50), (418, 48, 66, 78), (126, 22, 52, 98), (658, 3, 43, 13)],
    "sikm": [(50, 3, 4, 4), (37, 5, 3, 23), (20, 1, 11, 55), (20, 10, 14, 4), (30, 3, 18, 7)],
}

PAPER000_CUIKM_GAIN = 0.7072  # CUIKM's mean error 70.72 % below SIKM's (6.5 vs 22.2 mm)
PAPER000_NM_SPEEDUP = 115.6  # networks vs numerical method, solve time

# Paper 001 (RBF, 63 face holes): mean / max collar error per axis (mm), RBF and its NM.
PAPER_001 = {"rbf": {"x_mean": 0.591, "y_mean": 0.465, "x_max": 2.588, "y_max": 2.336},
             "nm": {"x_mean": 3.592, "y_mean": 1.168, "x_max": 25.589, "y_max": 10.611}}

# Paper 002 (huang9): errors of the global best after 50 / 100 iterations, mean iterations to
# reach (position, orientation) accuracies, and CEOPSO's population table (mean iterations).
PAPER_002 = {
    "after_100": {"pso": (7.4, 0.0163), "eopso": (2.7, 0.0122), "ceopso": (0.1, 0.0019)},  # (mm, rad)
    "after_50": {"ceopso": (1.8, 0.0025)},
    "reach": {(1.0, 0.0174): (149, 107, 42), (1.0, 0.0017): (211, 160, 53), (0.1, 0.0017): (298, 249, 70)},
    "population_iters": {200: 269.5, 400: 196.3, 600: 140.3, 800: 82.2, 1000: 74.5},
}
