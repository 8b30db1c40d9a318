"""The antagonistic W-PAM pair (models/arm/arm.xml) tracking joint-angle steps and a sine,
with Po feedback in both muscles' plugins: CSV per run, one PNG, a JSON of the settled
error per plateau and the sine's gain and lag.

    python scripts/arm_tracking.py [--out out/arm] [--hold 15] [--freq 0.1]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from wpam_mj.experiments import arm
from wpam_mj.infra.files import write_atomic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/arm"), help="output folder")
    parser.add_argument("--hold", type=float, default=15.0, help="seconds per step [s]")
    parser.add_argument("--freq", type=float, default=0.1, help="sine frequency [Hz]")
    parser.add_argument("--amplitude", type=float, default=10.0, help="sine amplitude [deg]")
    args = parser.parse_args()

    pair = arm.Pair.load()
    steps, plateaus = arm.step_response(pair, hold=args.hold)
    sine, point = arm.sine_response(pair, amplitude_deg=args.amplitude, freq=args.freq)
    args.out.mkdir(parents=True, exist_ok=True)
    for name, result in (("arm_steps.csv", steps), ("arm_sine.csv", sine)):
        write_atomic(args.out / name, lambda p, r=result: p.write_text(r.csv_text()))
    summary = {"pulley_radius_m": pair.radius, "contraction0_m": pair.contraction0,
               "hold_s": args.hold, "settled_window_s": arm.SETTLED_S,
               "plateaus": [{"target_deg": p.target_deg, "error_deg": p.error_deg,
                             "peak_to_peak_deg": p.peak_to_peak_deg} for p in plateaus],
               "max_abs_error_deg": max(abs(p.error_deg) for p in plateaus),
               "sine": {"freq_hz": point.freq_hz, "amplitude_deg": args.amplitude,
                        "gain": point.gain, "phase_lag_deg": point.phase_lag_deg}}
    write_atomic(args.out / "arm.json",
                 lambda p: p.write_text(json.dumps(summary, indent=2) + "\n"))
    write_atomic(args.out / "arm.png", lambda p: _figure(steps, plateaus, sine, point, p))
    for p in plateaus:
        print(f"target {p.target_deg:+5.1f} deg: settled error {p.error_deg:+.3f} deg, "
              f"peak-to-peak {p.peak_to_peak_deg:.3f} deg")
    print(f"sine {args.amplitude:g} deg at {point.freq_hz:g} Hz: gain {point.gain:.3f}, "
          f"lag {point.phase_lag_deg:.1f} deg; wrote {args.out}")


def _figure(steps, plateaus, sine, point, path: Path) -> None:
    import matplotlib  # noqa: PLC0415 (slow import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(3, 1, figsize=(9, 9), constrained_layout=True)
    ax = axes[0]
    ax.plot(steps.time, np.degrees(steps.theta_ref), "k--", lw=1, label="target")
    ax.plot(steps.time, np.degrees(steps.theta), lw=1.2, label="joint angle")
    worst = max(abs(p.error_deg) for p in plateaus)
    ax.set(xlabel="time [s]", ylabel="angle [deg]",
           title=f"angle steps: settled error at most {worst:.2f} deg (target 0.5 deg)")
    ax.legend(loc="lower left")
    ax = axes[1]
    for i, name in enumerate(arm.MUSCLES):
        ax.plot(steps.time, steps.po[:, i] / 1e6, lw=1, label=f"{name} Po")
    ax.set(xlabel="time [s]", ylabel="Po [MPa]", title="Po feedback in both muscles")
    ax.legend(loc="upper right")
    ax = axes[2]
    ax.plot(sine.time, np.degrees(sine.theta_ref), "k--", lw=1, label="target")
    ax.plot(sine.time, np.degrees(sine.theta), lw=1.2, label="joint angle")
    ax.set(xlabel="time [s]", ylabel="angle [deg]",
           title=f"sine {point.freq_hz:g} Hz: gain {point.gain:.3f}, "
                 f"lag {point.phase_lag_deg:.1f} deg")
    ax.legend(loc="lower left")
    fig.savefig(path, dpi=100, format="png")
    plt.close(fig)


if __name__ == "__main__":
    main()
