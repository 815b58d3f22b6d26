"""The attitude plot's layout: every legend inside the figure, inside its panel, clear of the axis labels.

``mavahrs replay … --filter all --plot`` draws five filters; the bottom "trust" panel's legend
(accelerometer and magnetometer per filter, ten entries in one row) was wider than the figure, cut off
on the left and drawn over the panel's y-axis label.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.filters.layout import OUT_ACCEL_WEIGHT, OUT_GAIN, OUT_MAG_WEIGHT, OUT_Q, OUT_WIDTH

FILTERS = ("madgwick", "mahony", "complementary", "gyroplatform", "best")  # `--filter all`


def _rows(n: int, k: int) -> np.ndarray:
    """(n, OUT_WIDTH) filter output rows: a slow roll, a gain and trust values that differ per filter."""
    t = np.linspace(0.0, 1.0, n)
    half = 0.5 * np.radians(30.0) * np.sin(2 * np.pi * t + k)
    out = np.zeros((n, OUT_WIDTH))
    out[:, OUT_Q], out[:, OUT_Q + 1] = np.cos(half), np.sin(half)
    out[:, OUT_GAIN] = 0.01 * (k + 1)
    out[:, OUT_ACCEL_WEIGHT] = 0.8 + 0.04 * k
    out[:, OUT_MAG_WEIGHT] = 0.6 + 0.05 * k
    return out


def test_every_legend_of_the_all_filters_plot_fits_its_panel(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from mavahrs.evaluation.plots import plot_attitude

    saved: list[Figure] = []
    real_savefig = Figure.savefig

    def savefig(self: Figure, *args: object, **kwargs: object) -> None:
        saved.append(self)
        real_savefig(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    n = 2000
    t = np.arange(n) / 250.0
    estimates = {name: _rows(n, k) for k, name in enumerate(FILTERS)}
    ref = _rows(n, 0)[:, OUT_Q : OUT_Q + 4]
    ap_t = t[::50]
    path = plot_attitude(tmp_path / "all.png", t, estimates, reference_q=ref, reference_label="SIMSTATE truth",
                         others={"autopilot ATTITUDE": (ap_t, ref[::50])}, title="aggressive.tlog")  # fmt: skip
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (fig,) = saved
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)  # closing the figure detached its canvas; the layout stays as saved
    canvas.draw()
    renderer = canvas.get_renderer()
    page = fig.bbox
    legends = [(ax, ax.get_legend()) for ax in fig.axes if ax.get_legend() is not None]
    labels = {ax.get_ylabel().split("\n")[0] for ax, _ in legends}
    assert {"roll (°)", "roll err (°)", "gain", "trust"} <= labels  # every panel with a legend is checked
    for ax, leg in legends:
        box = leg.get_window_extent(renderer)
        panel = ax.get_window_extent(renderer)
        name = ax.get_ylabel().split("\n")[0]
        assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1, (
            f"the {name} legend runs out of the figure: {box} vs {page}"
        )
        assert panel.x0 <= box.x0 and box.x1 <= panel.x1, f"the {name} legend is wider than its panel: {box} vs {panel}"
        for other in fig.axes:
            label = other.yaxis.label.get_window_extent(renderer)
            assert not box.overlaps(label), f"the {name} legend covers the axis label {other.get_ylabel()!r}"
