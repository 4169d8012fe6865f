"""Scoring IK solutions: errors, collision tables, figures, the papers' reported numbers."""
