"""Record concealed-physics scenes with MuJoCo (an engine and renderer that are not pegs's).

    python generate.py --kind drag --seed 3 --out DIR [--width 320 --height 180] [--shape long_push]
    python generate.py --kind all --seeds 0-4 --out DIR
    python generate.py --kind model_errors --seeds 0-4 --out DIR

Each recording is a folder: `bag/` (rosbag2, MCAP or SQLite3; `--layout realsense` for what a
RealSense + Franka rig records), `ground_truth.csv`, `truth.json` (the
hidden effect, for judging) and `config.yaml` (what a user would configure). Run inside the venv
that tests/mujoco/setup_venv.sh makes; needs MUJOCO_GL=egl (set here when unset).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).parent))

import counterfactual  # noqa: E402
import scenes  # noqa: E402
import simulate  # noqa: E402
import write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def record(kind: str, seed: int, out: Path, width: int, height: int, shape: str | None, stamp0: float,
           depth: str = "32FC1", layout: str = "pegs", storage: str = "mcap", support: str = "corners",
           follow: bool = True, stiff_contacts: bool = False) -> Path:
    scene = scenes.draw(kind, seed, shape, from_start=not follow)
    scene.support = support
    scene.stiff_contacts = stiff_contacts
    folder = out / f"{kind}_{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    clock = time.time()
    urdf = ROOT / "urdf" / "panda_pusher.urdf"
    run = simulate.simulate(scene, str(urdf), width, height)
    run.measured["shown"] = counterfactual.shown(scene, run, str(urdf))
    bag = folder / "bag"
    if bag.exists():
        for f in bag.iterdir():
            f.unlink()
        bag.rmdir()
    write.write_bag(bag, run, stamp0, depth, layout, storage)
    write.write_truth(folder, scene, run, stamp0)
    write.write_config(folder, scene, urdf, [c.name for c in run.cameras])
    print(f"{folder.name}: {scene.shape}, {len(run.frames)} frames, truth {scene.truth.get('family')} "
          f"in {time.time() - clock:.1f} s", flush=True)
    return folder


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kind", required=True,
                    help=f"one of {', '.join(scenes.KINDS + scenes.MODEL_ERRORS[:-2])}; all (the concealed "
                         "physics set) or model_errors (the tracking set)")
    ap.add_argument("--seed", type=int)
    ap.add_argument("--seeds", help="a range a-b or a list a,b,c")
    ap.add_argument("--shape", choices=scenes.SHAPES)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    ap.add_argument("--stamp0", type=float, default=0.0, help="stamp of the first message, s")
    ap.add_argument("--depth", choices=["32FC1", "16UC1"], default="32FC1", help="depth encoding (16UC1: mm)")
    ap.add_argument("--layout", choices=["pegs", "realsense"], default="pegs",
                    help="realsense: JPEG colour, 16UC1 depth, no masks, the drivers' tf chain (see write.py)")
    ap.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    ap.add_argument("--support", choices=["corners", "spread"], default="corners",
                    help="where objects bear on the table: MuJoCo's box corners, or spread under the bottom face")
    ap.add_argument("--plan-from-start", action="store_true",
                    help="lay out every push as recorded until the follow change: against the objects where "
                         "they stand at the start, the rod 3 cm behind the object's furthest extent (a later push "
                         "may bring the rod down into an object an earlier one moved, as an arm model that is off would)")
    ap.add_argument("--stiff-contacts", action="store_true",
                    help="contacts of the robot and the objects stiffer than MuJoCo's soft default (simulate.STIFF_CONTACT), "
                         "with which a push needs the rod millimetres inside its object")
    a = ap.parse_args()
    kinds = {"all": scenes.KINDS, "model_errors": scenes.MODEL_ERRORS}.get(a.kind, [a.kind])
    chosen = seeds(a.seeds) if a.seeds else [a.seed if a.seed is not None else 0]
    for kind in kinds:
        for seed in chosen:
            record(kind, seed, a.out, a.width, a.height, a.shape, a.stamp0, a.depth, a.layout, a.storage, a.support,
                   not a.plan_from_start, a.stiff_contacts)


if __name__ == "__main__":
    main()
