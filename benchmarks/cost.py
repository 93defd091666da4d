"""Instruction cost of each estimator call on x86-64, counted by valgrind's callgrind.

    .venv/bin/python benchmarks/cost.py [RECORDING] [--json out/cost.json]

Replays RECORDING (default: the first shared real flight, else the default
recording) through the estimator built with -O2 (`make -C estimator_c bench`)
under callgrind, once per configuration, and prints the mean number of
instructions per call of: the prediction (ekf_predict), a whole TDOA update
(tdoa_update: delay compensation, features, network, gate, update), the plain
and the robust update alone, the feature computation, the network inference, and the
blocked-anchor weighting (its STEP part once per 10 ms, its per-measurement parts).
Instruction counts are deterministic, unlike wall-clock time; the target is
"robust update including network inference <= 17k instructions per call"."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths
from rig.data.importer import load_any  # noqa: E402
from rig.data.recording import Recording  # noqa: E402
from rig.estimator import native  # noqa: E402
from rig.estimator.bias_net import FORMS, BiasNet, shape  # noqa: E402
from rig.estimator.evaluate import build_events, load_model, start_time, truth_pose_at  # noqa: E402

FUNCTIONS = ("ekf_predict", "tdoa_update", "ekf_scalar_update", "ekf_robust_scalar_update", "bn_features",
             "bn_predict", "bn_link_bias", "anchor_bias_step", "anchor_bias_observe", "anchor_bias_weight")
CONFIGURATIONS = {"plain": {"robust": 0, "use_bias_net": 0},
                  "robust": {"robust": 1, "use_bias_net": 0},
                  "robust+nn": {"robust": 1, "use_bias_net": 1}}
TARGET_ROBUST_NN = 17_000


def random_net(form: str, seed: int = 0) -> BiasNet:
    """Same shape and cost as a trained network of `form` (inference has no data-dependent branches)."""
    rng = np.random.default_rng(seed)
    n_in, hidden = shape(form)
    shapes = [(hidden, n_in), (hidden, hidden), (hidden, hidden), (1, hidden)]
    return BiasNet([rng.normal(0, 0.3, s) for s in shapes], [rng.normal(0, 0.1, s[0]) for s in shapes],
                   np.zeros(n_in), np.ones(n_in), 0.1, 0.0, form)


def write_session(path: Path, rec: Recording, params: native.EstimatorParams, net: BiasNet | None) -> None:
    """The session file read by estimator_c/targets/bench/main.c."""
    t0 = start_time(rec)
    pos, quat = truth_pose_at(rec, t0)
    events = build_events(rec, t0)
    anchors = [a for a in rec.anchors if 0 <= a.id < native.MAX_ANCHORS]
    with open(path, "wb") as f:
        f.write(b"UWBS" + bytes(params))
        f.write(np.uint32(len(anchors)).tobytes())
        for a in anchors:
            f.write(np.uint8(a.id).tobytes() + np.asarray(a.position, "<f4").tobytes()
                    + np.asarray(a.quaternion, "<f4").tobytes())
        f.write(np.uint8(net is not None).tobytes())
        if net is not None:
            f.write(net.pack().tobytes())
        f.write(np.uint32(0).tobytes() + np.asarray(pos, "<f4").tobytes() + np.asarray(quat, "<f4").tobytes())
        f.write(np.uint32(len(events)).tobytes() + np.ascontiguousarray(events, native.EVENT_DTYPE).tobytes())


def parse_callgrind(path: Path) -> dict[str, dict[str, int]]:
    """Calls and inclusive instructions per callee, summed over all call sites."""
    calls: dict[str, int] = defaultdict(int)
    inclusive: dict[str, int] = defaultdict(int)
    lines = path.read_text().splitlines()
    callee = None
    for k, line in enumerate(lines):
        if line.startswith("cfn="):
            callee = line[4:].strip()
        elif line.startswith("calls=") and callee is not None:
            calls[callee] += int(line[6:].split()[0])
            inclusive[callee] += int(lines[k + 1].split()[-1])
    return {name: {"calls": calls[name], "instructions": inclusive[name]} for name in calls}


def measure(binary: Path, session: Path, workdir: Path, name: str) -> dict[str, dict]:
    out = workdir / f"callgrind.{name}.out"
    subprocess.run(["valgrind", "--tool=callgrind", "--compress-strings=no", "--compress-pos=no",
                    f"--callgrind-out-file={out}", str(binary), str(session)],
                   check=True, capture_output=True, text=True)
    counts = parse_callgrind(out)
    result = {}
    for fn in FUNCTIONS:
        c = counts.get(fn)
        if c and c["calls"]:
            result[fn] = {"calls": c["calls"], "instructions_per_call": round(c["instructions"] / c["calls"])}
    return result


def default_recording() -> Path:
    flights = paths.flights() if paths.data_dir().exists() else []
    return flights[0] if flights else paths.default_recording()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recording", nargs="?", type=Path, help="MCAP recording or shared flight directory")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "cost.json")
    parser.add_argument("--random", choices=FORMS, metavar="FORM",
                        help="a network of random weights of this form instead of the shipped one")
    args = parser.parse_args()
    source = args.recording or default_recording()
    rec = load_any(source)
    model = None if args.random else load_model()
    net = model if model is not None else random_net(args.random or FORMS[0])
    native.make("bench")
    binary = native.ESTIMATOR_DIR / "build" / "bench_replay"
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, overrides in CONFIGURATIONS.items():
            session = Path(tmp) / f"{name}.session"
            write_session(session, rec, native.params_with(**overrides), net if overrides["use_bias_net"] else None)
            results[name] = measure(binary, session, Path(tmp), name)
            print(f"{name:10s} " + "  ".join(f"{fn} {v['instructions_per_call']:,}/call ({v['calls']} calls)"
                                            for fn, v in results[name].items()))
    robust_nn = results["robust+nn"]["tdoa_update"]["instructions_per_call"]
    summary = {"recording": str(source), "network": "shipped model" if model is not None else "random weights",
               "form": net.form,
               "unit": "x86-64 instructions (callgrind Ir), -O2", "configurations": results,
               "robust_update_with_network_per_call": robust_nn, "target_per_call": TARGET_ROBUST_NN,
               "within_target": robust_nn <= TARGET_ROBUST_NN}
    print(f"robust update incl. network inference: {robust_nn:,} instructions/call "
          f"(target <= {TARGET_ROBUST_NN:,}): {'OK' if robust_nn <= TARGET_ROBUST_NN else 'OVER'}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
