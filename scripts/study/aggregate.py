#!/usr/bin/env python3
"""Turns the runs of scripts/paper-study.sh into tables and gnuplot plots.

Usage: aggregate.py STUDY_DIR RESULTS_DIR

Reads STUDY_DIR/runs/<name>.log (the tracer's summary: training and render seconds, MAPE,
relMSE) and <name>.csv (MAPE every 50 iterations at 4 spp), where <name> is
<scene>-<variant>-s<seed> as paper-study.sh writes them. Writes RESULTS_DIR/tables.md and
the plots RESULTS_DIR/*.png; the gnuplot scripts and their data stay in STUDY_DIR/plots/.
Standard library only.
"""
import math
import os
import re
import statistics
import subprocess
import sys

SCENES = ["cornell-box", "veach-ajar", "statue"]
PRIORS = ["uniform-direction", "uniform-angle", "cosine"]
EPSILONS = ["0.001", "0.01", "0.1", "0.25"]  # 0.01 is the library's default
UNGUIDED_SPP = [8, 32, 128, 512]
COLORS = {"uniform-direction": "#1f77b4", "uniform-angle": "#2ca02c", "cosine": "#d62728",
          "bsdf": "#9467bd", "unguided": "#000000"}
# The study's image sizes (paper-study.sh), for the crops.
IMAGE_SIZES = {"cornell-box": (256, 256), "veach-ajar": (256, 144), "statue": (256, 256)}
# Crops for the side-by-side images, in pixels from the top-left corner: x, y, w, h.
CROPS = {"cornell-box": (8, 150, 96, 96), "veach-ajar": (64, 70, 128, 64),
         "statue": (64, 0, 128, 128)}


def parse_log(path):
    """The figures the tracer prints at the end of a run (None where absent)."""
    run = {"train_s": 0.0, "render_s": None, "mape": None, "relmse": None}
    with open(path) as f:
        for line in f:
            m = re.match(r"trained\s+\d+ samples .* in ([\d.]+) s", line)
            if m:
                run["train_s"] = float(m.group(1))
            m = re.match(r"rendered\s+\d+ spp in ([\d.]+) s", line)
            if m:
                run["render_s"] = float(m.group(1))
            m = re.match(r"error\s+MAPE ([\d.]+), relMSE ([\d.]+)", line)
            if m:
                run["mape"], run["relmse"] = float(m.group(1)), float(m.group(2))
    return run


def parse_csv(path):
    """{iteration: mape} of the evaluation renders."""
    curve = {}
    if os.path.exists(path):
        with open(path) as f:
            next(f)
            for line in f:
                it, _, _, mape = line.strip().split(",")
                if mape:
                    curve[int(it)] = float(mape)
    return curve


def load_runs(runs_dir):
    """{(scene, variant): {seed: run}} for every complete run."""
    groups = {}
    for fn in sorted(os.listdir(runs_dir)):
        if not fn.endswith(".log"):
            continue
        name = fn[:-4]
        m = re.match(r"(cornell-box|veach-ajar|statue)-(.+)-s(\d+)$", name)
        if not m:
            continue
        run = parse_log(os.path.join(runs_dir, fn))
        if run["mape"] is None:
            continue
        run["curve"] = parse_csv(os.path.join(runs_dir, name + ".csv"))
        run["png"] = os.path.join(runs_dir, name + ".png")
        groups.setdefault((m.group(1), m.group(2)), {})[int(m.group(3))] = run
    return groups


def stats(values):
    """mean, sample standard deviation, min, max, n."""
    n = len(values)
    if n == 0:
        return None
    sd = statistics.stdev(values) if n > 1 else 0.0
    return statistics.fmean(values), sd, min(values), max(values), n


SEED_COUNT = 3


def fmt(values, digits=4):
    """mean ± standard deviation over the seeds; the count only when a seed is missing."""
    s = stats(values)
    if s is None:
        return "n/a"
    mean, sd, _, _, n = s
    return f"{mean:.{digits}f} ± {sd:.{digits}f}" + ("" if n == SEED_COUNT else f" (n={n})")


def mapes(groups, scene, variant):
    return [r["mape"] for r in groups.get((scene, variant), {}).values()]


def variant_of(prior, eps):
    return prior if eps == "0.01" else f"{prior}-eps{eps}"


def curve_stats(groups, scene, variant):
    """[(iteration, mean, min, max, n)] over the seeds that have the iteration."""
    runs = groups.get((scene, variant), {}).values()
    its = sorted({it for r in runs for it in r["curve"]})
    rows = []
    for it in its:
        vals = [r["curve"][it] for r in runs if it in r["curve"]]
        rows.append((it, statistics.fmean(vals), min(vals), max(vals), len(vals)))
    return rows


def write_dat(path, rows):
    with open(path, "w") as f:
        for row in rows:
            f.write(" ".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in row) + "\n")


def welch_t(a, b):
    """Welch's t statistic of mean(a) - mean(b); None with fewer than 2 values each."""
    if len(a) < 2 or len(b) < 2:
        return None
    va, vb = statistics.variance(a) / len(a), statistics.variance(b) / len(b)
    if va + vb == 0:
        return None
    return (statistics.fmean(a) - statistics.fmean(b)) / math.sqrt(va + vb)


def diff_cell(a, b, digits=4):
    """mean(a) - mean(b) with Welch's t, for a table cell."""
    t = welch_t(a, b)
    if t is None:
        return "n/a"
    return f"{statistics.fmean(a) - statistics.fmean(b):+.{digits}f} (t = {t:+.1f})"


def curve_values(groups, scene, variant, it):
    return [r["curve"][it] for r in groups.get((scene, variant), {}).values() if it in r["curve"]]


def loglog_interpolate(points, x):
    """(MAPE of the unguided curve at time x, extrapolated?), log MAPE linear in log time.

    Beyond the last point the last segment is extended, at most to 4 times its time (MAPE
    of unguided path tracing falls like a power of the time, close to 1/2); None outside.
    """
    points = sorted(points)
    if len(points) < 2 or x < points[0][0] or x > 4.0 * points[-1][0]:
        return None
    segments = list(zip(points, points[1:]))
    for (x0, y0), (x1, y1) in segments:
        if x <= x1 or (x0, y0) == segments[-1][0]:
            t = (math.log(x) - math.log(x0)) / (math.log(x1) - math.log(x0))
            return math.exp(math.log(y0) + t * (math.log(y1) - math.log(y0))), x > x1
    return None


class Plots:
    """Collects gnuplot scripts and runs them."""

    def __init__(self, plot_dir, results_dir):
        self.plot_dir, self.results_dir = plot_dir, results_dir
        self.scripts = []
        os.makedirs(plot_dir, exist_ok=True)

    def dat(self, name, rows):
        path = os.path.abspath(os.path.join(self.plot_dir, name + ".dat"))
        write_dat(path, rows)
        return path

    def add(self, name, body, size="900,330"):
        out = os.path.abspath(os.path.join(self.results_dir, name + ".png"))
        script = (f"set terminal pngcairo size {size} font 'Sans,10'\n"
                  f"set output '{out}'\n" + body)
        path = os.path.join(self.plot_dir, name + ".gp")
        with open(path, "w") as f:
            f.write(script)
        self.scripts.append(path)

    def run(self):
        for path in self.scripts:
            subprocess.run(["gnuplot", path], check=True)


def convergence_panel(plots, groups, scene, series, title):
    """gnuplot commands for one panel: series is [(variant, label, color, dash)]."""
    parts = []
    for variant, label, color, dash in series:
        rows = curve_stats(groups, scene, variant)
        if not rows:
            continue
        dat = plots.dat(f"curve-{scene}-{variant}", rows)
        parts.append(f"'{dat}' using 1:3:4 with filledcurves fc rgb '{color}' "
                     f"fs transparent solid 0.15 noborder notitle")
        parts.append(f"'{dat}' using 1:2 with lines lw 2 dt {dash} lc rgb '{color}' "
                     f"title '{label}'")
    return (f"set title '{title}'\nset xlabel 'training iteration'\n"
            f"set ylabel 'MAPE (4 spp)'\nset key top right\nset grid\n"
            f"plot {', '.join(parts)}\n") if parts else ""


def crops_plot(plots, name, panels, crop, image_size, size):
    """Side-by-side crops of tracer PNG previews; panels is [(png, title)]."""
    x, y, w, h = crop
    _, height = image_size
    body = ["unset border", "unset tics", "unset key", "set size ratio -1",
            f"set multiplot layout 1,{len(panels)} margins 0.01,0.99,0.02,0.88 spacing 0.01"]
    for png, title in panels:
        # gnuplot puts the image's bottom row at y = 0.
        body.append(f"set title \"{title}\" noenhanced")
        body.append(f"plot [{x}:{x + w}][{height - y - h}:{height - y}] '{os.path.abspath(png)}' "
                    f"binary filetype=png with rgbimage")
    body.append("unset multiplot")
    plots.add(name, "\n".join(body) + "\n", size)


def main():
    study_dir, results_dir = sys.argv[1], sys.argv[2]
    runs_dir = os.path.join(study_dir, "runs")
    os.makedirs(results_dir, exist_ok=True)
    groups = load_runs(runs_dir)
    plots = Plots(os.path.join(study_dir, "plots"), results_dir)
    md = ["# Study tables", "",
          "Generated by `scripts/paper-study.sh` (`scripts/study/aggregate.py`) from the runs "
          "in `out/study/runs/`; do not edit. Every cell is the mean ± the sample standard "
          "deviation over seeds 1, 2 and 3 (a cell says n when a seed is missing). MAPE is against the Tungsten references "
          "(cornell-box, veach-ajar, box-downsampled to 256 pixels wide) and against a "
          "4096-spp unguided render (statue). See `docs/results.md` for the discussion.", ""]

    # ---- Figure 1: equal samples ---------------------------------------------------------
    md += ["## Equal samples: MAPE at 32 spp after training (Figure 1)", "",
           "Training: cornell-box and veach-ajar 500 iterations, statue 2000, of 4096 paths.",
           "", "| scene | unguided | " + " | ".join(PRIORS) + " | bsdf |",
           "|---|" + "---|" * (len(PRIORS) + 2)]
    for scene in SCENES:
        cells = [fmt(mapes(groups, scene, "unguided-spp32"))]
        cells += [fmt(mapes(groups, scene, p)) for p in PRIORS]
        cells.append(fmt(mapes(groups, scene, "bsdf")) if scene == "veach-ajar" else "–")
        md.append(f"| {scene} | " + " | ".join(cells) + " |")
    md += ["", "Welch's t of the difference of means (|t| > 4.3 is significant at 5% with 2 "
           "degrees of freedom, the fewest three seeds against three can have):", "",
           "| scene | cosine − uniform-direction | cosine − uniform-angle | cosine − unguided |",
           "|---|---|---|---|"]
    for scene in SCENES:
        cos = mapes(groups, scene, "cosine")
        cells = [diff_cell(cos, mapes(groups, scene, other))
                 for other in ["uniform-direction", "uniform-angle", "unguided-spp32"]]
        md.append(f"| {scene} | " + " | ".join(cells) + " |")
    md.append("")
    for scene in SCENES:
        panels = []
        ref = os.path.join(study_dir, "statue-reference.png")
        if scene == "statue" and os.path.exists(ref):
            panels.append((ref, "reference"))
        for variant, label in [("unguided-spp32", "unguided")] + [(p, p) for p in PRIORS] + \
                ([("bsdf", "bsdf")] if scene == "veach-ajar" else []):
            run = groups.get((scene, variant), {}).get(1)
            if run and os.path.exists(run["png"]):
                panels.append((run["png"], f"{label}\\nMAPE {run['mape']:.3f}"))
        if panels:
            w, h = CROPS[scene][2], CROPS[scene][3]
            cell = 190
            crops_plot(plots, f"crops-{scene}", panels, CROPS[scene], IMAGE_SIZES[scene],
                       f"{cell * len(panels)},{int(cell * h / w) + 50}")

    # ---- Figure 2: convergence -------------------------------------------------------------
    md += ["## Convergence during training (Figure 2)", "",
           "MAPE of a 4-spp render with the current model, at iteration 0 (the untrained flow, "
           "that is, the prior), 50, 200 and at the end of training.", "",
           "| scene | prior | iteration 0 | 50 | 200 | end |", "|---|---|---|---|---|---|"]
    for scene in SCENES:
        for prior in PRIORS + (["bsdf"] if scene == "veach-ajar" else []):
            rows = {r[0]: r for r in curve_stats(groups, scene, prior)}
            if not rows:
                continue
            last = max(rows)

            def at(it):
                runs = groups[(scene, prior)].values()
                return fmt([r["curve"][it] for r in runs if it in r["curve"]], 3)
            md.append(f"| {scene} | {prior} | {at(0)} | {at(50)} | {at(200)} | "
                      f"{at(last)} ({last}) |")
    md += ["", "Cosine minus uniform-direction, MAPE at 4 spp, with Welch's t:", "",
           "| scene | iteration 0 | 50 | 200 | 500 | 1000 | 2000 |", "|---|---|---|---|---|---|---|"]
    for scene in SCENES:
        cells = []
        for it in [0, 50, 200, 500, 1000, 2000]:
            a = curve_values(groups, scene, "cosine", it)
            b = curve_values(groups, scene, "uniform-direction", it)
            cells.append(diff_cell(a, b, 3) if a and b else "–")
        md.append(f"| {scene} | " + " | ".join(cells) + " |")
    md.append("")
    series = [(p, p, COLORS[p], 1) for p in PRIORS]
    for scene in SCENES:
        s = series + ([("bsdf", "bsdf", COLORS["bsdf"], 1)] if scene == "veach-ajar" else [])
        body = convergence_panel(plots, groups, scene, s,
                                 f"{scene}: MAPE during training (mean and range of 3 seeds)")
        if body:
            plots.add(f"convergence-{scene}", body, "720,420")

    # ---- Figure 3: early vs late -------------------------------------------------------------
    md += ["## Early vs late training on the statue (Figure 3)", "",
           "MAPE at 32 spp after 500 and 2000 iterations.", "",
           "| prior | 500 iterations | 2000 iterations |", "|---|---|---|"]
    for prior in ["uniform-direction", "cosine"]:
        md.append(f"| {prior} | {fmt(mapes(groups, 'statue', prior + '-i500'))} | "
                  f"{fmt(mapes(groups, 'statue', prior))} |")
    md.append("| cosine − uniform-direction (Welch's t) | " +
              diff_cell(mapes(groups, "statue", "cosine-i500"),
                        mapes(groups, "statue", "uniform-direction-i500")) + " | " +
              diff_cell(mapes(groups, "statue", "cosine"),
                        mapes(groups, "statue", "uniform-direction")) + " |")
    md.append("")
    panels = []
    for variant, label in [("uniform-direction-i500", "uniform-direction, 500"),
                           ("cosine-i500", "cosine, 500"),
                           ("uniform-direction", "uniform-direction, 2000"),
                           ("cosine", "cosine, 2000")]:
        run = groups.get(("statue", variant), {}).get(1)
        if run and os.path.exists(run["png"]):
            panels.append((run["png"], f"{label}\\nMAPE {run['mape']:.3f}"))
    if panels:
        crops_plot(plots, "statue-early-late", panels, CROPS["statue"], IMAGE_SIZES["statue"],
                   f"{200 * len(panels)},260")

    # ---- Figure 4: model size -----------------------------------------------------------------
    md += ["## Model size on the statue (Figure 4)", "",
           "| prior | model | MAPE at 32 spp after 2000 iterations | training seconds (1 thread) |",
           "|---|---|---|---|"]
    for prior in ["uniform-direction", "cosine"]:
        for model, variant in [("small", prior), ("large", prior + "-large")]:
            runs = groups.get(("statue", variant), {}).values()
            md.append(f"| {prior} | {model} | {fmt(mapes(groups, 'statue', variant))} | "
                      f"{fmt([r['train_s'] for r in runs], 1)} |")
        md.append(f"| {prior} | large − small (Welch's t) | " +
                  diff_cell(mapes(groups, "statue", prior + "-large"),
                            mapes(groups, "statue", prior)) + " | |")
    md.append("")
    body = convergence_panel(
        plots, groups, "statue",
        [("uniform-direction", "uniform-direction, small", COLORS["uniform-direction"], 1),
         ("uniform-direction-large", "uniform-direction, large", COLORS["uniform-direction"], 2),
         ("cosine", "cosine, small", COLORS["cosine"], 1),
         ("cosine-large", "cosine, large", COLORS["cosine"], 2)],
        "statue: small vs large model (mean and range of 3 seeds)")
    if body:
        plots.add("model-size-statue", body, "720,420")

    # ---- Equal time ------------------------------------------------------------------------------
    md += ["## Equal time against unguided path tracing", "",
           "Time is one thread's: guided = training iterations (tracing and `nf_train_step`) "
           "+ the 32-spp render; unguided = its render. Evaluation renders and scene loading "
           "are left out of both. The unguided MAPE at the guided run's time is interpolated "
           "(log MAPE linear in log time) between the unguided runs at 8, 32, 128 and 512 "
           "spp, or extrapolated along the last segment up to 4 times its time.", "",
           "| scene | method | seconds | MAPE | unguided MAPE at that time |",
           "|---|---|---|---|---|"]
    body = ["set logscale xy", "set grid", "set xlabel 'seconds (one thread)'",
            "set ylabel 'MAPE'", "set key top right",
            "set multiplot layout 1,3"]
    for scene in SCENES:
        curve = []
        for spp in UNGUIDED_SPP:
            runs = groups.get((scene, f"unguided-spp{spp}"), {}).values()
            if runs:
                t = statistics.fmean(r["render_s"] for r in runs)
                m = [r["mape"] for r in runs]
                curve.append((t, statistics.fmean(m), min(m), max(m)))
                md.append(f"| {scene} | unguided {spp} spp | {t:.1f} | {fmt(m)} | |")
        pts = [(c[0], c[1]) for c in curve]
        parts = []
        if curve:
            dat = plots.dat(f"equal-time-{scene}-unguided", curve)
            parts.append(f"'{dat}' using 1:2:3:4 with yerrorlines lw 2 lc rgb 'black' "
                         f"title 'unguided (8-512 spp)'")
        for prior in PRIORS + (["bsdf"] if scene == "veach-ajar" else []):
            runs = list(groups.get((scene, prior), {}).values())
            if not runs:
                continue
            times = [r["train_s"] + r["render_s"] for r in runs]
            m = [r["mape"] for r in runs]
            t = statistics.fmean(times)
            ref = loglog_interpolate(pts, t) if pts else None
            if ref is None:
                at_time = "outside the unguided runs"
            else:
                at_time = f"{ref[0]:.4f}" + (" (extrapolated)" if ref[1] else "")
            md.append(f"| {scene} | {prior} (train + 32 spp) | {fmt(times, 1)} | {fmt(m)} | "
                      f"{at_time} |")
            dat = plots.dat(f"equal-time-{scene}-{prior}",
                            [(t, statistics.fmean(m), min(m), max(m))])
            parts.append(f"'{dat}' using 1:2:3:4 with yerrorbars pt 7 ps 1.2 "
                         f"lc rgb '{COLORS[prior]}' title '{prior}'")
        if parts:
            body += [f"set title '{scene}'", "plot " + ", ".join(parts)]
    md.append("")
    body.append("unset multiplot")
    plots.add("equal-time", "\n".join(body) + "\n", "1200,400")

    # ---- The cosine prior's epsilon ----------------------------------------------------------
    md += ["## The cosine prior's defensive mixture weight `prior_epsilon`", "",
           "Cosine prior, MAPE at 32 spp after training (0.01 is the library's default); "
           "uniform-direction for comparison.", "",
           "| scene | " + " | ".join(f"ε = {e}" for e in EPSILONS) + " | uniform-direction |",
           "|---|" + "---|" * (len(EPSILONS) + 1)]
    for scene in SCENES:
        cells = [fmt(mapes(groups, scene, variant_of("cosine", e))) for e in EPSILONS]
        cells.append(fmt(mapes(groups, scene, "uniform-direction")))
        md.append(f"| {scene} | " + " | ".join(cells) + " |")
    md += ["", "ε minus the default 0.01, MAPE at 32 spp, with Welch's t:", "",
           "| scene | " + " | ".join(f"ε = {e}" for e in EPSILONS if e != "0.01") + " |",
           "|---|" + "---|" * (len(EPSILONS) - 1)]
    for scene in SCENES:
        base = mapes(groups, scene, "cosine")
        md.append(f"| {scene} | " + " | ".join(
            diff_cell(mapes(groups, scene, variant_of("cosine", e)), base)
            for e in EPSILONS if e != "0.01") + " |")
    md += ["", "MAPE at 4 spp during training, cosine prior by ε:", "",
           "| scene | ε | iteration 0 | 50 | 200 | end |", "|---|---|---|---|---|---|"]
    for scene in SCENES:
        for e in EPSILONS + ["uniform-direction"]:
            variant = "uniform-direction" if e == "uniform-direction" else variant_of("cosine", e)
            runs = groups.get((scene, variant), {}).values()
            if not runs:
                continue
            last = max(max(r["curve"]) for r in runs)

            def at(it):
                return fmt([r["curve"][it] for r in runs if it in r["curve"]], 3)
            label = e if e != "uniform-direction" else "uniform-direction prior"
            md.append(f"| {scene} | {label} | {at(0)} | {at(50)} | {at(200)} | "
                      f"{at(last)} ({last}) |")
    md.append("")
    eps_colors = {"0.001": "#ff7f0e", "0.01": "#d62728", "0.1": "#8c564b", "0.25": "#e377c2"}
    body = ["set multiplot layout 1,3"]
    for scene in SCENES:
        s = [(variant_of("cosine", e), f"cosine, ε = {e}", eps_colors[e], 1) for e in EPSILONS]
        s.append(("uniform-direction", "uniform-direction", COLORS["uniform-direction"], 2))
        panel = convergence_panel(plots, groups, scene, s, scene)
        if panel:
            body.append(panel)
    body.append("unset multiplot")
    plots.add("epsilon", "\n".join(body) + "\n", "1400,440")

    with open(os.path.join(results_dir, "tables.md"), "w") as f:
        f.write("\n".join(md) + "\n")
    plots.run()


if __name__ == "__main__":
    main()
