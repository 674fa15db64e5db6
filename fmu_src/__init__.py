"""FMI 2.0 co-simulation adapters (pythonfmu) around ``models``: one variable table, two slaves."""
