"""Issue 25's before/after per case: every recording of the given MuJoCo sets replayed by two pegs
builds, summed up per kind of model error, written into the README.

    VENV/bin/python cases.py --sets DIR [DIR ...] --pegs NEW [--baseline OLD] [--set SECTION.KEY=VALUE ...]
        [--baseline-set SECTION.KEY=VALUE ...] [--labels BEFORE AFTER] [--readme README.md] [--section NAME]
        [--reuse] [--jobs N]

Each recording (a folder with `bag`, `config.yaml`, `truth.json`, as `generate.py --kind
model_errors` writes it) is replayed with its own config by each build into `out_after` and
`out_before` (--reuse keeps a replay already there). `--jobs N` runs N replays at once: a
replay's pose search already uses every core, yet two at once on two cores took 0.68 of the wall
time (six replays, 20 s against 29), and the figures do not depend on it, every replay being
deterministic. `--set` adds a key to the new side's config (`--baseline-set` to the
baseline's), e.g. `--set correct.pose_search_ring=0.004`, for a change that is an option: both
sides may then be one build (--baseline defaults to --pegs), and the replays go to `out_after_` /
`out_before_` plus the settings, beside the config they ran with.
Per case: mean error (mm, over its objects), objects under 5 mm mean, objects with p95 of 10 mm
or more, objects meeting issue 25's bar (both: under 5 mm mean and p95 under 10 mm), median final
error, and the tracker's events (relocated, lost, off the table) after.
Writes the README section `mujoco-cases` (or `--section`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from collections import Counter
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import table  # noqa: E402

PEAK_MM = 10.0  # issue 25's bar for the p95 (table.GOOD_MM for the mean)
ORDER = ["control_still", "control_pushed", "hand", "slippery", "sticky", "tether", "heavy5"]


def sections_of(settings: list[str]) -> dict[str, list[str]]:
    """Each SECTION.KEY=VALUE as `KEY: VALUE` under its section; a malformed one stops the run
    before any replay."""
    sections: dict[str, list[str]] = {}
    for setting in settings:
        key, eq, value = setting.partition("=")
        section, dot, name = key.partition(".")
        if not (eq and dot and section and name and value):
            sys.exit(f"--set {setting!r}: expected SECTION.KEY=VALUE, e.g. correct.pose_search_ring=0.004")
        sections.setdefault(section, []).append(f"{name}: {value}")
    return sections


def with_settings(config: str, sections: dict[str, list[str]]) -> str:
    """`config` (a generated config.yaml: `pegs:` then `ros__parameters:`) with each of `sections`
    added: into the section of that name where the config has it as a block (`    robot:` and its
    keys indented under it), else as a section of its own. A key the config's section has already,
    or a section written inline (`    robot: {...}`), is refused rather than merged by hand."""
    head = "  ros__parameters:\n"
    if head not in config:
        sys.exit("config.yaml has no ros__parameters")
    lines = config.splitlines(keepends=True)
    for section, keys in sections.items():
        block = f"    {section}:\n"
        if block in lines:
            start = lines.index(block) + 1
            end = start
            while end < len(lines) and lines[end].startswith("      "):
                end += 1
            have = {line.strip().split(":", 1)[0] for line in lines[start:end]}
            for key in keys:
                if key.split(":", 1)[0] in have:
                    sys.exit(f"--set {section}.{key.split(':', 1)[0]}: the recording's config sets it "
                             "already; edit its config.yaml instead")
            lines[start:start] = [f"      {key}\n" for key in keys]
        elif any(line.startswith(f"    {section}:") for line in lines):
            sys.exit(f"--set {section}.*: the recording's config writes its {section} section inline; "
                     "edit its config.yaml instead")
        else:
            at = lines.index(head) + 1
            lines[at:at] = [f"    {section}: {{{', '.join(keys)}}}\n"]
    return "".join(lines)


def tagged(name: str, settings: list[str]) -> str:
    """`name` with each setting appended, for the files and folders made with them."""
    return "_".join([name] + settings).replace("/", "_")


def out_dir(folder: Path, side: str, settings: list[str]) -> Path:
    return folder / tagged(f"out_{side}", settings)


def replay(pegs: str, folder: Path, out: Path, reuse: bool, settings: list[str]) -> dict:
    if not (reuse and (out / "metrics.json").is_file()):
        config = folder / "config.yaml"
        if settings:
            out.mkdir(parents=True, exist_ok=True)
            (out / "config.yaml").write_text(with_settings(config.read_text(), sections_of(settings)))
            config = out / "config.yaml"
        result = subprocess.run([pegs, "replay", str(folder / "bag"), "--config", str(config),
                                 "--out", str(out)], capture_output=True, text=True)
        if result.returncode != 0:
            sys.exit(f"{folder}: replay failed: {result.stderr.strip()[-300:]}")
    return json.loads((out / "metrics.json").read_text())


def cell(errors: list[dict]) -> str:
    return (f"{statistics.mean(e['mean_mm'] for e in errors):.1f} | {sum(e['mean_mm'] < table.GOOD_MM for e in errors)} | "
            f"{sum(e['p95_mm'] >= PEAK_MM for e in errors)} | {sum(meets_bar(e) for e in errors)} | "
            f"{statistics.median(e['final_mm'] for e in errors):.1f}")


def meets_bar(error: dict) -> bool:
    """Issue 25's bar for one object: mean under 5 mm and never lost (p95 under 10 mm)."""
    return error["mean_mm"] < table.GOOD_MM and error["p95_mm"] < PEAK_MM


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=Path, nargs="+", required=True)
    ap.add_argument("--pegs", required=True)
    ap.add_argument("--baseline", help="the build before (default: --pegs)")
    ap.add_argument("--set", dest="settings", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="added to each recording's config for --pegs")
    ap.add_argument("--baseline-set", dest="baseline_settings", action="append", default=[],
                    metavar="SECTION.KEY=VALUE", help="added to each recording's config for --baseline")
    ap.add_argument("--readme", type=Path)
    ap.add_argument("--section", default="mujoco-cases", help="the README's markers to write between")
    ap.add_argument("--labels", nargs=2, default=["before", "after"], metavar=("BEFORE", "AFTER"),
                    help="the two sides' names in the table's header")
    ap.add_argument("--reuse", action="store_true", help="keep replays already in out_after / out_before")
    ap.add_argument("--jobs", type=int, default=1, help="replays run at once (default 1)")
    a = ap.parse_args()
    if a.jobs < 1:
        sys.exit("--jobs must be at least 1")
    for settings in (a.settings, a.baseline_settings):
        sections_of(settings)
    before, after, events = {}, {}, Counter()
    folders = sorted(f for s in a.sets for f in s.iterdir() if (f / "truth.json").is_file())
    with ThreadPoolExecutor(max_workers=a.jobs) as pool:
        runs = {folder: (pool.submit(replay, a.pegs, folder, out_dir(folder, "after", a.settings), a.reuse,
                                     a.settings),
                         pool.submit(replay, a.baseline or a.pegs, folder,
                                     out_dir(folder, "before", a.baseline_settings), a.reuse,
                                     a.baseline_settings))
                for folder in folders}
        # A failed replay stops the run at once, as it did one replay at a time: the replays
        # not started yet are dropped, those under way finish.
        for run in as_completed([run for pair in runs.values() for run in pair]):
            if run.exception() is not None:
                pool.shutdown(cancel_futures=True)
                raise run.exception()
    for folder in folders:
        kind = json.loads((folder / "truth.json").read_text())["kind"]
        new, old = (run.result() for run in runs[folder])
        for obj, e in new.get("tracking_error", {}).items():
            after[(kind, folder.name, obj)] = e
            before[(kind, folder.name, obj)] = old["tracking_error"][obj]
        events[kind] += len(new.get("track_events", []))
    kinds = [k for k in ORDER if any(key[0] == k for key in after)]
    kinds += sorted({key[0] for key in after} - set(kinds))
    was, now = a.labels
    lines = [f"| case | objects | {was}: mean | under 5 | p95 >= 10 | both | final | {now}: mean | under 5 "
             f"| p95 >= 10 | both | final | events {now} |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for k in kinds + ["all"]:
        keys = [key for key in after if k in ("all", key[0])]
        n = sum(events.values()) if k == "all" else events[k]
        lines.append(f"| {k} | {len(keys)} | {cell([before[x] for x in keys])} | {cell([after[x] for x in keys])} | {n} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.readme:
        table.write_section(a.readme, a.section, text)

if __name__ == "__main__":
    main()
