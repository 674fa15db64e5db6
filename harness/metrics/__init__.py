"""Metrics computed once from a RunResult: estimation quality, filter comparison, ATO targets."""
