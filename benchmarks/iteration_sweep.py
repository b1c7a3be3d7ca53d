"""Quality and training time against the iteration budget, for one shape.

    pip install '.[train,docs]'
    python benchmarks/iteration_sweep.py INPUT [--iters 100 250 500 1000] [--res 64] [--samples 100]
                                         [--work DIR] [--plot docs/iterations.png] [--json OUT]

Trains INPUT once per budget (iterations per level; a model already in
--work, named STEM_ITERS.onnx, is reused), scores 100 samples of each with
`sinrun eval`, and plots LP-IoU, LP-F and diversity with the training time,
so users can pick a budget.
"""

import argparse
import json
import subprocess
import sys
from pathlib import Path

SINRUN = str(Path(sys.executable).with_name("sinrun"))


def plot(rows: list, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")  # headless
    import matplotlib.pyplot as plt

    iters = [r["iters"] for r in rows]
    figure, quality = plt.subplots(figsize=(7, 4), dpi=120)
    for key, label, style in (("lp_iou", "LP-IoU", "o-"), ("lp_f", "LP-F", "s-"), ("diversity", "diversity", "^-")):
        quality.plot(iters, [r[key] for r in rows], style, label=label)
    quality.set_xlabel("training iterations per level")
    quality.set_ylabel("score (100 samples)")
    quality.set_ylim(0, 1)
    quality.set_xscale("log")
    quality.set_xticks(iters, [str(i) for i in iters])
    minutes = quality.twinx()
    minutes.plot(iters, [r["train_minutes"] for r in rows], "k--", label="training time")
    minutes.set_ylabel("training time (minutes, 2-core CPU)")
    minutes.set_ylim(bottom=0)
    lines = quality.get_legend_handles_labels()[0] + minutes.get_legend_handles_labels()[0]
    labels = quality.get_legend_handles_labels()[1] + minutes.get_legend_handles_labels()[1]
    quality.legend(lines, labels, loc="center right", fontsize=8)
    quality.set_title(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", type=Path)
    parser.add_argument("--iters", type=int, nargs="+", default=[100, 250, 500, 1000])
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--work", type=Path, default=Path("sweep"))
    parser.add_argument("--plot", type=Path, default=Path("docs/iterations.png"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    args.work.mkdir(parents=True, exist_ok=True)
    rows = []
    print("| iterations per level | training min | LP-IoU | LP-F | diversity |")
    print("|---|---|---|---|---|")
    for iters in args.iters:
        model = args.work / f"{args.input.stem}_{iters}.onnx"
        if not model.exists():
            subprocess.run([SINRUN, "train", str(args.input), "-o", str(model), "--res", str(args.res),
                            "--iters", str(iters), "--quiet"], check=True)
        report = args.work / f"{model.stem}_eval.json"
        subprocess.run([SINRUN, "eval", str(model), "--reference", str(args.input), "-n", str(args.samples),
                        "--json", str(report)], check=True, capture_output=True)
        scores = json.loads(report.read_text())
        seconds = json.loads(subprocess.run(
            [sys.executable, "-c", "import json,sys; from sinshape.runtime import load; "
             "print(json.dumps(load.load_model(sys.argv[1]).manifest.raw['training']))", str(model)],
            check=True, capture_output=True, text=True).stdout)["seconds"]
        row = {"iters": iters, "train_minutes": seconds / 60, **{k: scores[k] for k in ("lp_iou", "lp_f", "diversity")}}
        rows.append(row)
        print(f"| {iters} | {row['train_minutes']:.1f} | {row['lp_iou']:.3f} | {row['lp_f']:.3f} | "
              f"{row['diversity']:.3f} |", flush=True)
    plot(rows, args.plot, f"{args.input.name}, res {args.res}: quality and training time by budget")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
