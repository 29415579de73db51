"""``episode.png`` of a run report: episodes against time (the paper's Fig. 3 in numbers).

One column per episode (the first ok episode, the first that damaged the hardware if any, the
last), rows sharing their y-axis: body pitch, pitch rate, arm joint angles against their
commanded setpoints, motor currents, elbow cable tension against the cable's breaking tension.
Vertical lines mark the strike (the balance let go: ``balance_released_s``) and the arms'
ground contact (the first sharp pitch deceleration after it, below ``-strike_acc``); an x marks
each broken cable (EMCY 0xFF10). Drawn from the agent's time series files
(``ersac_hil.episode_series``).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ersac_hil.episode_series import EpisodeSeries  # noqa: E402
from protocol.can.objects import EmcyCode  # noqa: E402

__all__ = ["ground_contact_s", "plot_episodes"]

#: Earliest ground contact after the strike [s] (the strike's own transient is shorter).
CONTACT_AFTER_S = 0.1
#: (joint, colour, line style): colour by joint, solid left, dashed right (the arms move alike)
_ARM = (("shoulder_left", "tab:blue", "-"), ("shoulder_right", "tab:blue", (0, (4, 2))),
        ("elbow_left", "tab:orange", "-"), ("elbow_right", "tab:orange", (0, (4, 2))))
_MOTORS = (("wheel_left", "tab:grey", "-"), ("wheel_right", "tab:grey", (0, (4, 2))), *_ARM)


def strike_s(series: EpisodeSeries) -> float | None:
    """When the balance let go at the strike [s since the first SYNC], or None."""
    value = series.meta.get("telemetry", {}).get("balance_released_s")
    return float(value) if value is not None and series.meta.get("strike_acc") else None


def ground_contact_s(series: EpisodeSeries) -> float | None:
    """The arms' ground contact [s]: the first cycle at least ``CONTACT_AFTER_S`` after the
    strike whose pitch acceleration is below ``-strike_acc`` (the hands stop the fall), or
    None (no strike, or no such cycle)."""
    t0, limit = strike_s(series), series.meta.get("strike_acc")
    if t0 is None or not limit:
        return None
    hit = np.flatnonzero((series.t >= t0 + CONTACT_AFTER_S) & (series.pitch_acc < -float(limit)))
    return float(series.t[hit[0]]) if hit.size else None


def _title(label: str, series: EpisodeSeries) -> str:
    meta = series.meta
    theta = ", ".join(f"{v:.3f}" for v in meta.get("theta", ()))
    cost = meta.get("total_cost")
    flags = [k.replace("_", " ") for k, v in (meta.get("failures") or {}).items() if v]
    return (f"{label}: theta {theta}" + (f", cost {cost:.1f}" if cost is not None else "")
            + (f"\n{', '.join(flags)}" if flags else "\nno failure"))


def _marks(axes: Sequence[plt.Axes], series: EpisodeSeries) -> None:
    for ax in axes:
        for when, style, label in ((strike_s(series), "--", "strike"),
                                   (ground_contact_s(series), ":", "arms hit the ground")):
            if when is not None:
                ax.axvline(when, color="k", ls=style, lw=1, label=label if ax is axes[0] else None)


def plot_episodes(path: Path, episodes: Sequence[tuple[str, EpisodeSeries]]) -> None:
    """Draw ``episodes`` ((label, series), one column each) into ``path``."""
    rows = 5
    cols = len(episodes)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols + 1.6, 12.5), sharex="col", sharey="row",
                             squeeze=False, constrained_layout=True)
    for c, (label, s) in enumerate(episodes):
        pitch, rate, arms, amps, cable = axes[:, c]
        pitch.plot(s.t, np.degrees(s.pitch), color="k", lw=1.2, label="pitch (forward +)")
        rate.plot(s.t, np.degrees(s.pitch_rate), color="tab:purple", lw=1.2, label="pitch rate")
        spline = bool(s.spline.any())
        for joint, colour, style in _ARM:
            arms.plot(s.t, s.position[:, s.joint(joint)], color=colour, ls=style, lw=1.2,
                      label=joint.replace("_", " "))
            if not spline:
                arms.plot(s.t, s.setpoint_of(joint), color="k", lw=0.8, ls=":")
        if not spline:
            arms.plot([], [], color="k", ls=":", lw=0.8, label="setpoints (commanded)")
        else:
            arms.text(0.02, 0.04, "setpoints: the spline on the arm boards", transform=arms.transAxes,
                      fontsize=7, color="grey")
        for joint, colour, style in _MOTORS:
            amps.plot(s.t, s.current[:, s.joint(joint)], color=colour, ls=style, lw=1.0,
                      label=joint.replace("_", " "))
        low, high = s.meta["cable_strength_range_n"]
        cable.axhspan(low, high, color="tab:red", alpha=0.12, label=f"cables break ({low:.0f}-{high:.0f} N)")
        cable.axhline(s.meta["cable_breaking_tension_n"], color="tab:red", lw=0.8)
        tension = s.cable_tension.copy()
        broke = []
        for ev in s.meta.get("emcy", ()):
            if ev["code"] == EmcyCode.CABLE_BROKEN and 0 <= ev["index"] < len(s):
                side = 0 if ev["device"].endswith("left") else 1
                k = max(ev["index"] - 1, 0)  # the cable's last tension before it snapped
                broke.append((s.t[k], tension[max(k - 3, 0):k + 1, side].max()))
                tension[ev["index"]:, side] = np.nan  # a broken cable carries nothing
        for side, (colour, style) in enumerate((("tab:orange", "-"), ("tab:orange", (0, (4, 2))))):
            cable.plot(s.t, tension[:, side], color=colour, ls=style, lw=1.2,
                       label=f"{('left', 'right')[side]} elbow cable")
        for when, value in broke:
            cable.plot(when, value, "x", color="k", ms=9, mew=2, label="cable broke")
        _marks(axes[:, c], s)
        pitch.set_title(_title(label, s), fontsize=9)
        cable.set_xlabel("time since the first SYNC [s]")
        cable.set_xlim(0, s.t[-1] if len(s) else 1)
        for ax in axes[:, c]:
            ax.grid(alpha=0.3)
    for ax, unit in zip(axes[:, 0], ("body pitch [deg]", "pitch rate [deg/s]", "arm joint angle [rad]",
                                     "motor current [A]", "cable tension [N]")):
        ax.set_ylabel(unit)
    for row in axes:  # one legend per row, outside the data, right of the last column
        seen: dict[str, object] = {}
        for ax in row:
            for handle, text in zip(*ax.get_legend_handles_labels()):
                seen.setdefault(text, handle)
        row[-1].legend(seen.values(), seen.keys(), loc="upper left", bbox_to_anchor=(1.02, 1.0),
                       fontsize=7, frameon=False)
    top = max((float(np.max(s.cable_tension)) for _, s in episodes if len(s)), default=0.0)
    axes[4, 0].set_ylim(0, max(top, episodes[0][1].meta["cable_strength_range_n"][1]) * 1.08)
    fig.suptitle("episodes against time (strike and ground contact marked)", fontsize=11)
    fig.savefig(path, dpi=100)
    plt.close(fig)
