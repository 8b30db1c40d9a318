"""Pack what `bench_warp.py` needs on a GPU machine that cannot reach a package index.

    python benchmarks/warp_gpu_bundle.py [--out .gpu_wheels] [--part-mib 59.5] [--python 3.12]

Downloads (pip download, for Linux x86_64 and the given Python) the wheels the machine's
own Python lacks: warp-lang, mujoco-warp, mujoco, dm-control (its simulation modules only:
the suites' and robots' meshes, 50 MB of it, are left out), dm-env, dm-tree, gymnasium,
farama-notifications, stable-baselines3 (PPO on the GPU: docs/warp.md); then cuts them into
folders `<out>/1`, `<out>/2`, ... of at most --part-mib each (the warp-lang wheel alone is
149 MB), so that each folder can travel with one call to the machine.
`benchmarks/warp_gpu.sh` there joins the pieces and installs them. Versions are the gpu
extra's (pyproject.toml).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

WHEELS = ("warp-lang==1.19.0", "mujoco-warp==3.17.0", "mujoco==3.17.0", "dm-control==1.0.50",
          "dm-env==1.6", "dm-tree==0.1.10", "gymnasium==1.4.0", "farama-notifications==0.0.6",
          "stable-baselines3==2.9.2")  # the last for scripts/train_sb3.py --backend warp
DM_CONTROL_LEFT_OUT = ("dm_control/suite/", "dm_control/locomotion/", "dm_control/manipulation/",
                       "dm_control/blender/", "dm_control/composer/", "dm_control/entities/")
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_24_x86_64",
             "manylinux_2_17_x86_64", "manylinux2014_x86_64")


def download(folder: Path, python: str) -> list[Path]:
    platforms = [arg for p in PLATFORMS for arg in ("--platform", p)]
    subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
                    *platforms, "--python-version", python, "-d", str(folder), *WHEELS],
                   check=True)
    return sorted(folder.glob("*.whl"))


def slim_dm_control(wheel: Path) -> None:
    """Rewrite the dm-control wheel without its task suites and robots (their meshes), its
    RECORD listing the files kept."""
    kept = wheel.with_suffix(".slim")
    with zipfile.ZipFile(wheel) as src, zipfile.ZipFile(kept, "w", zipfile.ZIP_DEFLATED) as dst:
        names = [n for n in src.namelist() if not n.startswith(DM_CONTROL_LEFT_OUT)]
        for name in names:
            data = src.read(name)
            if name.endswith(".dist-info/RECORD"):
                data = b"\n".join(line for line in data.splitlines()
                                  if not line.decode().startswith(DM_CONTROL_LEFT_OUT)) + b"\n"
            dst.writestr(name, data)
    kept.replace(wheel)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=".gpu_wheels")
    parser.add_argument("--part-mib", type=float, default=59.5)
    parser.add_argument("--python", default="3.12", help="the GPU machine's Python")
    args = parser.parse_args(argv)
    out = Path(args.out)
    limit = int(args.part_mib * 2**20)
    shutil.rmtree(out, ignore_errors=True)
    with tempfile.TemporaryDirectory() as tmp:
        wheels = download(Path(tmp), args.python)
        for wheel in wheels:
            if wheel.name.startswith("dm_control-"):
                slim_dm_control(wheel)
        pieces: list[tuple[str, bytes]] = []
        for wheel in sorted(wheels, key=lambda w: -w.stat().st_size):
            data = wheel.read_bytes()
            if len(data) <= limit:
                pieces.append((wheel.name, data))
            else:
                for k in range(0, len(data), limit):
                    pieces.append((f"{wheel.name}.part{k // limit:02d}", data[k:k + limit]))
        folders: list[list[tuple[str, bytes]]] = []
        for name, data in sorted(pieces, key=lambda p: -len(p[1])):  # first fit, largest first
            for folder in folders:
                if sum(len(d) for _, d in folder) + len(data) <= limit:
                    folder.append((name, data))
                    break
            else:
                folders.append([(name, data)])
        for k, folder in enumerate(folders, 1):
            (out / str(k)).mkdir(parents=True)
            for name, data in folder:
                (out / str(k) / name).write_bytes(data)
            size = sum(len(d) for _, d in folder) / 2**20
            print(f"{out / str(k)}: {size:.1f} MiB: {', '.join(n for n, _ in folder)}")
    print(f"{len(folders)} folders; carry one per call, back to back (the machine stays warm "
          "30 s), then run benchmarks/warp_gpu.sh")
    return 0


if __name__ == "__main__":
    sys.exit(main())
