#!/usr/bin/env bash
# Build diffkfc for NVIDIA GPUs without CubeCL's LLVM bundle (which cubecl-llvm's build script
# downloads from GitHub; machines that reach only the package registries cannot fetch it):
#   scripts/build-cuda-nvrtc.sh [EXTRA FEATURES, e.g. diffkfc/wgpu]
# The `cuda-nvrtc` feature compiles kernels with NVRTC (CUDA C++) at run time, so LLVM is never
# called; its C API is still referenced by cubecl-cuda's LLVM path, and those symbols are linked
# to stubs that abort with a message naming the function. Needs libnvrtc where it runs.
# Writes target/release/diffkfc (CARGO_TARGET_DIR is honoured).
set -euo pipefail
cd "$(dirname "$0")/.."
features="diffkfc/cuda-nvrtc${1:+,$1}"
target="${CARGO_TARGET_DIR:-target}"
export DOCS_RS=1  # cubecl-llvm and tracel-llvm-bundler skip the download and the LLVM link
# Builds every dependency; the first link fails on the LLVM symbols, named below.
cargo build --release -p diffkfc --features "$features" 2>/dev/null || true
mkdir -p "$target/llvm-stub"
stub=$(cd "$target/llvm-stub" && pwd)
nm -u "$target"/release/deps/lib{cubecl_llvm,pliron_llvm,llvm_sys}-*.rlib 2>/dev/null \
  | awk '$2 ~ /^(LLVM|cubecl_(free_message|link_device_bitcode|set_llvm_option)$)/ {print $2}' \
  | sort -u > "$stub/symbols.txt"
[ -s "$stub/symbols.txt" ] || { echo "error: no LLVM symbols found in $target/release/deps" >&2; exit 1; }
{
  printf '#include <stdio.h>\n#include <stdlib.h>\n'
  printf 'static void stub(const char *f) { fprintf(stderr, "diffkfc was built without LLVM (scripts/build-cuda-nvrtc.sh): %%s called\\n", f); abort(); }\n'
  awk '{printf "void %s(void) { stub(\"%s\"); }\n", $1, $1}' "$stub/symbols.txt"
} > "$stub/stub.c"
cc -O1 -fPIC -c "$stub/stub.c" -o "$stub/stub.o"
ar rcs "$stub/libllvmstub.a" "$stub/stub.o"
cargo rustc --release -p diffkfc --bin diffkfc --features "$features" -- -C link-arg="$stub/libllvmstub.a"
echo "built $target/release/diffkfc with $features ($(wc -l < "$stub/symbols.txt") LLVM symbols stubbed)"
