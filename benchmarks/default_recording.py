"""What the default recording's error is made of: its config flown again with parts of
its pose-dependent bias or its delays left out, and with room networks of other seeds,
each replayed through the C estimator (robust) without and with the shipped correction.

    .venv/bin/python benchmarks/default_recording.py [--room-seeds 1 2 3] [--out out/default_recording.json]

Prints one line per variant and writes them to OUT. With --room-seeds, each seed's room
network is trained as `make room-bias-net` trains seed 0 (`rig train --form pair
--apart-from recordings/pair_bias_net.json --minus-link-bias --seed N`; about a minute
each) and flown in place of the shipped one."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402
from rig.sim.simulate import SimConfig, simulate  # noqa: E402

CONFIG = ROOT / "recordings" / "default.sim.json"
PAIR_NETWORK = ROOT / "recordings" / "pair_bias_net.json"
VARIANTS = {                       # label -> effects left out of the config
    "as shipped": (),
    "without learned_bias": ("learned_bias",),
    "without link_bias": ("link_bias",),
    "without link_bias and learned_bias": ("link_bias", "learned_bias"),
    "without the anchor delays": ("anchor_delay",),
}


def rmse_pair(config: SimConfig) -> dict:
    """The robust estimator's 3D RMSE on the flown config without and with the correction."""
    rec = simulate(config)
    return {"without_m": float(evaluate(rec, use_nn=False)["rmse_3d"]),
            "with_m": float(evaluate(rec, use_nn=True)["rmse_3d"])}


def without(config: SimConfig, left_out: tuple[str, ...]) -> SimConfig:
    return replace(config, effects=[e for e in config.effects if e["effect"] not in left_out])


def with_network(config: SimConfig, network: Path) -> SimConfig:
    effects = [{**e, "params": {**e["params"], "network": str(network)}} if e["effect"] == "learned_bias" else e
               for e in config.effects]
    return replace(config, effects=effects)


def room_network(seed: int, out: Path) -> Path:
    from rig.bias.config import TrainConfig
    from rig.bias.train import run_training, trained_on

    flights = [f for f in paths.flights() if f.name not in trained_on(PAIR_NETWORK)]
    run_training(flights, out, config=TrainConfig(seed=seed, form="pair"), minus_link_bias=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--room-seeds", nargs="*", type=int, default=[])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "default_recording.json")
    args = parser.parse_args()
    config = SimConfig.load(CONFIG)
    rows = {}
    for label, left_out in VARIANTS.items():
        rows[label] = rmse_pair(without(config, left_out))
        print(f"{label:36s} {rows[label]['without_m']:.3f} -> {rows[label]['with_m']:.3f} m", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.room_seeds:
            label = f"room network of seed {seed}"
            rows[label] = rmse_pair(with_network(config, room_network(seed, Path(tmp) / f"room{seed}.json")))
            print(f"{label:36s} {rows[label]['without_m']:.3f} -> {rows[label]['with_m']:.3f} m", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
