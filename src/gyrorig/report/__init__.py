"""Reports: plots (matplotlib, object API only, never ``plt.show``) and text summaries."""

from .plots import plot_trajectory

__all__ = ["plot_trajectory"]
