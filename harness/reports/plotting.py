"""The one matplotlib set-up of every report and sweep plot: the Agg backend (no display needed)
and saving a figure with its title, closed afterwards so that a long sweep holds no figures."""
from __future__ import annotations

import re
from pathlib import Path


def pyplot():
    """matplotlib.pyplot on the Agg backend (imported on first use: the harness's computing never
    needs matplotlib)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig, title: str | None, path: Path, dpi: int = 110) -> Path:
    """Give ``fig`` its title (if any), lay it out, write it to ``path`` and close it."""
    plt = pyplot()
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


_POWER = re.compile(r"(?<=[A-Za-z)])([23])(?![0-9])")


def display_unit(unit: str) -> str:
    """A unit as a plot or a printed table shows it: the ASCII powers of the FMU units and CSV
    headers as superscripts ("N/kN/(m/s)2" -> "N/kN/(m/s)²", "m2/s2" -> "m²/s²")."""
    return _POWER.sub(lambda m: "²" if m.group(1) == "2" else "³", unit)
