"""Shared piece of the ablation tools (heavy_mask_ablation.py, sections_hold_ablation.py): one grouped bar chart, a
bar per setting for each object."""

from collections.abc import Callable


def grouped_bars_png(
    path: str,
    objects: list[str],
    settings: list[str],
    value: Callable[[str, str], float],
    *,
    ylabel: str,
    title: str,
    label: Callable[[str], str] = str,
    ylim: tuple[float, float] | None = None,
    hline: float | None = None,
) -> None:
    """Write ``path`` (PNG): for each object (x, YCB names shortened) a bar ``value(object, setting)`` per setting,
    legend ``label(setting)``, optional y limits and a dashed target line at ``hline``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(9, 4.5))
    width = 0.8 / len(settings)
    for k, g in enumerate(settings):
        y = [value(o, g) for o in objects]
        ax.bar(np.arange(len(objects)) + (k - (len(settings) - 1) / 2) * width, y, width, label=label(g))
    if hline is not None:
        ax.axhline(hline, color="k", lw=0.8, ls="--")
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.set_xticks(np.arange(len(objects)), [o.split("_", 1)[1] for o in objects], rotation=20)
    ax.set_ylabel(ylabel)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
