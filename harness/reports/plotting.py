"""The one matplotlib set-up of every report and sweep plot: the Agg backend (no display needed)
and saving a figure with its title, closed afterwards so that a long sweep holds no figures."""
from __future__ import annotations

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
