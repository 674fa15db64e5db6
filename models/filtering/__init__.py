"""Filtering of speed and distance: the paper's Kalman filter (13)-(19), its EKF and Singer kinds."""
