#!/usr/bin/env bash
# libtorch for the `tch` feature of nodes/unet (burn-tch 0.22.1), from PyPI: no system install,
# works on CPU-only machines and on GPU machines.
#
#   scripts/libtorch.sh [DIR]          # installs into DIR (default ~/.cache/deep-contact/libtorch)
#   source <(scripts/libtorch.sh --env [DIR])
#   cargo build -p unet --features tch
#   dc-unet bench --devices flex,libtorch      # or cuda on a GPU machine
#
# burn-tch 0.22.1 expects PyTorch 2.9; the torch 2.11.0 wheel (a CUDA 13 build) works with the
# version check bypassed. torch-sys links libtorch.so, which needs libtorch_cuda.so and through it
# the CUDA libraries even on a CPU-only machine: the CUDA wheels torch itself requires are
# installed (about 3 GB), without torch's Python dependencies (`--no-deps` on torch).
set -euo pipefail
env_only=false
if [[ "${1:-}" == "--env" ]]; then env_only=true; shift; fi
dir="${1:-$HOME/.cache/deep-contact/libtorch}"
torch_version="${TORCH_VERSION:-2.11.0}"
if ! $env_only; then
  python3 -m pip install --disable-pip-version-check --no-deps --target "$dir" "torch==${torch_version}" >&2
  # The CUDA libraries this torch build names (its METADATA), with their own dependencies.
  mapfile -t cuda < <(sed -n 's/^Requires-Dist: \(\(cuda-toolkit\|nvidia-\)[^;]*\);.*Linux.*/\1/p' \
    "$dir"/torch-"${torch_version}".dist-info/METADATA | tr -d ' ')
  python3 -m pip install --disable-pip-version-check --target "$dir" --upgrade "${cuda[@]}" >&2
fi
libs="$dir/torch/lib"
for d in "$dir"/nvidia/*/lib "$dir"/nvidia/*/*/lib; do [[ -d "$d" ]] && libs="$libs:$d"; done
cat <<ENV
export LIBTORCH="$dir/torch"
export LIBTORCH_BYPASS_VERSION_CHECK=1
export LD_LIBRARY_PATH="$libs\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
ENV
