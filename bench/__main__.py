"""Run every benchmark in bench/ (``make bench``); each script updates its BENCHMARKS.md section."""
import runpy
import sys
from pathlib import Path

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))  # the scripts import benchutil

if __name__ == "__main__":
    scripts = sorted(HERE.glob("bench_*.py"))
    only = sys.argv[1:]
    for path in scripts:
        if only and not any(o in path.stem for o in only):
            continue
        print(f"== {path.name}", flush=True)
        runpy.run_path(str(path), run_name="__main__")
