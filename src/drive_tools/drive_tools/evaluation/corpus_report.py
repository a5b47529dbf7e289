"""``drive bench replay CORPUS --report DIR``: a corpus replay as one self-contained HTML page, with the same
data as JSON and CSV (issue 55 item 4; docs/recordings.md "A report worth publishing").

The unit of every interval is the bag: a bag's score is its RMS angle error over its own scored windows (the
windows nested in it), so a long bag does not weigh more than a short one, and two estimators are compared
on the bags both are scored on, paired. Per estimator: the median of the bags' RMS with a 95 % bootstrap
interval (BOOTSTRAP resamples of the bags, a fixed seed), the share of bags within ours' targets with its
Wilson interval; per motor class and speed band the median; a ranking by median whose neighbours are tested
with the Wilcoxon signed-rank test on their common bags (Holm's correction over the ranking's pairs): a pair
whose corrected p is at least ALPHA "does not differ significantly"; every not-applicable reason counted."""
import base64
import csv
import io
import math
import re
from collections import Counter
from pathlib import Path

import numpy as np

from drive_common.contract.strict_json import dumps

from .speed_range import SPEED_BANDS, TARGETS

BOOTSTRAP = 2000
ALPHA = 0.05
MIN_PAIRED_BAGS = 6
"""Two estimators are tested only on at least this many common bags (Wilcoxon's smallest two-sided p with
n = 6 is 0.03)."""
POLE_PAIR_BANDS = ((6, "1-5"), (16, "6-15"), (math.inf, "16+"))
SALIENCY_BANDS = ((1.1, "< 1.1"), (1.3, "1.1-1.3"), (math.inf, "≥ 1.3"))
"""Bands of a motor class: (upper bound, exclusive; label), in order."""
UNKNOWN = (math.inf, "unknown")
"""The band of a bag whose figure is not known: after every other."""


def _band(value, bands):
    """(rank, label) of ``value``'s band (a saliency below 1 by its inverse)."""
    if value is None:
        return UNKNOWN
    ratio = max(value, 1.0 / value) if value > 0 else value
    return next((rank, label) for rank, (top, label) in enumerate(bands) if ratio < top)


def speed_band(share):
    """(rank, label) of the speed band of a bag's speed per rated speed (speed_range.SPEED_BANDS, as % of
    rated)."""
    if share is None:
        return UNKNOWN
    for rank, (low, high) in enumerate(SPEED_BANDS):
        if low <= share < high:
            return rank, f"{100 * low:g}-{100 * high:g} %"
    return len(SPEED_BANDS), f"≥ {100 * SPEED_BANDS[-1][1]:g} %"


def bag_rows(per_bag):
    """One row per bag and estimator: the bag, its class figures, the estimator, applicable, its scores,
    lost, the reason."""
    rows = []
    for bag in per_bag:
        figures = bag.get("motor_figures") or {}
        for entry in bag["results"]:
            rows.append({"bag": bag["bag"], "motor": bag.get("motor"),
                         "recorded_estimator": bag.get("recorded_estimator"),
                         "n_p": figures.get("n_p"), "saliency": figures.get("saliency"),
                         "speed_per_rated": figures.get("speed_per_rated"), "estimator": entry["estimator"],
                         "applicable": entry["applicable"], "angle_error_rms": entry.get("angle_error_rms"),
                         "angle_error_peak": entry.get("angle_error_peak"), "lost": entry.get("lost"),
                         "reason": entry["reason"]})
    return rows


def _scored(rows, name):
    return {r["bag"]: r for r in rows
            if r["estimator"] == name and r["applicable"] and r["angle_error_rms"] is not None}


def _bootstrap_median(values, rng):
    values = np.asarray(values)
    if values.size < 2:
        return None, None
    medians = np.median(values[rng.integers(0, values.size, (BOOTSTRAP, values.size))], axis=1)
    return float(np.percentile(medians, 2.5)), float(np.percentile(medians, 97.5))


def _wilson(successes, n, z=1.96):
    if n == 0:
        return None, None
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def _within(row):
    return (row["angle_error_rms"] <= TARGETS["angle_error_rms"] and row["angle_error_peak"] is not None
            and row["angle_error_peak"] <= TARGETS["angle_error_peak"] and not row["lost"])


def reason_kind(reason):
    """A reason with its numbers and paths taken out (so equal causes count together)."""
    text = re.sub(r"(?<![\w/])/[\w./-]+", "PATH", reason.split("; the drive refuses it on this motor")[0])
    return re.sub(r"[-+]?\d[\d.,]*(e[-+]?\d+)?", "#", text)


def estimator_table(rows, names, seed=1):
    """Per estimator: bags scored, median RMS and its 95 % interval, share within targets and its interval,
    lost, not applicable (and the reasons counted)."""
    rng = np.random.default_rng(seed)
    table = []
    for name in names:
        scored = _scored(rows, name)
        rms = [r["angle_error_rms"] for r in scored.values()]
        within = sum(_within(r) for r in scored.values())
        low, high = _bootstrap_median(rms, rng)
        share_low, share_high = _wilson(within, len(scored))
        reasons = Counter(reason_kind(r["reason"]) for r in rows if r["estimator"] == name and not r["applicable"])
        table.append({"estimator": name, "scored": len(scored), "rms_median": float(np.median(rms)) if rms else None,
                      "rms_median_ci": [low, high], "within_targets": within,
                      "within_share": within / len(scored) if scored else None,
                      "within_share_ci": [share_low, share_high], "lost": sum(bool(r["lost"]) for r in scored.values()),
                      "not_applicable": sum(reasons.values()), "reasons": dict(reasons.most_common())})
    return table


def class_table(rows, names, key, band):
    """{class label: {estimator: {"bags", "rms_median"}}} over the bags grouped by ``band(row[key])`` ((rank,
    label)), the bands in their order."""
    out = {}
    for name in names:
        for row in _scored(rows, name).values():
            cell = out.setdefault(band(row[key]), {}).setdefault(name, [])
            cell.append(row["angle_error_rms"])
    return {label: {name: {"bags": len(v), "rms_median": float(np.median(v))} for name, v in cells.items()}
            for (_, label), cells in sorted(out.items())}


def ranking(rows, table):
    """The estimators with scored bags ordered by median RMS, each neighbour pair tested (Wilcoxon signed-rank
    on their common bags, Holm-corrected over the pairs): [{estimator, rms_median, against_next: {estimator,
    common_bags, p, p_holm, differs}}]."""
    from scipy.stats import wilcoxon
    ordered = sorted((t for t in table if t["scored"]), key=lambda t: t["rms_median"])
    tests = []
    for a, b in zip(ordered, ordered[1:]):
        sa, sb = _scored(rows, a["estimator"]), _scored(rows, b["estimator"])
        common = sorted(set(sa) & set(sb))
        p = None
        if len(common) >= MIN_PAIRED_BAGS:
            d = np.array([sa[k]["angle_error_rms"] - sb[k]["angle_error_rms"] for k in common])
            p = 1.0 if not np.any(d) else float(wilcoxon(d).pvalue)
        tests.append({"estimator": b["estimator"], "common_bags": len(common), "p": p})
    for rank, i in enumerate(sorted((i for i, t in enumerate(tests) if t["p"] is not None),
                                    key=lambda i: tests[i]["p"])):
        tests[i]["p_holm"] = min(1.0, tests[i]["p"] * (len([t for t in tests if t["p"] is not None]) - rank))
    result = []
    for i, t in enumerate(ordered):
        row = {"estimator": t["estimator"], "rms_median": t["rms_median"], "scored": t["scored"]}
        if i < len(tests):
            test = tests[i]
            test.setdefault("p_holm", None)
            test["differs"] = None if test["p_holm"] is None else test["p_holm"] < ALPHA
            row["against_next"] = test
        result.append(row)
    return result


def report_data(report):
    """The data of the page from a corpus replay report (the command's --json)."""
    names = [row["estimator"] for row in report["summary"]]
    rows = bag_rows(report["per_bag"])
    table = estimator_table(rows, names)
    return {"pattern": report["pattern"], "bags": report["bags"], "skipped": len(report["skipped"]),
            "engine": report.get("engine"), "targets": TARGETS, "bootstrap": BOOTSTRAP, "alpha": ALPHA,
            "estimators": table, "ranking": ranking(rows, table),
            "by_pole_pairs": class_table(rows, names, "n_p", lambda v: _band(v, POLE_PAIR_BANDS)),
            "by_saliency": class_table(rows, names, "saliency", lambda v: _band(v, SALIENCY_BANDS)),
            "by_speed": class_table(rows, names, "speed_per_rated", speed_band), "rows": rows}


def write_report(report, folder):
    """Write report.html, report.json and bags.csv of a corpus replay ``report`` into ``folder``; their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data = report_data(report)
    paths = {"html": folder / "report.html", "json": folder / "report.json", "csv": folder / "bags.csv"}
    paths["json"].write_text(dumps(data, indent=1))
    with paths["csv"].open("w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=list(data["rows"][0]) if data["rows"] else ["bag"])
        writer.writeheader()
        writer.writerows(data["rows"])
    paths["html"].write_text(page(data), encoding="utf-8")
    return {key: str(path) for key, path in paths.items()}


def _figure_png(data):
    """The per-bag RMS of each estimator as strip and box plot (log scale), PNG bytes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [t["estimator"] for t in data["estimators"] if t["scored"]]
    values = [[r["angle_error_rms"] for r in _scored(data["rows"], n).values()] for n in names]
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(names) + 1.5))
    if names:
        ax.boxplot(values, orientation="horizontal", showfliers=False)
        rng = np.random.default_rng(0)
        for i, v in enumerate(values, 1):
            ax.plot(v, i + rng.uniform(-0.15, 0.15, len(v)), ".", alpha=0.5, markersize=4)
        ax.set_yticks(range(1, len(names) + 1), names)
        ax.set_xscale("log")
        ax.axvline(TARGETS["angle_error_rms"], color="k", linestyle="--", linewidth=0.8)
    ax.set_xlabel("angle error RMS per bag [rad el.] (dashed: ours' target)")
    ax.set_title("per-bag angle error, each estimator on the bags it is scored on")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    plt.close(fig)
    return buffer.getvalue()


def _cell(value, digits=4):
    if value is None:
        return "—"
    return f"{value:.{digits}f}"


def _escape(text):
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _class_html(title, table, names):
    head = "".join(f"<th>{_escape(n)}</th>" for n in names)
    body = "".join(f"<tr><td>{_escape(label)}</td>" + "".join(
        f"<td>{_cell(cells[n]['rms_median'])} ({cells[n]['bags']})</td>" if n in cells else "<td>—</td>"
        for n in names) + "</tr>" for label, cells in table.items())
    return f"<h3>{title}</h3><table><tr><th></th>{head}</tr>{body}</table>"


def page(data):
    """The self-contained HTML page (inline CSS, the plot as a data URI, no script, nothing fetched)."""
    png = base64.b64encode(_figure_png(data)).decode()
    names = [t["estimator"] for t in data["estimators"]]
    estimators = "".join(
        f"<tr><td>{_escape(t['estimator'])}</td><td>{t['scored']}</td><td>{_cell(t['rms_median'])}</td>"
        f"<td>{_cell(t['rms_median_ci'][0])}-{_cell(t['rms_median_ci'][1])}</td>"
        f"<td>{t['within_targets']} ({_cell(t['within_share'], 2)}; {_cell(t['within_share_ci'][0], 2)}-"
        f"{_cell(t['within_share_ci'][1], 2)})</td><td>{t['lost']}</td><td>{t['not_applicable']}</td></tr>"
        for t in data["estimators"])
    ranking = "".join(
        f"<tr><td>{i + 1}</td><td>{_escape(r['estimator'])}</td><td>{_cell(r['rms_median'])}</td><td>"
        + (_against(r["against_next"]) if "against_next" in r else "") + "</td></tr>"
        for i, r in enumerate(data["ranking"]))
    reasons = "".join(f"<h4>{_escape(t['estimator'])}</h4><ul>" + "".join(
        f"<li>{count} × {_escape(reason)}</li>" for reason, count in t["reasons"].items()) + "</ul>"
        for t in data["estimators"] if t["reasons"])
    engine = data.get("engine") or {}
    where = f" on {_escape(engine['engine'])}" if engine else ""
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Estimators on {_escape(data['pattern'])}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;}}
table{{border-collapse:collapse;margin:1em 0;}}td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right;}}
td:first-child,th:first-child{{text-align:left;}}</style>
</head><body>
<h1>Estimators on {_escape(data['pattern'])}</h1>
<p>{data['bags']} bags replayed ({data['skipped']} paths skipped){where}.
The unit is the bag: its score is the RMS angle error [rad, electrical] over its own scored windows; intervals
are 95 % ({data['bootstrap']} bootstrap resamples of the bags for the median; Wilson for the share within
ours' targets: RMS ≤ {data['targets']['angle_error_rms']} rad, peak ≤ {data['targets']['angle_error_peak']} rad, no
lost lock).</p>
<h2>Per estimator</h2>
<table><tr><th>estimator</th><th>bags scored</th><th>median RMS</th><th>95 % interval</th>
<th>within targets (share; interval)</th><th>lost</th><th>not applicable</th></tr>{estimators}</table>
<img alt="per-bag angle error per estimator" src="data:image/png;base64,{png}">
<h2>Ranking</h2>
<p>By median RMS; each estimator against the next, paired on the bags both are scored on (Wilcoxon signed-rank,
Holm-corrected over the pairs, α = {data['alpha']}; at least {MIN_PAIRED_BAGS} common bags). Estimators scored on
different bags rank on different evidence: the common bags are given.</p>
<table><tr><th>rank</th><th>estimator</th><th>median RMS</th><th>against the next</th></tr>{ranking}</table>
<h2>Per motor class and speed band</h2><p>Median RMS (bags) per estimator.</p>
{_class_html('pole pairs', data['by_pole_pairs'], names)}
{_class_html('HF saliency L_qh/L_dh (the replay commissioning)', data['by_saliency'], names)}
{_class_html('speed per rated speed in the scored windows', data['by_speed'], names)}
<h2>Not applicable: the reasons counted</h2>{reasons or '<p>none</p>'}
<p>The same data: report.json; one row per bag and estimator: bags.csv.</p>
</body></html>
"""


def _against(test):
    if test["p"] is None:
        return f"not tested: {test['common_bags']} common bags"
    verdict = "differs" if test["differs"] else "does not differ significantly"
    return f"{verdict} from {_escape(test['estimator'])} (p {test['p_holm']:.3g} on {test['common_bags']} bags)"
