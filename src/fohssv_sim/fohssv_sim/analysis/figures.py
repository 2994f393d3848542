"""What every figure of the analysis shares: the quick label, state units, saving.

:func:`save` writes a figure to each path and stores its visible titles (the figure title and
every axes title, joined by newlines) as the file's ``Title`` metadata (PNG text chunk, SVG
``<dc:title>``), so a saved figure can be checked for what it says without a viewer.

Pure: matplotlib (Agg), no ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ['QUICK_LABEL', 'STATE_UNITS', 'pyplot', 'titled', 'visible_titles', 'save']

#: The label of every output of ``fohssv report --quick``: its runs are too short and its
#: grids too coarse for the verdicts to stand.
QUICK_LABEL = 'quick (not converged)'

#: Units of the state components (docs/model.md §1).
STATE_UNITS = {'z': 'm', 'w': 'm/s', 'theta': 'rad', 'q': 'rad/s'}


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def titled(title: str, label: str = '') -> str:
    """``title`` with ``label`` (e.g. :data:`QUICK_LABEL`) as its first line."""
    return f'{label}\n{title}' if label else title


def visible_titles(fig: Any) -> str:
    """The figure title and every axes title, one per line."""
    parts = []
    if fig._suptitle is not None and fig._suptitle.get_text():
        parts.append(fig._suptitle.get_text())
    parts += [ax.get_title() for ax in fig.axes if ax.get_title()]
    return '\n'.join(parts)


def save(fig: Any, paths: Sequence[Path], **kwargs: Any) -> None:
    """Save ``fig`` to every path (format from the suffix) with its titles as metadata."""
    text = visible_titles(fig)
    for p in paths:
        meta = {'Title': text} if Path(p).suffix.lower() in ('.png', '.svg') else None
        fig.savefig(p, metadata=meta, **kwargs)
