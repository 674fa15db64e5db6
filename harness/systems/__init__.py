"""FMU systems: SSP packages written and read, our Jacobi master, libcosim, the system CLI."""
