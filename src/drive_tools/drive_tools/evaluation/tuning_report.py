"""Reports of ``drive tune current|speed|pll``: the gains a rule or a model gives, beside Szabó's Table 2
where the motor is its IPMSM; each as text lines."""
import dataclasses
import math

from foc_controller.tuning import (
    SZABO_TABLE2,
    current_bandwidth_damping,
    current_pi_gains,
    speed_bandwidth_damping,
    speed_pi_gains,
)
from hf_estimator.pll_model import margins
from hf_estimator.pll_tuning import MAPPINGS, tuned

TABLE2_MOTOR = "szabo_ipmsm"
"""The motor whose gains Szabó's Table 2 gives."""


def gains_entry(gains):
    return {"A_p": gains.kp, "T_i_s": gains.kp / gains.ki, "kp": gains.kp, "ki": gains.ki}


def current_tuning(motor, plate, omega_n, zeta, axes):
    """The d/q current PI gains of ``motor`` (its name or file; nameplate ``plate``) for the closed-loop
    ω_n [rad/s] and ζ on ``axes``; ValueError where no gains reach them."""
    inductance = {"d": plate.L_d_H, "q": plate.L_q_H}
    report = {"motor": motor, "bandwidth_rad_s": omega_n, "damping": zeta,
              "method": "closed-loop poles of the PI around 1/(Ls + R): k_p = 2ζω_n L − R, k_i = ω_n² L "
                        "(Szabó ref. [16])",
              "gains": {axis: gains_entry(current_pi_gains(inductance[axis], plate.R_s_ohm, omega_n, zeta))
                        for axis in axes}}
    if motor == TABLE2_MOTOR:
        report["table2"] = {axis: {**gains_entry(SZABO_TABLE2[axis]), **dict(zip(
            ("bandwidth_rad_s", "damping"),
            current_bandwidth_damping(inductance[axis], plate.R_s_ohm, SZABO_TABLE2[axis])))} for axis in axes}
    return report


def current_tuning_lines(report):
    lines = [f"current PI on {report['motor']}: ω_n {report['bandwidth_rad_s']:.1f} rad/s, ζ {report['damping']:g} "
             f"({report['method']})"]
    for axis, g in report["gains"].items():
        line = f"  {axis}: A_p {g['A_p']:8.3f} V/A  T_i {1e3 * g['T_i_s']:7.3f} ms"
        if "table2" in report:
            t = report["table2"][axis]
            line += (f"   (Table 2: A_p {t['A_p']:.2f}, T_i {1e3 * t['T_i_s']:.1f} ms, which this method gives "
                     f"for ω_n {t['bandwidth_rad_s']:.1f} rad/s, ζ {t['damping']:.3f})")
        lines.append(line)
    return lines


def speed_tuning(motor, plate, requested, zeta, pll_crossover, crossover_from, ratio):
    """The speed PI gains of ``motor`` (nameplate ``plate``: J, B, k_t = 1.5 n_p ψ_f) for the requested
    ω_n [rad/s], kept at ≤ ``ratio`` × the PLL crossover [rad/s]; ValueError where no gains reach it."""
    k_t = 1.5 * plate.n_p * plate.psi_f_Wb
    cap = ratio * pll_crossover
    omega_n = min(requested, cap)
    report = {"motor": motor, "requested_bandwidth_rad_s": requested, "bandwidth_rad_s": omega_n,
              "damping": zeta, "pll_crossover_rad_s": pll_crossover, "pll_crossover_from": crossover_from,
              "ratio": ratio, "limited_by_pll": requested > cap, "J_kgm2": plate.J_kgm2, "k_t_Nm_per_A": k_t,
              "method": "closed-loop poles of the PI around k_t/(Js + B), current loop ideal: "
                        "k_p = (2ζω_n J − B)/k_t, k_i = ω_n² J/k_t (Szabó ref. [16])",
              "gains": gains_entry(speed_pi_gains(plate.J_kgm2, plate.B_Nms, k_t, omega_n, zeta))}
    if motor == TABLE2_MOTOR:
        table = SZABO_TABLE2["speed"]
        report["table2"] = {**gains_entry(table), **dict(zip(
            ("bandwidth_rad_s", "damping"), speed_bandwidth_damping(plate.J_kgm2, plate.B_Nms, k_t, table)))}
    return report


def speed_tuning_lines(report):
    r = report
    cap = r["ratio"] * r["pll_crossover_rad_s"]
    lines = [f"speed PI on {r['motor']}: ω_n {r['bandwidth_rad_s']:.1f} rad/s, ζ {r['damping']:g} "
             f"(J {r['J_kgm2']:g} kg·m², k_t {r['k_t_Nm_per_A']:.4f} N·m/A)",
             f"  PLL crossover {r['pll_crossover_rad_s']:.1f} rad/s ({r['pll_crossover_from']}); the speed loop is "
             f"kept at ≤ {r['ratio']:g} × it"
             + (f": the requested {r['requested_bandwidth_rad_s']:g} rad/s was lowered to {cap:.1f}"
                if r["limited_by_pll"] else ""),
             f"  A_p {r['gains']['A_p']:.4f} A·s/rad  T_i {1e3 * r['gains']['T_i_s']:.2f} ms"]
    if "table2" in r:
        t = r["table2"]
        lines.append(f"  Table 2: A_p {t['A_p']:.3f}, T_i {1e3 * t['T_i_s']:.0f} ms, which this method gives for "
                     f"ω_n {t['bandwidth_rad_s']:.1f} rad/s, ζ {t['damping']:.3f} with the nameplate's J")
    return lines


def pll_tuning(design, estimator, motor, phase_margin_deg, crossover_rad_s, model, T_f_s):
    """The PLL of ``estimator`` on ``motor`` (design: drive_tools.evaluation.pll_check.design_for_motor) tuned by
    its carrier model and, where it maps onto it, Szabó's (§2.4) to the phase margin [deg] and crossover
    [rad/s] requested (None: the highest reaching the margin), beside the margins of its current gains.
    ``model`` names the tuning chosen; ``T_f_s`` the synchronous estimator's loop filter (else None)."""
    models = {"carrier": design.carrier, "szabo": design.szabo}
    A_now, T_now = design.current_gains
    report = {"motor": motor, "estimator": estimator, "mapping": MAPPINGS[estimator],
              "injection": {"frequency_Hz": design.path.omega_h_rad_s / (2.0 * math.pi),
                            "amplitude_V": design.path.injection_amplitude_V,
                            "demodulation_amplitude": design.path.u_star},
              "request": {"phase_margin_deg": phase_margin_deg, "crossover_rad_s": crossover_rad_s, "model": model},
              "T_f_s": T_f_s, "tuned": {}, "current_gains": {"A_p": A_now, "T_i_s": T_now}}
    for name, loop in models.items():
        if loop is None:
            continue
        try:
            report["tuned"][name] = tuned(loop, phase_margin_deg, crossover_rad_s)
        except ValueError as error:
            report["tuned"][name] = {"error": str(error)}
        report["current_gains"][name] = dataclasses.asdict(margins(loop, A_now, T_now))
    return report


def pll_tuning_lines(report):
    A_now, T_now = report["current_gains"]["A_p"], report["current_gains"]["T_i_s"]
    lines = [f"PLL of `{report['estimator']}` on {report['motor']}: {report['injection']['frequency_Hz']:g} Hz, "
             f"{report['injection']['amplitude_V']:g} V",
             f"  maps onto the model as: {report['mapping']}"]
    if report["T_f_s"] is not None:
        lines.append(f"  loop filter T_f {1e3 * report['T_f_s']:.3f} ms")
    rows = [(f"current gains, {m}", A_now, T_now, report["current_gains"][m]) for m in ("carrier", "szabo")
            if m in report["current_gains"]]
    rows += [(f"tuned by the {m} model", t["A_p"], t["T_i_s"], t) for m, t in report["tuned"].items()
             if "error" not in t]
    lines.append(f"  {'':34s} {'A_p':>10s} {'T_i [ms]':>9s} {'crossover':>10s} {'margin':>7s} {'gain margin':>11s}")
    lines += [f"  {label:34s} {A:10.1f} {1e3 * T:9.2f} {m['crossover_rad_s']:10.1f} "
              f"{m['phase_margin_deg']:6.1f}° {m['gain_margin_dB']:8.1f} dB" for label, A, T, m in rows]
    lines += [f"  tuned by the {m} model: {t['error']}" for m, t in report["tuned"].items() if "error" in t]
    for check in report.get("check", []):
        lines.append(f"  closed loop, A_p {check['A_p']:.1f}, T_i {1e3 * check['T_i_s']:.2f} ms "
                     f"({check['plant']} plant): {'bandwidth':>10s} {'peak':>8s} {'crossover':>10s} {'margin':>7s}")
        for label in ("measured", "carrier_model", "szabo_model"):
            if label in check:
                f = check[label]
                lines.append(f"    {label:30s} {f['bandwidth_rad_s']:10.1f} {f['peak_dB']:6.2f} dB "
                             f"{f['crossover_rad_s']:10.1f} {f['phase_margin_deg']:6.1f}°")
    lines += [f"  plot: {path}" for path in report.get("plots", [])]
    if report.get("interrupted"):
        lines.append(f"  closed-loop check interrupted after {len(report['check'])} of 4 runs")
    return lines
