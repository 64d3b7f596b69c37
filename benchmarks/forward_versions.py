"""The forward march of this checkout against another, side by side: each version's own
``benchmarks/forward.py`` run from a copy of its tree laid out as its wheel installs it, the versions
alternating round by round, so that the machine's drift falls on both alike.

Prints, per version and round, the ``mi_nest.render`` ray-steps/s that ``forward.py`` reports (its best of
``--repeats``), then the best of the rounds per version and their ratio, and each round's own ratio with
their median. Extra arguments go to
``forward.py`` (both versions must accept them).

    git worktree add /tmp/before 04d869c
    python benchmarks/forward_versions.py --baseline /tmp/before -- --field grid
"""
from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from reconstruction import cpu_name, installed_layout

HERE = Path(__file__).resolve().parents[1]
THROUGHPUT = re.compile(r"^Dr\.Jit mi_nest\s+.*?(\d\.\d+e[+-]\d+)\s+\S+x\s*$", re.MULTILINE)


def throughput(tree: Path, path_entry: Path, arguments: list[str]) -> float:
    """``mi_nest.render``'s ray-steps/s from ``tree``'s ``forward.py`` run on the copy at ``path_entry``."""
    script = tree / "benchmarks" / "forward.py"
    env = {**os.environ, "PYTHONPATH": f"{path_entry}{os.pathsep}{tree / 'benchmarks'}"}
    check = "import mi_nest, sys; sys.exit(0 if mi_nest.__file__.startswith(sys.argv[1]) else 1)"
    if subprocess.run([sys.executable, "-c", check, str(path_entry)], env=env, cwd=path_entry).returncode:
        raise SystemExit(f"the copy in {path_entry} is not the mi_nest that Python imports there")
    done = subprocess.run([sys.executable, str(script), *arguments], env=env, cwd=path_entry, capture_output=True,
                          text=True)
    if done.returncode != 0:
        raise SystemExit(f"forward.py of {tree} failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
    found = THROUGHPUT.search(done.stdout)
    if found is None:
        raise SystemExit(f"no 'Dr.Jit mi_nest' line in the output of {script}:\n{done.stdout[-2000:]}")
    return float(found.group(1))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", type=Path, required=True, help="another mi_nest checkout (a git worktree)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating runs of each version")
    parser.add_argument("forward_arguments", nargs="*", help="after --: arguments of forward.py")
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    if not (args.baseline / "benchmarks" / "forward.py").is_file():
        parser.error(f"{args.baseline} has no benchmarks/forward.py")
    print(f"{cpu_name()}; forward.py {' '.join(args.forward_arguments)}, {args.rounds} alternating rounds", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"this checkout": HERE, "baseline": args.baseline.resolve()}
        layouts = {name: installed_layout(tree, Path(tmp) / name.replace(" ", "_")) for name, tree in trees.items()}
        values = {name: [] for name in trees}
        for round_index in range(args.rounds):
            for name, tree in trees.items():
                values[name].append(throughput(tree, layouts[name], args.forward_arguments))
                print(f"  round {round_index + 1}: {name:14s} {values[name][-1]:.3e} ray-steps/s", flush=True)
    best = {name: max(v) for name, v in values.items()}
    # The machine's speed can change by a third between rounds: a round's own ratio is the steadier figure.
    ratios = [mine / theirs for mine, theirs in zip(values["this checkout"], values["baseline"])]
    print(f"best: this checkout {best['this checkout']:.3e}, baseline {best['baseline']:.3e} ray-steps/s; "
          f"this checkout / baseline {best['this checkout'] / best['baseline']:.2f}x")
    print(f"per round: {', '.join(f'{r:.2f}x' for r in ratios)}; median {statistics.median(ratios):.2f}x")


if __name__ == "__main__":
    main()
