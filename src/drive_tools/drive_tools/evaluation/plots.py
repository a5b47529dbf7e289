"""PNG plots: a run (angle, angle error, speed, load, phase currents), angle errors side by side (replay,
compare), and the PLL tuning's Bode plots."""
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from drive_common.config.experiment import RPM  # noqa: E402
from drive_common.contract.estimator_states import TRACKING  # noqa: E402
from drive_common.contract.log import COLUMN  # noqa: E402

from .metrics import LOCK_LOST_RAD, angle_error, wrap  # noqa: E402


def plot_run(result, out_dir, command="run"):
    """Write ``<out_dir>/<scenario>_<estimator>_<command>.png`` (``command``: run, launch or bridge, so
    one never overwrites another) and return its path. Panels: true and estimated angle; angle error with
    the start-up (until the estimator first tracks) and any lost lock after it shaded; speed; load
    torque; phase currents. Dotted lines mark the scenario's events."""
    import numpy as np
    log, n_p = result.log, result.n_p
    t = log[:, COLUMN["t"]]
    error = angle_error(log, n_p)
    fig, axes = plt.subplots(5, 1, figsize=(10, 12), sharex=True,
                             gridspec_kw={"height_ratios": [1, 1, 1, 0.6, 1]})
    axes[0].plot(t, wrap(n_p * log[:, COLUMN["theta_m"]]), label="true θ_e")
    axes[0].plot(t, wrap(log[:, COLUMN["theta_e_hat"]]), "--", label="estimated θ̂_e")
    axes[0].set_ylabel("electrical angle [rad]")
    axes[1].plot(t, error, color="tab:red", lw=0.7, label="θ_e − θ̂_e")
    tracking = np.nonzero(log[:, COLUMN["state"]] == TRACKING)[0]
    starting = np.arange(t.size) < (tracking[0] if tracking.size else t.size)
    if starting.any():
        axes[1].fill_between(t, -np.pi, np.pi, where=starting, color="tab:gray", alpha=0.12, step="mid",
                             label="start-up: axis and polarity, no torque")
    lost = (np.abs(error) > LOCK_LOST_RAD) & ~starting
    if lost.any():
        axes[1].fill_between(t, -np.pi, np.pi, where=lost, color="tab:red", alpha=0.15, step="mid",
                             label="lock lost (|error| > π/2)")
    axes[1].set_ylabel("angle error [rad]")
    axes[2].plot(t, log[:, COLUMN["omega_m_ref"]] / RPM, label="reference")
    axes[2].plot(t, log[:, COLUMN["omega_m"]] / RPM, label="true")
    axes[2].plot(t, log[:, COLUMN["omega_e_hat"]] / n_p / RPM, alpha=0.7, label="estimated")
    axes[2].set_ylabel("speed [rpm]")
    axes[3].plot(t, log[:, COLUMN["tau_load"]], color="tab:brown", label="load τ_L")
    axes[3].set_ylabel("load [N·m]")
    for name, color in (("i_a_meas", "tab:blue"), ("i_b_meas", "tab:orange"), ("i_c_meas", "tab:green")):
        axes[4].plot(t, log[:, COLUMN[name]], lw=0.5, alpha=0.55, color=color, label=f"{name[:3]} (measured)")
    axes[4].set_ylabel("phase current [A]")
    axes[4].set_xlabel("time [s]")
    events = [e for e in result.scenario.events_s() if 0.0 < e < result.scenario.duration_s]
    for ax in axes:
        for event in events:
            ax.axvline(event, color="k", lw=0.6, ls=":")
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{result.scenario.name}: {result.scenario.motor}, estimator {result.estimator} ({command}); "
                 f"dotted: speed and load events")
    fig.tight_layout()
    return _save(fig, Path(out_dir) / f"{result.scenario.name}_{result.estimator}_{command}.png")


def _save(fig, path):
    """Write the figure as a PNG (creating its directory), close it and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_angle_errors(results, labels, path, not_drawn=(), title=None):
    """One PNG with the electrical angle error θ_e − θ̂_e of several runs over time, overlaid (legend:
    label and estimator); ``not_drawn`` lines are listed under the plot. Returns its path."""
    fig, ax = plt.subplots(1, 1, figsize=(10, 4 + 0.25 * len(not_drawn)))
    for result, label in zip(results, labels):
        name = label if label == result.estimator else f"{label} ({result.estimator})"
        ax.plot(result.log[:, COLUMN["t"]], angle_error(result.log, result.n_p), lw=0.7, label=name)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("θ_e − θ̂_e [rad, electrical]")
    ax.grid(True, alpha=0.3)
    if results:
        ax.legend(loc="upper right", fontsize=8, title="estimator", title_fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    if not_drawn:
        fig.text(0.01, 0.01, "not drawn: " + "\n".join(not_drawn), fontsize=7, va="bottom")
    fig.tight_layout(rect=(0, min(0.4, 0.04 * len(not_drawn)), 1, 1))
    return _save(fig, path)


def plot_bode(curves, path, title):
    """Magnitude [dB] and phase [deg] over ω [rad/s] of (label, ω, complex response, phase [deg],
    style) curves (style as matplotlib's, e.g. "-" or "o"); the paper's Fig. 8-9 layout. Returns the path."""
    import numpy as np
    fig, (mag, phase) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for label, omega, response, phase_deg, style in curves:
        mag.semilogx(omega, 20.0 * np.log10(np.abs(response)), style, label=label)
        phase.semilogx(omega, phase_deg, style, label=label)
    mag.axhline(0.0, color="k", lw=0.5)
    mag.axhline(-3.0, color="k", lw=0.5, ls=":")
    mag.set_ylabel("magnitude [dB]")
    phase.set_ylabel("phase [deg]")
    phase.set_xlabel("ω [rad/s]")
    for ax in (mag, phase):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="lower left", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def plot_pll(design, A_p, T_i_s, checks, stem):
    """`drive tune pll`'s plots: Szabó's process (Fig. 8), the open loop with the tuned gains in both
    models (Fig. 9), and each closed-loop check (measured points over both models). Returns the paths."""
    import math

    import numpy as np
    name = f"{design.motor}, {design.estimator.name}"
    omega = np.logspace(0, math.log10(0.9 * design.carrier.search_max_rad_s), 2000)
    loops = [(label, loop) for label, loop in (("carrier model", design.carrier),
                                               ("Szabó model", design.szabo)) if loop is not None]
    paths = []
    if design.szabo is not None:
        process = design.szabo.rest(omega) * 1j * omega
        paths.append(plot_bode([("|K|·G_p·filter (Szabó)", omega, process,
                                 np.degrees(design.szabo.phase(1.0, math.inf, omega)) + 90.0, "-")],
                               stem.with_name(stem.name + "_process.png"),
                               f"{name}: PLL process, no PLL gains (Szabó Fig. 8)"))
    paths.append(plot_bode([(f"{label}, A_p {A_p:.0f}, T_i {1e3 * T_i_s:.1f} ms", omega,
                             loop.open_loop(A_p, T_i_s, omega),
                             np.degrees(loop.phase(A_p, T_i_s, omega)), "-")
                            for label, loop in loops],
                           stem.with_name(stem.name + "_open_loop.png"),
                           f"{name}: PLL open loop with the tuned gains A_p {A_p:.0f}, T_i {1e3 * T_i_s:.1f} ms "
                           f"(Szabó Fig. 9)"))
    for i, check in enumerate(checks or []):
        w = np.asarray(check["response"]["omega_rad_s"])
        T = np.asarray(check["response"]["T_re"]) + 1j * np.asarray(check["response"]["T_im"])
        dense = np.logspace(math.log10(w[0]), math.log10(w[-1]), 1000)
        curves = [("measured (runner)", w, T, np.degrees(np.unwrap(np.angle(T))), "o")]
        for label, loop in loops:
            model = loop.closed_loop(check["A_p"], check["T_i_s"], dense)
            curves.append((label, dense, model, np.degrees(np.unwrap(np.angle(model))), "-"))
        paths.append(plot_bode(curves, stem.with_name(f"{stem.name}_closed_loop_{i + 1}.png"),
                               f"{name}: closed loop θ̂/θ with the "
                               f"{'tuned' if math.isclose(check['A_p'], A_p) else 'current'} gains A_p "
                               f"{check['A_p']:.0f}, T_i {1e3 * check['T_i_s']:.1f} ms ({check['plant']} plant)"))
    return [str(p) for p in paths]
