"""The walk-through in docs/notebook.md runs as written (its Python blocks, top to bottom, in one namespace)."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib

DOC = Path(__file__).resolve().parents[1] / "docs" / "notebook.md"


def test_notebook_walkthrough_runs(tmp_path, monkeypatch):
    matplotlib.use("Agg")
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert len(blocks) >= 6
    ns: dict = {}
    for block in blocks:
        exec(compile(block, str(DOC), "exec"), ns)  # noqa: S102 - the document's own code
    fit, refit = ns["fit"], ns["refit"]
    # the walk-through ends with a report on disk and a refit that used the prior
    assert Path(ns["report"]).is_file()
    assert refit.constraints.priors and not fit.constraints
    assert refit.params["precession_rate_rad_s"][1] < fit.params["precession_rate_rad_s"][1]
    import matplotlib.pyplot as plt

    plt.close("all")
