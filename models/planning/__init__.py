"""A span, the car's traction characteristic and the energy-efficient run over it (Meleshin 2011,
Sidorenko 1997)."""
