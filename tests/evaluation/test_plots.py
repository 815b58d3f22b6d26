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


def _saved_figures(monkeypatch: pytest.MonkeyPatch) -> list:  # type: ignore[type-arg]
    from matplotlib.figure import Figure

    saved: list[Figure] = []
    real_savefig = Figure.savefig

    def savefig(self: Figure, *args: object, **kwargs: object) -> None:
        saved.append(self)
        real_savefig(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return saved


def _drawn(fig):  # type: ignore[no-untyped-def]
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def test_identical_filters_say_which_one_hides_the_other(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Mahony and the gyro-platform filter give the same attitude with their defaults: the legend says so."""
    pytest.importorskip("matplotlib")
    from mavahrs.evaluation.plots import plot_attitude

    saved = _saved_figures(monkeypatch)
    n = 500
    t = np.arange(n) / 250.0
    same = _rows(n, 1)
    estimates = {"mahony": same, "gyroplatform": same.copy(), "best": _rows(n, 2)}
    plot_attitude(tmp_path / "same.png", t, estimates, reference_q=_rows(n, 0)[:, OUT_Q : OUT_Q + 4])
    (fig,) = saved
    roll = next(ax for ax in fig.axes if ax.get_ylabel() == "roll (°)")
    labels = roll.get_legend_handles_labels()[1]
    assert "mahony (identical to gyroplatform, hidden beneath it)" in labels
    assert "gyroplatform" in labels and "best" in labels  # the others keep their plain names


def test_filters_within_a_hundredth_of_a_degree_say_which_one_hides_the_other(tmp_path: Path,
                                                                             monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """With GNSS velocity Mahony and the gyro-platform filter differ by at most 0.002° (the demo's tlog): the
    orange line was invisible under the purple one, and the legend said nothing (it took only bit-equal
    attitudes as the same)."""
    pytest.importorskip("matplotlib")
    from mavahrs.evaluation.plots import plot_attitude

    saved = _saved_figures(monkeypatch)
    n = 500
    t = np.arange(n) / 250.0
    base = _rows(n, 1)
    near = base.copy()
    half = np.radians(0.002) / 2  # a 0.002° turn about x of every sample
    q = base[:, OUT_Q : OUT_Q + 4]
    w, x, y, z = q.T
    c, s_ = np.cos(half), np.sin(half)
    near[:, OUT_Q : OUT_Q + 4] = np.stack([c * w - s_ * x, c * x + s_ * w, c * y + s_ * z, c * z - s_ * y], axis=1)
    apart = base.copy()
    apart[:, OUT_Q : OUT_Q + 4] = _rows(n, 2)[:, OUT_Q : OUT_Q + 4]
    plot_attitude(tmp_path / "near.png", t, {"mahony": near, "gyroplatform": base, "best": apart},
                  reference_q=_rows(n, 0)[:, OUT_Q : OUT_Q + 4])  # fmt: skip
    (fig,) = saved
    roll = next(ax for ax in fig.axes if ax.get_ylabel() == "roll (°)")
    labels = roll.get_legend_handles_labels()[1]
    assert "mahony (within 0.002° of gyroplatform, hidden beneath it)" in labels, labels
    assert "gyroplatform" in labels and "best" in labels


def test_fleet_plot_names_flagged_flights_inside_the_figure_with_whole_counts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Flagged flights are numbered at their points and named in a strip under the axes: no label is cut off
    by the figure's edge or drawn over the legend; the histograms count whole flights."""
    pytest.importorskip("matplotlib")
    from mavahrs.evaluation.plots import plot_fleet

    saved = _saved_figures(monkeypatch)
    rng = np.random.default_rng(1)
    rows = []
    for i in range(20):
        flagged = i % 3 == 0
        rows.append({"path": f"/logs/flight_{i:03d}_a_long_scenario_name.tlog",
                     "inclination_max_deg": float(rng.uniform(0.1, 20)), "heading_max_deg": float(rng.uniform(0.2, 40)),
                     "duration_s": 100.0, "alarms": 2 if flagged else 0, "first_alarm_s": 12.5 * i if flagged else None,
                     "inclination_rms_deg": float(rng.uniform(0.1, 3)), "vibration_x_m_s2": 1.0,
                     "vibration_y_m_s2": 2.0, "vibration_z_m_s2": float(rng.uniform(0, 5)),
                     "gyro_clip_fraction": 0.0, "accel_clip_fraction": 0.0})  # fmt: skip
    plot_fleet(tmp_path / "fleet.png", rows)
    (fig,) = saved
    renderer = _drawn(fig)
    page = fig.bbox
    texts = [t for t in fig.texts if "flight_" in t.get_text()]
    listed = " ".join(t.get_text() for t in texts)
    for i in range(0, 20, 3):
        assert f"flight_{i:03d}_a_long_scenario_name.tlog @ {12.5 * i:.1f} s" in listed
    legend = fig.axes[0].get_legend().get_window_extent(renderer)
    for t in texts:
        box = t.get_window_extent(renderer)
        assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1, t.get_text()
        for ax in fig.axes:
            assert not box.overlaps(ax.get_window_extent(renderer)), f"{t.get_text()!r} is drawn over a panel"
    for note in fig.axes[0].texts:  # the numbers at the points
        assert note.get_text().isdigit() and not note.get_window_extent(renderer).overlaps(legend)
    for ax in fig.axes[1:]:
        ticks = [v for v in ax.get_yticks() if ax.get_ylim()[0] <= v <= ax.get_ylim()[1]]
        assert ticks and all(float(v).is_integer() for v in ticks), ticks


def test_a_turning_heading_is_drawn_within_the_smallest_angles() -> None:
    """A heading from 355° turning 320° to the right (arducopter_gentle's yaw: 19 s at 355°, 26 s at 315°) is
    drawn −5° … 315°, not −365° … −45° (the median rule's turn); a level BROAD roll at ±180° stays near 180°."""
    from mavahrs.evaluation.plots import _angle

    yaw = np.concatenate([np.full(190, -5.0), np.linspace(-5.0, 315.0, 140), np.full(260, 315.0)])
    wrapped = (yaw + 180.0) % 360.0 - 180.0  # as Euler angles come: −5 … 180, −180 … −45
    drawn = _angle(wrapped, 2)
    assert drawn[0] == pytest.approx(-5.0) and drawn[-1] == pytest.approx(315.0)
    assert np.all(np.abs(np.diff(drawn)) < 10.0), "no wrap-around drawn"
    roll = 180.0 + 3.0 * np.sin(np.linspace(0.0, 20.0, 500))
    drawn_roll = _angle((roll + 180.0) % 360.0 - 180.0, 0)
    assert np.allclose(drawn_roll, roll) or np.allclose(drawn_roll, roll - 360.0)  # one turn, no jumps


def _threshold_lines(ax) -> tuple[list[float], list[float]]:  # type: ignore[no-untyped-def]
    """x of the vertical and y of the horizontal dashed lines on the fleet overview's scatter."""
    vertical = [float(ln.get_xdata()[0]) for ln in ax.lines if ln.get_linestyle() == "--" and
                ln.get_xdata()[0] == ln.get_xdata()[1]]  # fmt: skip
    horizontal = [float(ln.get_ydata()[0]) for ln in ax.lines if ln.get_linestyle() == "--" and
                  ln.get_ydata()[0] == ln.get_ydata()[1]]  # fmt: skip
    return vertical, horizontal


def test_fleet_plot_draws_the_thresholds_the_monitor_judged_with(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The dashed lines are the monitor's: in its default mode (thresholds that follow both estimators' σ) the
    floors they never go below, 1° tilt / 3° heading; in ``fixed`` mode its angles. Until user6 the overview drew
    ``fixed``'s 10° / 25° whatever the mode, so a flight flagged for a 2° tilt fault (``mavahrs inject-fault
    --tilt 2``: 2.2° at most) sat far inside the "thresholds"."""
    pytest.importorskip("matplotlib")
    from mavahrs.evaluation.plots import plot_fleet
    from mavahrs.service.monitor import MonitorSettings

    saved = _saved_figures(monkeypatch)
    rows = [{"path": "/logs/tilt2.tlog", "inclination_max_deg": 2.2, "heading_max_deg": 1.2, "duration_s": 200.7,
             "alarms": 1, "first_alarm_s": 100.2, "inclination_rms_deg": 1.5, "vibration_x_m_s2": 0.07},
            {"path": "/logs/clean.tlog", "inclination_max_deg": 0.4, "heading_max_deg": 1.0, "duration_s": 58.9,
             "alarms": 0, "first_alarm_s": None, "inclination_rms_deg": 0.16, "vibration_x_m_s2": 0.1}]  # fmt: skip
    default = MonitorSettings()
    plot_fleet(tmp_path / "default.png", rows)
    plot_fleet(tmp_path / "fixed.png", rows, monitor=MonitorSettings(mode="fixed", tilt_threshold_deg=4.0,
                                                                     heading_threshold_deg=12.0))  # fmt: skip
    (ax_default, ax_fixed) = (fig.axes[0] for fig in saved)
    assert _threshold_lines(ax_default) == ([default.min_tilt_threshold_deg], [default.min_heading_threshold_deg])
    assert _threshold_lines(ax_default)[0][0] < rows[0]["inclination_max_deg"]  # the flagged flight lies beyond
    assert any("floors (1° tilt, 3° heading" in t for t in ax_default.get_legend_handles_labels()[1])
    assert _threshold_lines(ax_fixed) == ([4.0], [12.0])
    assert "monitor thresholds (4° tilt, 12° heading)" in ax_fixed.get_legend_handles_labels()[1]


def test_audit_plot_draws_the_thresholds_of_its_config(sitl_gentle_tlog: Path, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """``mavahrs audit --config C --plot``: the overview's dashed lines are C's ``[pipeline.monitor]``."""
    pytest.importorskip("matplotlib")
    log = sitl_gentle_tlog
    from mavahrs.cli import main

    config = tmp_path / "fixed.toml"
    config.write_text('[pipeline.monitor]\nmode = "fixed"\ntilt_threshold_deg = 4.0\nheading_threshold_deg = 12.0\n')
    saved = _saved_figures(monkeypatch)
    assert main(["audit", str(log), "--serial", "--no-progress", "--plot", str(tmp_path / "fleet.png"),
                 "--config", str(config)]) == 0  # fmt: skip
    (overview,) = [fig for fig in saved if fig.axes and fig.axes[0].get_title().startswith("mavahrs vs")]
    assert _threshold_lines(overview.axes[0]) == ([4.0], [12.0])


def test_a_plot_name_without_a_suffix_is_written_as_png_and_said_so(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``-o flight`` (no suffix): matplotlib writes flight.png; the plot function returns, and the command
    says, that file (until user8 "wrote flight" named a file that does not exist)."""
    pytest.importorskip("matplotlib")
    from mavahrs.cli import main
    from mavahrs.evaluation.plots import plot_attitude

    n = 300
    written = plot_attitude(tmp_path / "api", np.arange(n) / 250.0, {"best": _rows(n, 1)})
    assert written == tmp_path / "api.png" and written.is_file() and not (tmp_path / "api").exists()
    csv = tmp_path / "r.csv"  # a replay CSV, drawn as it is
    cols = ("qw,qx,qy,qz,roll_deg,pitch_deg,yaw_deg,gain,accel_weight,mag_weight,accel_rejected,mag_rejected,"
            "bias_x_deg_s,bias_y_deg_s,bias_z_deg_s,flags,sent").split(",")  # as `mavahrs replay --csv` writes
    rows = ["time_s," + ",".join(f"best_{c}" for c in cols)]
    rows += [f"{10 + k * 0.004:.6f},{np.cos(k * 1e-3):.7f},{np.sin(k * 1e-3):.7f},0,0,{np.degrees(2e-3 * k):.3f},0,0,"
             "0.01,1,1,0,0,0,0,0,0,1" for k in range(n)]  # fmt: skip
    csv.write_text("\n".join(rows) + "\n")
    capsys.readouterr()
    assert main(["plot", str(csv), "-o", str(tmp_path / "flight")]) == 0
    assert f"wrote {tmp_path / 'flight.png'}" in capsys.readouterr().err
    assert (tmp_path / "flight.png").is_file() and not (tmp_path / "flight").exists()
    # the same CSV cut down by hand: without the gain and trust columns it is drawn; without a quaternion
    # column one line names it (until user8 "internal error: KeyError: 'best_gain'")
    header = rows[0].split(",")
    for name, keep in (("short", [c for c in header if not c.endswith(("_gain", "_weight"))]),
                       ("broken", [c for c in header if c != "best_qz"])):  # fmt: skip
        idx = [header.index(c) for c in keep]
        (tmp_path / f"{name}.csv").write_text("\n".join(",".join(r.split(",")[i] for i in idx) for r in rows) + "\n")
    assert main(["plot", str(tmp_path / "short.csv"), "-o", str(tmp_path / "short.png")]) == 0
    assert (tmp_path / "short.png").is_file()
    capsys.readouterr()
    assert main(["plot", str(tmp_path / "broken.csv"), "-o", str(tmp_path / "broken.png")]) == 1
    assert f"plot: {tmp_path / 'broken.csv'}: a replay CSV without its column(s) best_qz" in capsys.readouterr().err


def test_a_slower_magnetometer_is_not_drawn_as_rejected_between_its_readings(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """A PX4 ULog's compass at 98 Hz between 248 Hz IMU samples: the samples without a reading carry
    FLAG_MAG_INVALID and a weight of 0; the trust panel drew them as 0 ("rejected") and the compass line
    alternated 0/1, a solid block.  Now: held between readings, a gap once the compass is gone, and a
    real rejection (weight 0 on a sample with a reading) still drawn as 0."""
    pytest.importorskip("matplotlib")
    from mavahrs.evaluation.plots import TRUST_HOLD_S, held_trust, plot_attitude
    from mavahrs.filters.layout import FLAG_MAG_INVALID, OUT_FLAGS

    n = 2500
    t = np.arange(n) / 250.0  # 10 s
    rows = _rows(n, 0)
    reading = np.arange(n) % 5 < 2  # 100 Hz of 250
    rows[:, OUT_MAG_WEIGHT] = np.where(reading, 1.0, 0.0)
    rows[:, OUT_FLAGS] = np.where(reading, 0, FLAG_MAG_INVALID)
    rejected = (t >= 3.0) & (t < 4.0) & reading  # the filter rejects the compass for 1 s
    rows[rejected, OUT_MAG_WEIGHT] = 0.0
    gone = t >= 7.0  # and then the compass stops
    rows[gone, OUT_MAG_WEIGHT] = 0.0
    rows[gone, OUT_FLAGS] = FLAG_MAG_INVALID

    w = held_trust(t, rows, OUT_MAG_WEIGHT, FLAG_MAG_INVALID)
    trusted = (t < 3.0) | ((t >= 4.01) & (t < 7.0))
    assert np.all(w[trusted] == 1.0), "held between the readings"
    assert np.all(w[(t >= 3.01) & (t < 4.0)] == 0.0), "a rejection is still drawn as one"
    last = t[reading & ~gone][-1]  # the compass's last reading
    assert np.all(w[(t >= 7.0) & (t <= last + TRUST_HOLD_S)] == 1.0)
    assert np.isnan(w[t > last + TRUST_HOLD_S]).all(), "a compass that is gone is a gap, not 'rejected'"

    saved = _saved_figures(monkeypatch)
    plot_attitude(tmp_path / "mag.png", t, {"best": rows})
    (fig,) = saved
    trust = next(ax for ax in fig.axes if ax.get_ylabel().startswith("trust"))
    mag_line = next(ln for ln in trust.get_lines() if ln.get_linestyle() == ":" and len(ln.get_xdata()) > 0)
    x, y = np.asarray(mag_line.get_xdata(), float), np.asarray(mag_line.get_ydata(), float)
    assert np.all(y[(x < 3.0)] == 1.0), "the panel draws the held trust"
