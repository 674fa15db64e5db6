"""Pure computation for the rail-car co-simulation unit: physics, sensors, identification, filters.

No FMI and no file I/O here (profiles are parsed from text handed in by the caller).
Equation numbers refer to the paper, Gorbachev et al. (2015), unless marked otherwise; the model,
its units and its sources are written up in docs/model.md.
"""
