"""Diagnose recordings of the third-party set with `pegs diagnose` and judge each report against
the hidden truth (truth.json), as `pegs scenario concealed` does for pegs's own scenarios.

    python judge.py --pegs target/release/pegs --seeds 100-102 --out DIR [--kinds drag,tether]
                    [--robot-contact] [--set correct.pose_damping=25 ...] [--reuse] [--before DIR]
                    [--readme README.md --section NAME]

A verdict passes when the named family is the concealed one on the right object (a mass error may
be named on either object of the collision, as the ratio between them), its parameter is within
25 % of the truth, and on a control nothing is named. Writes DIR/diagnosis.md (or, with
--robot-contact, DIR/diagnosis_robot_contact.md; each --set adds itself to the name), and with
--readme that text between the README's `<!-- NAME:start -->` and `<!-- NAME:end -->` markers.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import cases  # noqa: E402
import generate  # noqa: E402
import scenes  # noqa: E402
import table  # noqa: E402


def verdicts(report: dict) -> str:
    """Each object's verdict when nothing is named (no missing physics, not enough evidence, not
    located, not confirmed)."""
    return ", ".join(f"{o['object']}: {o['verdict'].replace('_', ' ')}" for o in report.get("objects", []))


def evidence(report: dict, obj: str) -> str:
    """What the verdict on `obj` rests on: its verdict, windows and folds."""
    o = next((o for o in report.get("objects", []) if o["object"] == obj), None)
    if o is None:
        return "-"
    return f"{o['verdict'].replace('_', ' ')}: {o.get('windows', 0)} windows, {len(o.get('folds', []))} folds"


def named_effects(report: dict) -> dict[str, tuple[str, float | None]]:
    """Object -> (named family, its first parameter)."""
    out = {}
    for o in report.get("objects", []):
        params = o.get("parameters") or []
        out[o["object"]] = (o["effect"], params[0]["value"] if params else None)
    return out


def judge(truth: dict, report: dict) -> dict:
    named = named_effects(report)
    family, obj, value = truth["family"], truth["object"], truth.get("parameter")
    found = {k: v for k, v in named.items() if v[0] != "none"}
    if family == "none":
        return {"named": ", ".join(f"{k}: {v[0]}" for k, v in found.items()) or verdicts(report),
                "estimate": None, "error": None, "passed": not found}
    estimate = None
    if family == "mass_error":
        # Either side of the collision, as a ratio between the two.
        other = truth["ratio_to"]
        if named.get(obj, ("none",))[0] == family and named[obj][1]:
            estimate = named[obj][1]
        elif named.get(other, ("none",))[0] == family and named[other][1]:
            estimate = 1.0 / named[other][1]
    elif named.get(obj, ("none",))[0] == family and named[obj][1] is not None:
        estimate = abs(named[obj][1])
    error = abs(estimate - value) / abs(value) if estimate is not None and value else None
    return {"named": ", ".join(f"{k}: {v[0]}" for k, v in found.items()) or verdicts(report),
            "estimate": estimate, "error": error, "passed": error is not None and error <= 0.25}


# A recording shows its effect free of the robot where at least this many windows (one starting
# at each frame) the robot does not touch end 5 mm or more from where they end without it
# (counterfactual.py): a diagnosis fitting free motion needs two windows per fold of three.
FREE_SHOWN_ENOUGH = 6


def shown(truth: dict) -> tuple[str, bool | None]:
    """What the recording can show of its effect (truth.json's `shown`, written by the generator
    from counterfactual replays): a table cell and whether it shows free of the robot (None for
    a recording made before the generator measured it)."""
    per_object = truth.get("shown")
    if per_object is None:
        return "-", None
    names = [truth["object"]] + ([truth["ratio_to"]] if "ratio_to" in truth else [])
    best = max((per_object[n] for n in names if n in per_object), key=lambda v: v["free_shown"])
    cell = (f"{best['free_shown']}/{best['free_windows']} free ({best['free_max_mm']:.0f} mm), "
            f"{best['pushed_shown']}/{best['pushed_windows']} pushed ({best['pushed_max_mm']:.0f} mm)")
    return cell, best["free_shown"] >= FREE_SHOWN_ENOUGH


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pegs", required=True)
    ap.add_argument("--seeds", default="100-102")
    ap.add_argument("--kinds", default=",".join(scenes.KINDS))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    ap.add_argument("--robot-contact", action="store_true",
                    help="pass --robot-contact to pegs diagnose (windows where the robot pushes count too)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="add a setting to each recording's config for its diagnosis (written beside it as "
                         "config_<settings>.yaml, the report to diagnosis_<mode>_<settings>)")
    ap.add_argument("--reuse", action="store_true",
                    help="judge a recording's existing report instead of diagnosing it again")
    ap.add_argument("--before", type=Path, metavar="DIR",
                    help="the same recordings diagnosed by another build (its --out): a column with its verdicts")
    ap.add_argument("--readme", type=Path)
    ap.add_argument("--section", default="mujoco-diagnosis", help="the README's markers to write between")
    a = ap.parse_args()
    sections = cases.sections_of(a.set)
    mode = cases.tagged("robot_contact" if a.robot_contact else "free", a.set)
    before = ["named before"] if a.before else []
    head = ["recording", "shape", "concealed", "shown (windows the effect moves 5 mm)", *before, "named",
            "estimate (truth)", "error", "evidence on the concealed object", "1 s open loop before -> after (mm)",
            "pass", "minutes"]
    lines = ["| " + " | ".join(head) + " |",
             "| " + " | ".join("---:" if h in ("error", "minutes") else "---" for h in head) + " |"]
    passed_before = 0
    passed = total = 0
    observable = [0, 0]  # named, effects shown free of the robot
    controls = [0, 0]  # clean, all
    for kind in a.kinds.split(","):
        for seed in generate.seeds(a.seeds):
            folder = a.out / f"{kind}_{seed}"
            if not (folder / "truth.json").is_file():
                generate.record(kind, seed, a.out, a.width, a.height, None, 0.0)
            truth = json.loads((folder / "truth.json").read_text())
            shown_cell, free = shown(truth) if truth["family"] != "none" else ("-", None)
            clock = time.time()
            diag = folder / f"diagnosis_{mode}"
            config = folder / "config.yaml"
            if a.set:
                config = folder / f"{cases.tagged('config', a.set)}.yaml"
                config.write_text(cases.with_settings((folder / "config.yaml").read_text(), sections))
            command = [a.pegs, "diagnose", str(folder / "bag"), "--config", str(config),
                       "--out", str(diag)] + (["--robot-contact"] if a.robot_contact else [])
            reused = a.reuse and (diag / "report.json").is_file()
            if reused:
                result = subprocess.CompletedProcess(command, 0, "", "")
            else:
                result = subprocess.run(command, capture_output=True, text=True)
            minutes = "-" if reused else f"{(time.time() - clock) / 60:.1f}"
            earlier = []
            if a.before:
                old = a.before / folder.name / diag.name / "report.json"
                if old.is_file():
                    w = judge(truth, json.loads(old.read_text()))
                    passed_before += w["passed"]
                    earlier = [w["named"] + (" (pass)" if w["passed"] else "")]
                else:
                    earlier = ["-"]
            total += 1
            if result.returncode != 0:
                last = (result.stderr.strip().splitlines() or ["?"])[-1]
                lines.append("| " + " | ".join([folder.name, truth["shape"], truth["family"], shown_cell, *earlier,
                                                f"failed: {last}", "", "", "", "", "no", minutes]) + " |")
                observable[1] += bool(free)
                print(lines[-1], flush=True)
                continue
            report = json.loads((diag / "report.json").read_text())
            v = judge(truth, report)
            passed += v["passed"]
            if truth["family"] == "none":
                controls[0] += v["passed"]
                controls[1] += 1
            elif free:
                observable[0] += v["passed"]
                observable[1] += 1
            value = truth.get("parameter")
            est = f"{v['estimate']:.3g} ({value:.3g})" if v["estimate"] is not None and value is not None else "-"
            err = f"{100 * v['error']:.0f} %" if v["error"] is not None else "-"
            obj = next((o for o in report["objects"] if o["object"] == truth["object"]), report["objects"][0])
            loop = f"{obj['before']['open_loop_error_mm']:.1f} -> {obj['after']['open_loop_error_mm']:.1f}"
            lines.append("| " + " | ".join([folder.name, truth["shape"], truth["family"], shown_cell, *earlier, v["named"],
                                            est, err, evidence(report, truth["object"]), loop,
                                            "yes" if v["passed"] else "no", minutes]) + " |")
            print(lines[-1], flush=True)
    windows = "every window of motion, the robot's pushes included" if a.robot_contact else \
        "windows where the object moves without the robot touching it"
    text = (f"`pegs diagnose{' --robot-contact' if a.robot_contact else ''}` on recordings MuJoCo simulated and "
            f"rendered (kinds {a.kinds}, seeds {a.seeds}, 3 cameras at {a.width}x{a.height}), judged against the hidden truth: "
            f"the concealed family on the right object with its parameter within 25 %, nothing named on a "
            f"control. Judged on {windows}, by cross-validation over three folds. Passed: {passed} of {total} "
            f"({total - controls[1]} concealed effects, {controls[0]} of {controls[1]} controls clean). "
            f"Of the {observable[1]} effects the recordings show free of the robot (in {FREE_SHOWN_ENOUGH} or more "
            f"windows the robot does not touch, the effect moves the object's end 5 mm or more: `shown`, from "
            f"MuJoCo replaying each window without it), {observable[0]} named. "
            + (f"Diagnosed by another build (`--before`, column \"named before\"): {passed_before} passed. "
               if a.before else "")
            + f"Generated by `tests/mujoco/judge.py{' --robot-contact' if a.robot_contact else ''}"
            f"{''.join(f' --set {x}' for x in a.set)}`.\n\n"
            + "\n".join(lines) + "\n")
    a.out.mkdir(parents=True, exist_ok=True)
    name = cases.tagged("diagnosis_robot_contact" if a.robot_contact else "diagnosis", a.set)
    (a.out / f"{name}.md").write_text(text)
    print(text)
    if a.readme:
        table.write_section(a.readme, a.section, text)


if __name__ == "__main__":
    main()
