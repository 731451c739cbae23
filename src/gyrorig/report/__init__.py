"""Reports: plots (matplotlib, object API only, never ``plt.show``), text summaries and the HTML report."""

from .html import write_report
from .plots import (plot_fit, plot_stability, plot_sweep, plot_tracking, plot_trajectory, plot_validation,
                    plot_work_precision)
from .text import markdown_table

__all__ = ["markdown_table", "plot_fit", "plot_stability", "plot_sweep", "plot_tracking", "plot_trajectory",
           "plot_validation", "plot_work_precision", "write_report"]
