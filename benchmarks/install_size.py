"""What `pip install sinshape` weighs: the wheel, and the installed runtime
(no extras) package by package, for this checkout and another commit, side
by side in one run.

    python benchmarks/install_size.py [--before GIT_REF] [--now GIT_REF] [--extras prep,train]

Each side is a commit (`now`: HEAD), taken with `git archive` so that nothing
untracked or stale (an old build/ folder) slips in, built into a wheel
(`pip wheel --no-deps`) and installed into a fresh venv; sizes are what the files take on disk (`du`), without pip and
setuptools, which every venv has. Needs the network or a pip cache for the
dependencies, like any install.
"""

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENV_OWN = {"pip", "setuptools", "pkg_resources", "_distutils_hack", "distutils-precedence.pth"}
DISTRIBUTION = {"pil": "pillow"}  # import names that are not their distribution's


def disk_bytes(path: Path) -> int:
    return int(subprocess.run(["du", "-sb", str(path)], capture_output=True, text=True, check=True).stdout.split()[0])


def measure(source: Path, work: Path, extras: str) -> dict:
    """Wheel size, and installed bytes by top-level entry of site-packages."""
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(work), str(source)], check=True)
    wheel = next(work.glob("sinshape-*.whl"))
    subprocess.run([sys.executable, "-m", "venv", str(work / "venv")], check=True)
    target = f"{wheel}[{extras}]" if extras else str(wheel)
    subprocess.run([str(work / "venv" / "bin" / "pip"), "install", "-q", target], check=True)
    site = next((work / "venv" / "lib").glob("python*/site-packages"))
    entries = {}
    for entry in site.iterdir():
        name = entry.name.split("-")[0] if entry.name.endswith((".dist-info", ".libs")) else entry.name
        if name.endswith(".libs"):
            name = name[:-5]
        name = DISTRIBUTION.get(name.lower(), name.lower())
        if name not in VENV_OWN and not name.startswith("__"):
            entries[name] = entries.get(name, 0) + disk_bytes(entry)
    return {"wheel": wheel.stat().st_size, "installed": entries}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", default=None, help="a git commit to compare with (default: none)")
    parser.add_argument("--now", default="HEAD", help="the git commit to measure (default: HEAD)")
    parser.add_argument("--extras", default="", help="extras to install on both sides, e.g. prep")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sides = {"before": args.before, "now": args.now} if args.before else {"now": args.now}
        for side, ref in sides.items():
            (tmp / f"{side}-src").mkdir()
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], capture_output=True, check=True)
            subprocess.run(["tar", "-x", "-C", str(tmp / f"{side}-src")], input=archive.stdout, check=True)
        results = {}
        for side in sides:
            (tmp / side).mkdir()
            results[side] = measure(tmp / f"{side}-src", tmp / side, args.extras)
    mb = 1e6
    print(f"extras: {args.extras or 'none'}")
    print(f"{'':24}" + "".join(f"{side:>12}" for side in results))
    print(f"{'wheel (MB)':24}" + "".join(f"{r['wheel'] / mb:12.1f}" for r in results.values()))
    print(f"{'installed, all (MB)':24}" + "".join(f"{sum(r['installed'].values()) / mb:12.1f}" for r in results.values()))
    names = sorted({n for r in results.values() for n in r["installed"]},
                   key=lambda n: -max(r["installed"].get(n, 0) for r in results.values()))
    for name in names:
        sizes = [r["installed"].get(name, 0) / mb for r in results.values()]
        if max(sizes) >= 1:
            print(f"  {name:22}" + "".join(f"{s:12.1f}" if s else f"{'-':>12}" for s in sizes))


if __name__ == "__main__":
    main()
