"""Issue 25's before/after per case: every recording of the given MuJoCo sets replayed by two pegs
builds, summed up per kind of model error, written into the README.

    VENV/bin/python cases.py --sets DIR [DIR ...] --pegs NEW --baseline OLD [--readme README.md] [--reuse]

Each recording (a folder with `bag`, `config.yaml`, `truth.json`, as `generate.py --kind
model_errors` writes it) is replayed with its own config by each build into `out_after` and
`out_before` (--reuse keeps a replay already there). Per case: mean error (mm, over its objects),
objects under 5 mm mean, objects with p95 of 10 mm or more, median final error, and the tracker's
events (relocated, lost, off the table) after. Writes the README section `mujoco-cases`.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import table  # noqa: E402

PEAK_MM = 10.0  # issue 25's bar for the p95 (table.GOOD_MM for the mean)
ORDER = ["control_still", "control_pushed", "hand", "slippery", "sticky", "tether", "heavy5"]


def replay(pegs: str, folder: Path, out: Path, reuse: bool) -> dict:
    if not (reuse and (out / "metrics.json").is_file()):
        result = subprocess.run([pegs, "replay", str(folder / "bag"), "--config", str(folder / "config.yaml"),
                                 "--out", str(out)], capture_output=True, text=True)
        if result.returncode != 0:
            sys.exit(f"{folder}: replay failed: {result.stderr.strip()[-300:]}")
    return json.loads((out / "metrics.json").read_text())


def cell(errors: list[dict]) -> str:
    return (f"{statistics.mean(e['mean_mm'] for e in errors):.1f} | {sum(e['mean_mm'] < table.GOOD_MM for e in errors)} | "
            f"{sum(e['p95_mm'] >= PEAK_MM for e in errors)} | {statistics.median(e['final_mm'] for e in errors):.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=Path, nargs="+", required=True)
    ap.add_argument("--pegs", required=True)
    ap.add_argument("--baseline", required=True)
    ap.add_argument("--readme", type=Path)
    ap.add_argument("--reuse", action="store_true", help="keep replays already in out_after / out_before")
    a = ap.parse_args()
    before, after, events = {}, {}, Counter()
    for folder in sorted(f for s in a.sets for f in s.iterdir() if (f / "truth.json").is_file()):
        kind = json.loads((folder / "truth.json").read_text())["kind"]
        new = replay(a.pegs, folder, folder / "out_after", a.reuse)
        old = replay(a.baseline, folder, folder / "out_before", a.reuse)
        for obj, e in new.get("tracking_error", {}).items():
            after[(kind, folder.name, obj)] = e
            before[(kind, folder.name, obj)] = old["tracking_error"][obj]
        events[kind] += len(new.get("track_events", []))
    kinds = [k for k in ORDER if any(key[0] == k for key in after)]
    kinds += sorted({key[0] for key in after} - set(kinds))
    lines = ["| case | objects | before: mean | under 5 | p95 >= 10 | final | after: mean | under 5 | p95 >= 10 "
             "| final | events after |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for k in kinds + ["all"]:
        keys = [key for key in after if k in ("all", key[0])]
        n = sum(events.values()) if k == "all" else events[k]
        lines.append(f"| {k} | {len(keys)} | {cell([before[x] for x in keys])} | {cell([after[x] for x in keys])} | {n} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.readme:
        table.write_section(a.readme, "mujoco-cases", text)

if __name__ == "__main__":
    main()
