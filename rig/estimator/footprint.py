"""Flash, RAM and stack of the estimator built for the Cortex-M4F (STM32F405).

Flash and static RAM come from `arm-none-eabi-size` of a minimal image that links
the whole estimator (weights included, as const data in flash) minus the same
image without it, so library code the estimator pulls in is counted. Stack comes
from GCC's `-fstack-usage`: the worst chain of frames through the estimator's
call graph (the functions and their callees are listed in CALL_GRAPH)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from rig.estimator.native import ESTIMATOR_DIR, FIRMWARE_ELF, make

BUILD = ESTIMATOR_DIR / "build" / "arm"

# Who calls whom inside the estimator (static functions included); leaves omitted.
CALL_GRAPH = {
    "est_handle_event": ["step", "add_imu", "queue_tdoa", "est_reset", "est_get_output", "reject"],
    "step": ["ekf_predict", "tdoa_update", "reset_after_divergence", "ekf_grow_uncertainty",
             "ekf_condition_covariance", "ekf_is_diverged"],
    "reset_after_divergence": ["est_reset"],
    "est_reset": ["quat_to_rot"],
    "ekf_predict": ["propagate_covariance", "quat_rotate_body", "quat_to_rot", "ekf_grow_uncertainty",
                    "ekf_condition_covariance"],
    "propagate_covariance": ["ekf_transition_blocks"],
    "tdoa_update": ["tdoa_predict", "bn_features", "bn_predict", "ekf_innovation_variance",
                    "ekf_robust_scalar_update", "ekf_scalar_update", "ekf_condition_covariance"],
    "bn_features": ["azimuth_elevation"],
    "azimuth_elevation": ["fast_atan2f"],
    "bn_predict": ["pair_predict", "link_predict"],
    "pair_predict": ["dense_relu", "linear_out"],
    "link_predict": ["bn_link_bias"],
    "bn_link_bias": ["dense_relu", "linear_out"],
    "ekf_robust_scalar_update": ["cholesky_lower", "whiten", "gm_weight", "reweighted_gain_column",
                                 "ekf_scalar_update", "ekf_apply_error"],
    "ekf_scalar_update": ["ekf_apply_error"],
    "ekf_apply_error": ["quat_rotate_body", "quat_to_rot"],
}
ENTRY = "est_handle_event"


def _size(elf: Path) -> dict[str, int]:
    out = subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True, check=True).stdout
    text, data, bss = (int(v) for v in out.splitlines()[1].split()[:3])
    return {"text": text, "data": data, "bss": bss}


def stack_frames() -> dict[str, int]:
    """Frame size per function from the .su files of the estimator objects."""
    frames: dict[str, int] = {}
    for su in BUILD.glob("*.su"):
        if su.name.startswith("footprint"):
            continue
        for line in su.read_text().splitlines():
            location, size, _ = line.split("\t")
            function = location.rsplit(":", 1)[-1]
            frames[function] = max(frames.get(function, 0), int(size))
    return frames


def worst_stack(frames: dict[str, int], entry: str = ENTRY) -> tuple[int, list[str]]:
    """Deepest sum of frames from `entry` along CALL_GRAPH (which has no cycles)."""
    best, path = 0, []
    for callee in CALL_GRAPH.get(entry, []):
        depth, sub = worst_stack(frames, callee)
        if depth > best:
            best, path = depth, sub
    return frames.get(entry, 0) + best, [entry, *path]


FIRMWARE_RAM = 128 * 1024
FIRMWARE_FLASH = 1024 * 1024


def firmware() -> dict:
    """The whole STM32F405 firmware image (-O2): estimator, service, protocol, board glue."""
    make("firmware")
    size = _size(FIRMWARE_ELF)
    return {"flash": size["text"] + size["data"], "ram": size["data"] + size["bss"], **size,
            "image": str(FIRMWARE_ELF.relative_to(ESTIMATOR_DIR)),
            "compiler_flags": "-mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard -O2",
            "device": {"flash": FIRMWARE_FLASH, "ram": FIRMWARE_RAM}}


def measure() -> dict:
    make("footprint", "arm")
    with_est = _size(BUILD / "footprint_with.elf")
    without = _size(BUILD / "footprint_without.elf")
    frames = stack_frames()
    stack, chain = worst_stack(frames)
    flash = (with_est["text"] + with_est["data"]) - (without["text"] + without["data"])
    static_ram = (with_est["data"] + with_est["bss"]) - (without["data"] + without["bss"])
    objects = {o.stem: _size(o) for o in sorted(BUILD.glob("*.o"))}
    return {
        "estimator": {
            "flash": flash,
            "ram": static_ram + stack,
            "static_ram": static_ram,
            "stack": stack,
            "stack_chain": chain,
            "objects": objects,
            "compiler_flags": "-mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard -Os",
            "budget": {"flash": 13 * 1024, "ram": 12 * 1024},
        },
        "firmware": firmware(),
    }
