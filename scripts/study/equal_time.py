#!/usr/bin/env python3
"""Aggregates scripts/equal-time.sh's runs into docs/equal-time.md: the table (mean and spread
over seeds), gnuplot plots of error against wall time, and the ablation. The page's prose is
scripts/study/equal-time.md.in; this fills in its @PLACEHOLDERS@."""
import argparse
import os
import platform
import re
import statistics
import subprocess
import sys

SCENE_SIZE = {"cornell-box": "256 x 256", "veach-ajar": "320 x 180",
              "living-room": "320 x 180", "modern-hall": "256 x 256",
              "veach-bidir": "256 x 256", "statue": "256 x 256"}


COMPARE = "build/examples/nf_compare"


def scene_label(entry):
    """A scene of the study as the tables name it: "veach-ajar 320 x 180"; an entry
    SCENE@WxH is that scene at that size."""
    if "@" in entry:
        scene, size = entry.split("@")
        return f"{scene} {size.replace('x', ' x ')}"
    return f"{entry} {SCENE_SIZE.get(entry, '')}".strip()


def precise_errors(image, reference):
    """MAPE and relMSE from nf_compare (6 decimals; the tracer's log has 4, too few for the
    Cornell box's relMSE of about 3e-4), or None."""
    if not (os.path.exists(image) and os.path.exists(reference) and os.path.exists(COMPARE)):
        return None
    out = subprocess.run([COMPARE, reference, image], capture_output=True, text=True).stdout
    m = re.search(r"^MAPE ([0-9.eE+-]+) relMSE ([0-9.eE+-]+)", out, re.M)
    return (float(m.group(1)), float(m.group(2))) if m else None


def parse_log(path, reference=None):
    """The figures of one nf_tracer --time-budget log, or None if it is incomplete."""
    try:
        text = open(path).read()
    except OSError:
        return None
    r = {}
    m = re.search(r"^error\s+MAPE ([0-9.eE+-]+), relMSE ([0-9.eE+-]+)", text, re.M)
    if not m:
        return None
    r["mape"], r["relmse"] = float(m.group(1)), float(m.group(2))
    if reference:
        precise = precise_errors(path[:-len(".log")] + ".exr", reference)
        if precise:
            r["mape"], r["relmse"] = precise
    m = re.search(r"^budget\s+([0-9.]+) s of ([0-9.]+): (\d+) training passes, (\d+) render "
                  r"passes in ([0-9.]+) s; the training passes weigh ([0-9.]+)", text, re.M)
    if m:
        r["seconds"] = float(m.group(1))
        r["train_passes"], r["render_passes"] = int(m.group(3)), int(m.group(4))
        r["train_weight"] = float(m.group(6))
    m = re.search(r"^paths\s+([0-9.]+) rays and ([0-9.]+) guided vertices per path; a render "
                  r"pass takes ([0-9.]+) CPU s, its relative variance ([0-9.eE+-]+)", text, re.M)
    if m:
        r["guided_vertices"] = float(m.group(2))
        r["pass_cpu"], r["pass_variance"] = float(m.group(3)), float(m.group(4))
    m = re.search(r"^selection\s+guiding off in (\d+)%", text, re.M)
    if m:
        r["off"] = int(m.group(1))
    return r


def mean_sd(values):
    if not values:
        return float("nan"), float("nan")
    return statistics.mean(values), statistics.stdev(values) if len(values) > 1 else 0.0


def fmt(v, digits=3):
    if v != v:
        return "–"
    if v == 0:
        return "0"
    if abs(v) >= 100:
        return f"{v:.0f}"
    return f"{v:.{digits}g}"


def cell(values):
    m, sd = mean_sd(values)
    return f"{fmt(m)} ± {fmt(sd, 2)}" if len(values) > 1 else fmt(m)


def main():
    ap = argparse.ArgumentParser()
    for name in ("out", "page", "plots", "budgets", "seeds", "scenes", "ablation-budget",
                 "guided", "threads", "template"):
        ap.add_argument("--" + name, required=True)
    a = ap.parse_args()
    budgets = [b for b in a.budgets.split()]
    seeds = a.seeds.split()
    scenes = a.scenes.split()
    runs = os.path.join(a.out, "runs")
    refs = {scene: os.path.join(a.out, "references", f"{scene}.exr") for scene in scenes}
    os.makedirs(a.plots, exist_ok=True)

    # ---- The main table and its CSV.
    rows = []
    table = ["| scene | budget | plain PT relMSE | guided relMSE | guided / PT | plain PT MAPE "
             "| guided MAPE | guided / PT | guided: training passes, render passes (PT) |",
             "|---|---|---|---|---|---|---|---|---|"]
    ratios = {}
    for scene in scenes:
        for b in budgets:
            res = {}
            for method in ("pt", "guided"):
                res[method] = [parse_log(os.path.join(runs, f"{scene}-{b}-{s}-{method}.log"),
                                         refs[scene]) for s in seeds]
                res[method] = [r for r in res[method] if r]
                for s, r in zip(seeds, res[method]):
                    rows.append((scene, b, s, method, r["mape"], r["relmse"],
                                 r.get("train_passes", 0), r.get("render_passes", 0)))
            pt, gd = res["pt"], res["guided"]
            if not pt or not gd:
                continue
            rel = [r["relmse"] for r in gd], [r["relmse"] for r in pt]
            mape = [r["mape"] for r in gd], [r["mape"] for r in pt]
            ratio_rel = statistics.mean(rel[0]) / statistics.mean(rel[1])
            ratio_mape = statistics.mean(mape[0]) / statistics.mean(mape[1])
            ratios[(scene, b)] = ratio_rel
            passes = (f"{statistics.mean([r.get('train_passes', 0) for r in gd]):.0f}, "
                      f"{statistics.mean([r.get('render_passes', 0) for r in gd]):.0f} "
                      f"({statistics.mean([r.get('render_passes', 0) for r in pt]):.0f})")
            table.append(f"| {scene_label(scene)} | {b} s | {cell(rel[1])} | "
                         f"{cell(rel[0])} | **{ratio_rel:.2f}** | {cell(mape[1])} | "
                         f"{cell(mape[0])} | {ratio_mape:.2f} | {passes} |")
    with open(os.path.join(a.out, "results.csv"), "w") as f:
        f.write("scene,budget,seed,method,mape,relmse,train_passes,render_passes\n")
        for r in rows:
            f.write(",".join(str(x) for x in r) + "\n")

    # ---- Plots: relMSE and MAPE against the budget, per scene (gnuplot, log-log).
    plot_lines = []
    for scene in scenes:
        dat = os.path.join(a.out, f"{scene}.dat")
        with open(dat, "w") as f:
            for b in budgets:
                line = [b]
                for method in ("pt", "guided"):
                    rs = [parse_log(os.path.join(runs, f"{scene}-{b}-{s}-{method}.log"),
                                    refs[scene]) for s in seeds]
                    rs = [r for r in rs if r]
                    for key in ("relmse", "mape"):
                        v = [r[key] for r in rs] or [float("nan")]
                        line += [statistics.mean(v), min(v), max(v)]
                f.write(" ".join(str(x) for x in line) + "\n")
        png = os.path.join(a.plots, f"{scene.replace('@', '-')}.png")
        gp = f"""set terminal pngcairo size 900,360 font ",10"
set output "{png}"
set multiplot layout 1,2 title "{scene}: error against wall time ({a.threads} threads; mean and range of {len(seeds)} seeds)"
set logscale xy
set xlabel "wall time, training included (s)"
set key top right
set grid
set ylabel "relMSE"
plot "{dat}" using 1:2:3:4 with yerrorlines lw 2 title "plain path tracing", \\
     "{dat}" using 1:8:9:10 with yerrorlines lw 2 title "guided"
set ylabel "MAPE"
plot "{dat}" using 1:5:6:7 with yerrorlines lw 2 title "plain path tracing", \\
     "{dat}" using 1:11:12:13 with yerrorlines lw 2 title "guided"
unset multiplot
"""
        subprocess.run(["gnuplot"], input=gp, text=True, check=True)
        rel = os.path.relpath(png, os.path.dirname(a.page))
        plot_lines.append(f"![{scene}]({rel})")

    # ---- The ablation.
    abl = {}
    order = []
    try:
        for line in open(os.path.join(a.out, "ablation.list")):
            scene, idx, seed, label, opts = line.rstrip("\n").split("\t")
            key = (scene, int(idx))
            if key not in abl:
                abl[key] = {"label": label, "opts": opts, "runs": []}
                order.append(key)
            r = parse_log(os.path.join(runs, f"ablation-{scene}-{idx}-{seed}.log"),
                          os.path.join(a.out, "references", f"{scene}.exr"))
            if r:
                abl[key]["runs"].append(r)
    except OSError:
        pass
    ablation = []
    for scene in dict.fromkeys(k[0] for k in order):
        base = abl.get((scene, 0))
        base_rel = statistics.mean([r["relmse"] for r in base["runs"]]) if base and base["runs"] else float("nan")
        base_mape = statistics.mean([r["mape"] for r in base["runs"]]) if base and base["runs"] else float("nan")
        ablation += [f"**{scene}** {SCENE_SIZE.get(scene, '')}, {a.ablation_budget} s:", "",
                     "| configuration | relMSE | / plain PT | MAPE | / plain PT | render passes "
                     "| CPU s per render pass | relative variance of a pass | guided vertices "
                     "per path |",
                     "|---|---|---|---|---|---|---|---|---|"]
        for key in order:
            if key[0] != scene or not abl[key]["runs"]:
                continue
            rs = abl[key]["runs"]
            rel = [r["relmse"] for r in rs]
            mape = [r["mape"] for r in rs]
            opts = abl[key]["opts"]
            ablation.append(
                f"| {abl[key]['label']}{f' (`{opts}`)' if opts else ''} | {cell(rel)} | "
                f"{statistics.mean(rel) / base_rel:.2f} | {cell(mape)} | "
                f"{statistics.mean(mape) / base_mape:.2f} | "
                f"{statistics.mean([r.get('render_passes', 0) for r in rs]):.0f} | "
                f"{fmt(statistics.mean([r.get('pass_cpu', float('nan')) for r in rs]))} | "
                f"{fmt(statistics.mean([r.get('pass_variance', float('nan')) for r in rs]))} | "
                f"{fmt(statistics.mean([r.get('guided_vertices', float('nan')) for r in rs]))} |")
        ablation.append("")

    # ---- References.
    refs = ["| scene | resolution | reference: unguided render passes | seconds |",
            "|---|---|---|---|"]
    for scene in scenes:
        log = os.path.join(a.out, "references", f"{scene}.log")
        try:
            text = open(log).read()
        except OSError:
            continue
        m = re.search(r"(\d+) render passes", text)
        s = re.search(r"^reference_seconds (\d+)", text, re.M)
        o = re.search(r"^reference_of (\S+)", text, re.M)
        if o:
            refs.append(f"| {scene} | {scene_label(scene)} | {scene_label(o.group(1))}'s, "
                        "box-downsampled | |")
            continue
        refs.append(f"| {scene} | {scene_label(scene)} | {m.group(1) if m else '?'} | "
                    f"{s.group(1) if s else '?'} |")

    cpu = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or "unknown"
    runs_commit = commit
    try:
        runs_commit = open(os.path.join(a.out, "commit")).read().strip() or commit
    except OSError:
        pass
    # The study's compute: every run's and reference's wall time, from their logs.
    total = 0.0
    for d in (runs, os.path.join(a.out, "references")):
        for name in os.listdir(d):
            if name.endswith(".log"):
                m = re.search(r"^total\s+([0-9.]+) s", open(os.path.join(d, name)).read(), re.M)
                total += float(m.group(1)) if m else 0.0
    template = open(a.template).read()
    subs = {
        "@TABLE@": "\n".join(table),
        "@PLOTS@": "\n\n".join(plot_lines),
        "@ABLATION@": "\n".join(ablation),
        "@REFERENCES@": "\n".join(refs),
        "@MACHINE@": f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}",
        "@COMMIT@": commit,
        "@RUNS_COMMIT@": runs_commit,
        "@MINUTES@": str(round(total / 60)),
        "@GUIDED@": " " + a.guided if a.guided else "",
        "@THREADS@": a.threads,
        "@SEEDS@": ", ".join(seeds),
        "@BUDGETS@": ", ".join(budgets),
        "@BUDGETS_WORDS@": " ".join(budgets),
        "@SCENES_WORDS@": " ".join(scenes),
        "@REF_SECONDS@": os.environ.get("NF_EQ_REFERENCE_SECONDS", "240"),
        "@REFERENCES_ROWS@": "\n".join(refs[2:]),
        "@ABLATION_BUDGET@": a.ablation_budget,
    }
    for k, v in subs.items():
        template = template.replace(k, v)
    with open(a.page, "w") as f:
        f.write(template)
    for (scene, b), r in sorted(ratios.items()):
        print(f"{scene} {b} s: guided / plain relMSE {r:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
