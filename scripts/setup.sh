#!/usr/bin/env bash
# One-time (and idempotent) set-up on Debian 12 as root: system packages, then a
# virtual environment .venv/ at the repository root with the project installed
# (editable) and its Python dependencies. A second run only checks and takes seconds.
set -euo pipefail
cd "$(dirname "$0")/.."

# libclang-rt-dev: clang's sanitizer and libFuzzer runtimes (the fuzz test links
# them), which clang alone does not pull in on every Debian 12 image.
APT_PACKAGES=(build-essential gcc-arm-none-eabi libnewlib-arm-none-eabi binutils-arm-none-eabi
              qemu-system-arm clang libclang-rt-dev valgrind)

missing=()
for pkg in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
    echo "setup: installing system packages: ${missing[*]}"
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv"
    "$PYTHON" -m venv .venv
fi
# Reinstall only when the dependency list changed (the stamp holds its hash).
stamp=.venv/.uwb-rig-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || [ ! -x .venv/bin/rig ]; then
    echo "setup: installing Python packages into .venv (torch is the local CPU wheel)"
    # torch first and pinned, so nothing can pull a CUDA build from the index.
    .venv/bin/pip install -q --disable-pip-version-check torch==2.13.0 2>&1 | grep -v "^WARNING: Location" || true
    .venv/bin/pip install -q --disable-pip-version-check -e ".[test]" 2>&1 | grep -v "^WARNING: Location" || true
    .venv/bin/rig --help >/dev/null
    echo "$want" > "$stamp"
fi
echo "setup: ready (.venv/bin/rig)"
