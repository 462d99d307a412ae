"""matplotlib on a headless backend, and atomic PNG files: what every picture of the package draws with
(training's loss curves, :mod:`licrom.viz.render`'s filmstrips and plots)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .._io import atomic_path

__all__ = ["pyplot", "save_png"]


def pyplot() -> Any:
    """matplotlib.pyplot on the headless Agg backend (imported on first use: it is slow to import)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig: Any, path: str | os.PathLike, dpi: float = 110) -> Path:
    """Write a matplotlib figure as a PNG, atomically, and close it."""
    out = Path(path)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
    return out
