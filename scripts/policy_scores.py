"""Mean episode return of the reference policies on each registered id, and a trained
policy against the paper's PI and pi_ff on the tracking task.

    python scripts/policy_scores.py [--seeds 10]
    python scripts/policy_scores.py --trained out/train/best.zip [--seeds 20] [--out docs]

Without --trained: constant Po at the regulator minimum (the Pi feedforward alone),
random actions and the paper's PI on Po (`wpam_mj.environments.policies`) on every id
whose action is Po, each over the seeds 0..N-1; the ratio is the constant policy's score
over the PI's. docs/learning.md quotes its output.

With --trained (a Stable-Baselines3 model of scripts/train_sb3.py, trained on
wpam_mj/WPAMTrackResidual-v0; needs the `learn` extra): on the seeds 0..N-1 of that task,
which the training never saw, the paper's PI (a zero correction), pi_ff (the project's
controller beyond the paper: the same PI with the flow feedforward of Pi and Po,
controller="pi_ff", zero correction) and the trained policy (deterministic): mean return,
RMS and mean absolute tracking error, the share of steps within 0.5 mm, the mean Po
command. Writes `learned_vs_pi_ff.csv` and `learned_vs_pi_ff.png` (seed 0's episode) to
--out.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import gymnasium
import numpy as np

import wpam_mj  # noqa: F401 (registers the ids)
from wpam_mj.environments.policies import POLICIES, mean_return
from wpam_mj.environments.registry import VARIANTS

RESIDUAL_ID = "wpam_mj/WPAMTrackResidual-v0"


def reference_table(seeds: range) -> None:
    print(f"{'id':32s} " + " ".join(f"{p:>9s}" for p in POLICIES) + "  const/PI")
    for env_id, kwargs in VARIANTS.items():
        if kwargs.get("action", "po") != "po":
            continue
        start = time.perf_counter()
        scores = {p: mean_return(env_id, p, seeds) for p in POLICIES}
        print(f"{env_id:32s} " + " ".join(f"{scores[p]:9.1f}" for p in POLICIES)
              + f"  {scores['constant'] / scores['pi']:8.3f}"
              f"  ({time.perf_counter() - start:.0f} s)", flush=True)


def episodes(predict, seeds: list[int], **kwargs) -> dict[str, np.ndarray]:
    """One episode per seed on the batched residual task: rewards and the info series,
    each (steps, seeds)."""
    venv = gymnasium.make_vec(RESIDUAL_ID, num_envs=len(seeds), **kwargs)
    obs, _ = venv.reset(seed=seeds)
    series: dict[str, list] = {"reward": [], "x_m": [], "target_m": [], "error_m": [],
                               "po_cmd_pa": [], "time_s": []}
    done = np.zeros(len(seeds), dtype=bool)
    while not done.all():
        obs, rewards, terminated, truncated, infos = venv.step(predict(obs))
        series["reward"].append(rewards)
        for key in series.keys() - {"reward"}:
            series[key].append(infos[key])
        done |= terminated | truncated
    venv.close()
    return {k: np.array(v) for k, v in series.items()}


def compare(trained: Path, seeds: list[int], out: Path) -> None:
    from stable_baselines3 import PPO, SAC  # noqa: PLC0415 (the `learn` extra)

    model = None
    for algo in (PPO, SAC):
        try:
            model = algo.load(trained, device="cpu")
            break
        except (KeyError, ValueError, TypeError, AttributeError):
            continue
    if model is None:
        raise SystemExit(f"{trained}: not a PPO or SAC model of scripts/train_sb3.py")

    def zero(obs):
        return np.zeros((len(obs), 1), np.float32)

    runs = {"paper's PI": episodes(zero, seeds),
            "pi_ff": episodes(zero, seeds, controller="pi_ff"),
            f"trained ({trained.name})":
                episodes(lambda o: model.predict(o, deterministic=True)[0], seeds)}
    header = ["policy", "return", "rms_error_mm", "mean_abs_error_mm", "within_0.5mm",
              "mean_po_kpa"]
    rows = []
    for name, s in runs.items():
        e = s["error_m"] * 1e3
        rows.append([name, s["reward"].sum(axis=0).mean(), np.sqrt(np.mean(e ** 2)),
                     np.mean(np.abs(e)), np.mean(np.abs(e) <= 0.5),
                     np.mean(s["po_cmd_pa"]) / 1e3])
    print(f"{len(seeds)} test seeds of {RESIDUAL_ID} (0..{len(seeds) - 1}):")
    print(f"{header[0]:28s}" + "".join(f"{h:>18s}" for h in header[1:]))
    for row in rows:
        print(f"{row[0]:28s}" + "".join(f"{v:18.3f}" for v in row[1:]))
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "learned_vs_pi_ff.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows([[r[0], *(f"{v:.4f}" for v in r[1:])] for r in rows])
    plot(runs, out / "learned_vs_pi_ff.png")


def plot(runs: dict[str, dict[str, np.ndarray]], path: Path) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, (ax_x, ax_e, ax_po) = plt.subplots(3, 1, figsize=(7.0, 7.0), sharex=True,
                                            constrained_layout=True)
    first = next(iter(runs.values()))
    t = first["time_s"][:, 0]
    ax_x.plot(t, first["target_m"][:, 0] * 1e3, color="k", lw=1.0, label="target")
    for (name, s), color in zip(runs.items(), ("tab:gray", "tab:blue", "tab:red")):
        ax_x.plot(t, s["x_m"][:, 0] * 1e3, color=color, lw=1.0, label=name)
        ax_e.plot(t, s["error_m"][:, 0] * 1e3, color=color, lw=1.0,
                  label=f"{name}: return {s['reward'][:, 0].sum():.0f}")
        ax_po.plot(t, s["po_cmd_pa"][:, 0] / 1e3, color=color, lw=1.0)
    ax_x.set_ylabel("contraction x [mm]")
    ax_e.set_ylabel("x - x_r [mm]")
    ax_e.set_ylim(-3, 3)
    ax_e.axhspan(-0.5, 0.5, color="0.9", zorder=0)
    ax_po.set_ylabel("Po command [kPa]")
    ax_po.set_xlabel("time [s]")
    ax_x.legend(fontsize=8, loc="upper left")
    ax_e.legend(fontsize=8, loc="lower right")
    ax_x.set_title("WPAMTrackResidual-v0, test seed 0: the paper's PI, pi_ff and the "
                   "trained policy", fontsize=9)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=None,
                        help="test seeds 0..N-1 (default: 10, or 20 with --trained)")
    parser.add_argument("--trained", type=Path, default=None,
                        help="a model saved by scripts/train_sb3.py (best.zip)")
    parser.add_argument("--out", type=Path, default=Path("docs"),
                        help="where --trained writes its table and figure")
    args = parser.parse_args()
    if args.trained is None:
        reference_table(range(args.seeds or 10))
    else:
        compare(args.trained, list(range(args.seeds or 20)), args.out)


if __name__ == "__main__":
    main()
