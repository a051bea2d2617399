"""Matplotlib figures to PNG files, atomically (the plots of demos and benchmarks)."""

from __future__ import annotations

from pathlib import Path

from softvr.files import atomic_output

__all__ = ["save_figure"]


def save_figure(fig, path, *, dpi: int = 110) -> Path:
    """Write a Matplotlib figure to ``path`` as PNG (its folder is created), atomically, then
    close the figure. Returns the path."""
    import matplotlib.pyplot as plt  # noqa: PLC0415

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_output(path, ".png") as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return path
