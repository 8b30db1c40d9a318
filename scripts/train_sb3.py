"""Train a Stable-Baselines3 agent (PPO or SAC) on the batched vector environment and
score it against the paper's PI (not run in CI; needs the `learn` extra: docs/learning.md).

    python scripts/train_sb3.py --algo ppo --steps 2000000 --out out/train

The agent trains on `--n-envs` environments of `--env` stepped together on `mujoco.batch`
(`wpam_mj.environments.sb3.BatchedVecEnv`, `--nthread` threads) for exactly `--steps`
environment steps (for PPO a whole number of rollouts of n-envs x n-steps; anything else
is refused). `--backend warp --device cuda` steps them on MuJoCo Warp instead (the gpu
extra: docs/warp.md; `--device cpu` is Warp's CPU device), and scores them there too, and
the trained policy also on the default backend. Every `--eval-every` steps the
deterministic policy is scored on the validation seeds 1000.. (`--curve-seeds` episodes)
and the best so far is kept. At the end the best and the last policies are scored on the
held-out test seeds 0..N-1 (`--test-seeds`), which never chose anything, beside the
reference policies of `wpam_mj.environments.policies` on the same task with Po as the
action (holding Po at the regulator minimum, random, the paper's PI every 10 ms). Writes to `--out`:
`learning_curve.png` and `learning_curve.csv` (steps, wall seconds, validation return),
`scores.json` (every score, steps, wall time, training steps per second, the settings),
`best.zip` and `last.zip`.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import time
from pathlib import Path

import gymnasium
import matplotlib
import numpy as np
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.vec_env import VecMonitor

import wpam_mj  # noqa: F401 (registers the ids)
from wpam_mj.environments.policies import POLICIES, mean_return
from wpam_mj.environments.sb3 import BatchedVecEnv
from wpam_mj.environments.vector_env import default_threads
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.warp_backend import check_device

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ALGOS = {"ppo": PPO, "sac": SAC}
REFERENCE_ID = "wpam_mj/WPAMTrack-v0"  # the same task with Po as the action


def episode_returns(env_id: str, predict, seeds: list[int], nthread: int,
                    **kwargs) -> np.ndarray:
    """One episode per seed of `predict(obs) -> actions` on the batched vector env (kwargs:
    the backend, its device, the episode's time_limit): the return of each (the episodes
    start together and last the same number of steps)."""
    venv = gymnasium.make_vec(env_id, num_envs=len(seeds), nthread=nthread, **kwargs)
    obs, _ = venv.reset(seed=seeds)
    total = np.zeros(len(seeds))
    running = np.ones(len(seeds), dtype=bool)
    while running.any():
        obs, rewards, terminated, truncated, _ = venv.step(predict(obs))
        total += np.where(running, rewards, 0.0)
        running &= ~(terminated | truncated)
    venv.close()
    return total


def plot(curve: list[tuple[int, float, float]], pi_validation: float, out: Path,
         title: str) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 4.0), constrained_layout=True)
    steps, _, values = zip(*curve)
    ax.plot(steps, values, "o-", color="k", ms=3, label="trained policy (deterministic)")
    ax.axhline(pi_validation, ls="--", color="tab:gray",
               label=f"paper's PI (zero action): {pi_validation:.0f}")
    ax.set_xlabel("training steps")
    ax.set_ylabel("mean episode return")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="lower right", fontsize=8)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def make_model(args, venv):
    """The agent with the documented settings (docs/learning.md, "Training")."""
    policy_kwargs = {"log_std_init": args.log_std_init, "net_arch": [64, 64]}
    if args.algo == "ppo":
        return PPO("MlpPolicy", venv, n_steps=args.n_steps, batch_size=args.batch_size,
                   n_epochs=args.epochs, learning_rate=args.learning_rate, gamma=args.gamma,
                   gae_lambda=args.gae_lambda, clip_range=args.clip_range, ent_coef=0.0,
                   use_sde=args.sde, sde_sample_freq=args.sde_sample_freq, seed=args.seed,
                   verbose=0, policy_kwargs=policy_kwargs, device="cpu")
    return SAC("MlpPolicy", venv, learning_rate=args.learning_rate, gamma=args.gamma,
               batch_size=args.batch_size, buffer_size=args.steps,
               learning_starts=args.learning_starts, train_freq=1,
               gradient_steps=args.gradient_steps, use_sde=args.sde,
               sde_sample_freq=args.sde_sample_freq, use_sde_at_warmup=args.sde,
               seed=args.seed, verbose=0,
               policy_kwargs=policy_kwargs, device="cpu")


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algo", choices=sorted(ALGOS), default="ppo")
    p.add_argument("--env", default="wpam_mj/WPAMTrackResidual-v0",
                   help="registered id to train on (default: the residual task)")
    p.add_argument("--steps", type=int, default=3_932_160,
                   help="environment steps to train, exactly (default: 60 PPO rollouts "
                        "of 16 x 4096)")
    p.add_argument("--n-envs", type=int, default=16, help="environments stepped together")
    p.add_argument("--nthread", type=int, default=min(2, default_threads(16)),
                   help="mujoco.batch threads (default: 2, or the CPUs available)")
    p.add_argument("--seed", type=int, default=0, help="seed of the agent and the "
                   "training environments (env i: seed + i)")
    p.add_argument("--n-steps", type=int, default=4096,
                   help="PPO: steps per environment per rollout")
    p.add_argument("--batch-size", type=int, default=2048, help="minibatch size")
    p.add_argument("--epochs", type=int, default=5, help="PPO: passes over each rollout")
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--gamma", type=float, default=0.99, help="discount per 10 ms step")
    p.add_argument("--gae-lambda", type=float, default=0.95, help="PPO: GAE lambda")
    p.add_argument("--clip-range", type=float, default=0.2, help="PPO: clip range")
    p.add_argument("--sde", action=argparse.BooleanOptionalAction, default=True,
                   help="generalized state-dependent exploration (gSDE)")
    p.add_argument("--sde-sample-freq", type=int, default=-1,
                   help="gSDE: steps between new noise matrices (-1: once per rollout)")
    p.add_argument("--log-std-init", type=float, default=-3.0,
                   help="initial log standard deviation of the Gaussian policy (-2: "
                        "exploring the Po correction by about +-11 kPa)")
    p.add_argument("--gradient-steps", type=int, default=1,
                   help="SAC: gradient steps per vector step")
    p.add_argument("--learning-starts", type=int, default=10_000,
                   help="SAC: steps before the first update, acting with the initial "
                        "policy (its gSDE noise about a zero correction: the PI) rather "
                        "than uniformly random corrections when --sde")
    p.add_argument("--eval-every", type=int, default=131_072,
                   help="score the policy on the validation seeds every this many steps")
    p.add_argument("--curve-seeds", type=int, default=8, help="validation seeds 1000..")
    p.add_argument("--test-seeds", type=int, default=20, help="held-out seeds 0..N-1")
    p.add_argument("--backend", choices=("mujoco", "warp"), default="mujoco",
                   help="physics of the vector env: mujoco.batch, or MuJoCo Warp (the gpu "
                        "extra)")
    p.add_argument("--device", default="cpu", help="--backend warp: cuda (or cuda:N), or "
                   "cpu (Warp's CPU device)")
    p.add_argument("--time-limit", type=float, default=10.0,
                   help="episode length [s] for training and scoring (default: the "
                        "registered ids' 10 s; shorter only to check the script quickly)")
    p.add_argument("--out", type=Path, default=Path("out/train"))
    args = p.parse_args()
    if args.backend == "mujoco" and args.device != "cpu":
        p.error(f"--device {args.device} needs --backend warp (mujoco.batch runs on the CPU)")
    if args.backend == "warp":  # the extra and the device, before minutes of reference scores
        try:
            check_device(args.device)
        except ParameterError as err:
            p.error(f"--backend warp --device {args.device}: {err}")
    if not 0.0 < args.time_limit <= 10.0:
        p.error(f"--time-limit {args.time_limit:g} must be in (0, 10] s")
    per_update = args.n_envs * (args.n_steps if args.algo == "ppo" else 1)
    unit = "n-envs x n-steps, one PPO rollout" if args.algo == "ppo" else "n-envs"
    for name in ("steps", "eval_every"):
        value = getattr(args, name)
        if value <= 0 or value % per_update:
            p.error(f"--{name.replace('_', '-')} {value} must be a positive multiple of "
                    f"{per_update} ({unit})")
    return args


def main() -> None:
    args = parse_args()
    torch.set_num_threads(1)  # small MLPs: threads only contend with the batch's
    args.out.mkdir(parents=True, exist_ok=True)
    test = list(range(args.test_seeds))
    validation = list(range(1000, 1000 + args.curve_seeds))
    limit = {"time_limit": args.time_limit}
    physics = {"backend": args.backend, "device": args.device, **limit}
    refs = {name: mean_return(REFERENCE_ID, name, test, **limit) for name in POLICIES}

    def zero(o):
        return np.zeros((len(o), 1), np.float32)

    refs["zero action"] = float(episode_returns(args.env, zero, test, args.nthread,
                                                **physics).mean())
    pi_validation = float(episode_returns(args.env, zero, validation, args.nthread,
                                          **physics).mean())
    print("reference policies (test seeds):", {k: round(v, 1) for k, v in refs.items()},
          flush=True)

    venv = VecMonitor(BatchedVecEnv(args.env, args.n_envs, nthread=args.nthread, **physics))
    venv.seed(args.seed)
    model = make_model(args, venv)

    def predict(m):
        return lambda obs: m.predict(obs, deterministic=True)[0]

    curve: list[tuple[int, float, float]] = []
    best, evaluating, start = -np.inf, 0.0, time.perf_counter()
    done = 0
    while done < args.steps:
        chunk = min(args.eval_every, args.steps - done)  # whole rollouts (parse_args)
        model.learn(total_timesteps=chunk, reset_num_timesteps=False)
        done = model.num_timesteps
        t0 = time.perf_counter()
        value = float(episode_returns(args.env, predict(model), validation,
                                      args.nthread, **physics).mean())
        if value > best:
            best = value
            model.save(args.out / "best.zip")
        evaluating += time.perf_counter() - t0
        curve.append((done, time.perf_counter() - start - evaluating, value))
        print(f"{done:9d} steps, {curve[-1][1]:6.0f} s training: validation {value:6.1f}",
              flush=True)
    wall = time.perf_counter() - start - evaluating
    best_model = ALGOS[args.algo].load(args.out / "best.zip", device="cpu")
    scores = {**refs,
              "trained best": float(episode_returns(args.env, predict(best_model), test,
                                                    args.nthread, **physics).mean()),
              "trained last": float(episode_returns(args.env, predict(model), test,
                                                    args.nthread, **physics).mean())}
    if args.backend != "mujoco":  # the policy learned on Warp, on the plugin's physics
        for name, policy in (("zero action", zero), ("trained best", predict(best_model))):
            scores[f"{name}, mujoco backend"] = float(episode_returns(
                args.env, policy, test, args.nthread, **limit).mean())
    print("scores (test seeds):", {k: round(v, 1) for k, v in scores.items()})
    print(f"{args.algo} trained {model.num_timesteps} steps in {wall:.0f} s "
          f"({model.num_timesteps / wall:.0f} steps/s without the evaluations), load "
          f"average {os.getloadavg()[0]:.2f}")
    with open(args.out / "learning_curve.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["steps", "train_wall_s", "validation_return"])
        writer.writerows(curve)
    title = (f"{args.algo.upper()} on {args.env}, seed {args.seed}, {args.n_envs} batched "
             f"envs ({args.backend}, {args.device})\nmean return over the "
             f"{len(validation)} validation seeds 1000..")
    plot(curve, pi_validation, args.out / "learning_curve.png", title)
    (args.out / "scores.json").write_text(json.dumps(
        {"settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
         "episode_steps": venv.get_attr("episode_steps")[0], "test_seeds": test,
         "validation_seeds": validation,
         "scores": scores, "pi_validation": pi_validation, "steps": model.num_timesteps,
         "train_wall_s": wall,
         "train_steps_per_s": model.num_timesteps / wall,
         "load_average_end": os.getloadavg()[0], "curve": curve}, indent=1) + "\n")
    model.save(args.out / "last.zip")


if __name__ == "__main__":
    main()
