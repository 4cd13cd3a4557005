#!/usr/bin/env bash
# One-shot, idempotent set-up: Debian packages (Mesa EGL/GL and Vulkan, astcenc, glslang and SPIRV-Cross, ninja, chromium
# for the bench report test, g++ for the fused training kernel),
# a virtual environment in .venv, torch, and bcfpipe with its test extras.
#
#   BCF_TORCH   pip requirement for torch (default: torch==2.13.0, the CPU build).
#               CUDA users: BCF_TORCH=torch (PyPI's default Linux wheel is CUDA),
#               or pre-install the CUDA torch build they want and set BCF_TORCH=skip.
#   BCF_NO_APT  set to 1 to skip the Debian packages (e.g. no root).
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PKGS="libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libvulkan1 mesa-vulkan-drivers astcenc glslang-tools spirv-cross spirv-tools ninja-build chromium g++"
if [[ "${BCF_NO_APT:-0}" != 1 ]] && command -v apt-get >/dev/null; then
  missing=""
  for p in $APT_PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
  done
  if [[ -n "$missing" ]]; then
    SUDO=""; [[ "$(id -u)" != 0 ]] && SUDO="sudo"
    echo "setup: installing Debian packages:$missing" >&2
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
  fi
fi

PY="${PYTHON:-python3}"
if [[ ! -x .venv/bin/python ]]; then
  echo "setup: creating .venv" >&2
  "$PY" -m venv .venv
fi
stamp=.venv/.bcfpipe-setup
want="$(cat pyproject.toml scripts/setup.sh | sha1sum | cut -c1-16)-${BCF_TORCH:-default}"
if [[ -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
  exit 0
fi
TORCH="${BCF_TORCH:-torch==2.13.0}"
if [[ "$TORCH" != skip ]]; then
  echo "setup: installing $TORCH" >&2
  .venv/bin/pip install -q "$TORCH"
fi
echo "setup: installing bcfpipe[dev,ray]" >&2
.venv/bin/pip install -q -e ".[dev,ray]" 2> >(grep -v "is ignored: it is neither a file nor a directory" >&2)
echo "$want" > "$stamp"
