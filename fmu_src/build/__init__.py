"""Packaging: every FMU we ship is built here, from ``fmu_src/variables.py`` and the C sources.

``python build.py`` is its command line (``cli``). The modules, bottom up:

- ``toolchain``: the project root, a C compiler, fmpy's FMI headers, the linux64 check;
- ``model_description``: the one writer of modelDescription.xml (FMI 2.0 and 3.0) from the
  variable table, for all seven FMUs;
- ``pythonfmu_fmus``: RailCar, RailCarEstimator, AtoController (pythonfmu, FMI 2.0): pythonfmu's
  build in a subprocess, then our description, our FMI 2 binary and a GUID from the sources;
- ``native``: the native FMI 2.0 FMUs (C core, no Python) and their generated table headers
  (``python -m fmu_src.build.native``);
- ``native_fmi3``: the native FMI 3.0 FMUs (same backend behind the FMI 3 glue);
- ``dist``: a folder of built FMUs: paths, GUIDs, staleness, build.py in a subprocess;
- ``cli``: build and validate them all (build.py's flags and output lines).

Nothing here imports the harness; the harness asks ``dist`` whether its FMUs are current.
The package imports none of its modules itself, so that ``python -m fmu_src.build.native`` runs
the module once.
"""
