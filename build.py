"""Build dist/RailCar.fmu, dist/RailCarEstimator.fmu, dist/AtoController.fmu and the native FMUs; validate them.

    python build.py [--dest dist] [--pythonfmu-binary] [--no-native]

The command line of ``fmu_src.build`` (fmu_src/build/cli.py says what is built, in which order,
and how it is validated; fmu_src/build/__init__.py maps the package).
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))   # fmu_src from this tree, wherever it runs

from fmu_src.build.cli import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
