"""Identification of mass and resistance, eqs. (3)-(12), and the online estimator around it."""
