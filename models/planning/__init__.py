"""A span, the car's traction characteristic and the energy-efficient run over it (seeds 003, 004)."""
