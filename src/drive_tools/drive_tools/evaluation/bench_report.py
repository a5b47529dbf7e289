"""The benchmarks' reports as text lines (drive bench throughput, bridge, full-speed, injection-cost,
motor, startup); their JSON is the report itself."""
from .report_text import formatted


def throughput_line(row):
    """One estimator's closed-loop throughput (drive_tools.evaluation.bench.throughput)."""
    return (f"  {row['estimator']:14s} {row['samples_per_second']:12,.0f} samples/s (best of {row['repeats']} × "
            f"{row['samples']} samples; median {row['samples_per_second_median']:,.0f}; per CPU second "
            f"{row['samples_per_cpu_second']:,.0f})")


def against_lines(report):
    """Today's throughput beside an older commit's (drive_tools.evaluation.bench.throughput_against)."""
    then = report["label"]
    lines = [f"  {report['rounds']} alternating runs of {report['samples']} samples each, today and {then} "
             f"(samples per CPU second, best / median)"]
    for name, row in report["results"].items():
        cells = [f"{label} " + (f"{row[label]['best']:11,.0f} / {row[label]['median']:11,.0f}" if "best" in row[label]
                                else f"not measured ({row[label]['error']})") for label in ("today", then)]
        ratio = (f"  today/{then} {row['ratio_best']:.2f} (median {row['ratio_median']:.2f})"
                 if "ratio_best" in row else "")
        lines.append(f"  {name:20s} {cells[0]}   {cells[1]}{ratio}")
    return lines


def motulator_lines(report, python):
    """motulator's reference throughput beside ours (report: the throughput report with ``motulator``)."""
    reference = report["motulator"]
    if "error" in reference:
        return [f"  motulator: not timed ({reference['error']})"]
    return [f"  motulator      {reference['samples_per_second']:12,.0f} samples/s ({reference['samples']} samples "
            f"in {reference['wall_time_s']:.2f} s, {reference['cpu_time_s']:.2f} CPU s, {python})"] + [
        f"  {name:14s} {ratio:12,.0f} × motulator per CPU second "
        f"({report['ratio_to_motulator_wall'][name]:,.0f} × on the wall clock)"
        for name, ratio in report["ratio_to_motulator"].items()]


def bridge_lines(report, paced):
    """drive_tools.evaluation.bench.bridge_rates as a table: paced (late periods, latency, angle error) or
    answer-paced (samples/s, latency, the host's share, the bare link)."""
    hop = report["links"][0]["hop_us"] if report["links"] else None
    hop_line = f"  one rclpy hop on this machine: {hop:.1f} µs (latencies in hops in --json)" if hop else ""
    hop_line += "".join(f"\n  {row['link']}: the answer compiled whole, {row['ring_overflow']} samples the ring had "
                        f"no room for; {'; '.join(sum(row['scheduling'].values(), [])) or 'normal scheduling'}"
                        for row in report["links"] if row.get("answer") == "compiled")
    if paced:
        lines = [f"bridge closed loop, {report['scenario']} ({report['samples']} samples, inverter on its own clock "
                 f"at {report['sampling_rate_Hz']:g} Hz; worst of {report['repeats']})",
                 f"  {'link':6s} {'N':>3s} {'late':>8s} {'latency p50':>12s} {'p99':>9s} {'max':>9s} "
                 f"{'angle RMS':>10s} {'peak':>7s} {'lost':>5s}"]
        for row in report["links"]:
            us = [formatted(row[key], "{:.0f}") for key in ("latency_p50_us", "latency_p99_us", "latency_max_us")]
            angles = [formatted(row[key], "{:.4f}") for key in ("angle_error_rms", "angle_error_peak")]
            lines.append(f"  {row['link']:6s} {row['block_samples']:3d} {100.0 * row['late_fraction']:7.3f}% "
                         f"{us[0]:>9s} µs {us[1]:>6s} µs {us[2]:>6s} µs {angles[0]:>10s} {angles[1]:>7s} "
                         f"{row['lock_lost']:5d}")
        return lines + [hop_line]
    lines = [f"bridge closed loop, {report['scenario']} ({report['samples']} samples, inverter paced by the "
             f"host's answers; best of {report['repeats']})",
             f"  {'link':6s} {'samples/s':>10s} {'latency p50':>12s} {'p99':>9s} {'host p50':>9s} {'p99':>9s} "
             f"{'bare echo':>10s} {'missing':>8s}"]
    lines += [f"  {row['link']:6s} {row['samples_per_s']:10.0f} {row['latency_p50_us']:9.0f} µs "
              f"{row['latency_p99_us']:6.0f} µs {row['host_p50_us']:6.0f} µs {row['host_p99_us']:6.0f} µs "
              f"{row['link_echo_us']:7.0f} µs {row['missing_commands']:8d}" for row in report["links"]]
    return lines + [hop_line]


def _band_label(band):
    return f"{100 * band[0]:g}-{100 * band[1]:g} %"


def full_speed_lines(reports):
    """drive_tools.evaluation.speed_range.full_speed_comparison per scenario: whole run and per speed band."""
    lines = []
    for report in reports:
        lines.append(f"{report['scenario']} ({report['motor']}, {report['duration_s']:g} s); angle error RMS / peak "
                     f"[rad el.] and HF current RMS [A] per |speed| band (share of rated)")
        bands = [_band_label(b["band"]) for b in report["runs"][0]["bands"]]
        lines.append(f"  {'estimator':16s} {'loop':8s} {'whole run':>15s} {'targets':>8s} "
                     + " ".join(f"{b:>22s}" for b in bands))
        for run in report["runs"]:
            whole = f"{formatted(run['angle_error_rms'], '{:.4f}')} / {formatted(run['angle_error_peak'], '{:.3f}')}"
            kept = {True: "kept", False: "missed", None: "-"}[run.get("meets_targets")]
            cells = [f"{formatted(b.get('angle_error_rms'), '{:.4f}')} / "
                     f"{formatted(b.get('angle_error_peak'), '{:.3f}')} "
                     f"{formatted(b.get('hf_current_rms_A'), '{:.2f}')}" for b in run["bands"]]
            lines.append(f"  {run['estimator']:16s} {run['loop'].split(',')[0]:8s} {whole:>15s} {kept:>8s} "
                         + " ".join(f"{c:>22s}" for c in cells))
    return lines


def injection_cost_lines(report):
    """drive_tools.evaluation.speed_range.injection_cost: HF current, its copper loss and the angle error."""
    lines = [f"{report['scenario']} ({report['motor']}): what the injection costs over the steady windows",
             f"  {'estimator':28s} {'U_h [V]':>8s} {'HF RMS [A]':>11s} {'P_cu,HF [W]':>12s} {'RMS [rad]':>10s} "
             f"{'peak [rad]':>11s} {'targets':>8s}"]
    lines += [f"  {row['estimator']:28s} {formatted(row['amplitude_V'], '{:.2f}'):>8s} "
              f"{row['hf_current_rms_A']:11.3f} {row['hf_copper_loss_W']:12.4f} "
              f"{formatted(row['angle_error_rms'], '{:.4f}'):>10s} "
              f"{formatted(row['angle_error_peak'], '{:.3f}'):>11s} "
              f"{'kept' if row['meets_targets'] else 'missed':>8s}" for row in report["estimators"] + report["sweep"]]
    lines.append(f"  least amplitude keeping the targets (ours): {formatted(report['least_amplitude_V'], '{:g} V')}")
    return lines


def motor_bench_lines(reports):
    """drive_tools.evaluation.motor_bench.motor_trial per motor: commissioning, loops, start-up, the cases and
    the verdict."""
    lines = []
    for r in reports:
        errors = ", ".join(f"{k} {100.0 * v:+.2f} %" for k, v in r["identification_error"].items())
        lines.append(f"{r['motor']}: {r['description'] or r['file']}")
        lines.append(f"  commissioned ({', '.join(r['tests'])}; against the plant's truth): {errors or '—'}")
        if r["refused_at"]:
            lines += [f"  REFUSED ({r['refused_at']}): {r['reason']}", f"  verdict: {r['verdict']}"]
            continue
        s = r["startup"]
        lines.append(f"  current limit {r['current_limit_A']:.3g} A; loops: tracking {r['tracking_bandwidth_Hz']:.3g} "
                     f"Hz, carrier {r['injection_frequency_Hz']:.4g} Hz, {r['injection_amplitude_V']:.3g} V")
        lines += [f"  WARNING {line}" for line in r["warnings"]]
        if r["drive_notes"]:
            lines.append(f"  the drive says: {r['drive_notes']}")
        loaded = r["loaded_test"]
        if loaded["significant"]:
            lines.append(f"  loaded test: ours' error under load corrected ({loaded['correction_at_rated_rad']:+.4f} "
                         f"rad at rated current)")
        else:
            lines.append(f"  loaded test: within 3× its own noise ({loaded['zero_spread_rad']:.3g} rad at zero "
                         f"current): no correction")
        fraction = s["polarity_correct_fraction"]
        lines.append(f"  start-up over {s['runs']} angles: polarity "
                     f"{formatted(None if fraction is None else 100.0 * fraction, '{:.1f} %')}, "
                     f"lock lost {s['lock_lost']}, not started {s['not_started']}")
        lines += [f"  {c['case']:16s} load {c['load_per_rated']:.2f} rated  RMS "
                  f"{formatted(c['angle_error_rms'], '{:.4f}')} rad  peak {formatted(c['angle_error_peak'], '{:.3f}')} "
                  f"rad  exit {c['exit_code']}  {c['verdict']}"
                  for c in r["cases"]]
        lines.append(f"  verdict: {r['verdict']}" + (f": {r['reason']}" if r["reason"] else ""))
    return lines


def startup_lines(reports):
    """drive_tools.evaluation.startup_bench.startup_sweep per motor and load case."""
    lines = [f"{'motor':12s} {'load':20s} {'runs':>5s} {'polarity':>9s} {'|err| max':>10s} {'back max':>9s} "
             f"{'start max':>10s} {'lost':>5s} {'no start':>9s}"]
    for r in reports:
        fraction, duration = r["polarity_correct_fraction"], r["duration_max_s"]
        cells = (formatted(None if fraction is None else 100.0 * fraction, "{:.1f} %"),
                 formatted(r["angle_error_max_e_rad"], "{:.3f} rad"),
                 formatted(r["reverse_rotation_max_m_deg"], "{:.2f}°"),
                 formatted(None if duration is None else 1e3 * duration, "{:.1f} ms"))
        lines.append(f"{r['motor']:12s} {r['case']:20s} {r['runs']:5d} {cells[0]:>9s} {cells[1]:>10s} "
                     f"{cells[2]:>9s} {cells[3]:>10s} {r['lock_lost']:5d} {r['not_started']:9d}")
    return lines
