#!/usr/bin/env bash
# `make portable`: FlowClip for other x86-64 CPUs than the build machine's
# (a farm node, a container host). Builds the executable once per x86-64
# level into DIR/LEVEL/, then installs DIR/bin/flowclip-LEVEL and the
# launcher DIR/bin/flowclip, which runs the best level the CPU has
# (docs/portable.md). Checks that no executable holds instructions beyond
# its level, the reason for the exercise.
#   tools/build_portable.sh [DIR] [JOBS]
set -euo pipefail
dir=${1:-build-portable}
jobs=${2:-$(nproc)}
levels=(x86-64-v3 x86-64-v4)
mkdir -p "$dir/bin"
for level in "${levels[@]}"; do
  echo "portable: building $level in $dir/$level" >&2
  cmake -S server -B "$dir/$level" -G Ninja -DCMAKE_BUILD_TYPE=Release -DFLOWCLIP_NATIVE=OFF \
    -DFLOWCLIP_ARCH="$level" ${CMAKE_FLAGS:-} >/dev/null
  cmake --build "$dir/$level" --target flowclip flowclip_launcher -j "$jobs"
done

# A level's instructions only: no AVX-512 register below v4, no AVX one in the launcher.
uses() { objdump -d --no-show-raw-insn "$1" | grep -c -E "$2" || true; }
if [ "$(uses "$dir/x86-64-v3/flowclip" '%zmm|%k[1-7]')" != 0 ]; then
  echo "portable: $dir/x86-64-v3/flowclip uses AVX-512 instructions" >&2
  exit 1
fi
if [ "$(uses "$dir/x86-64-v3/flowclip_launcher" '%ymm|%zmm')" != 0 ]; then
  echo "portable: the launcher uses AVX instructions" >&2
  exit 1
fi
if [ "$(uses "$dir/x86-64-v4/flowclip" '%zmm')" = 0 ]; then
  echo "portable: $dir/x86-64-v4/flowclip has no AVX-512 path: was it built for its level?" >&2
  exit 1
fi

# Installed together, each replaced whole.
for level in "${levels[@]}"; do
  install -m 755 "$dir/$level/flowclip" "$dir/bin/.flowclip-$level.tmp"
  mv -f "$dir/bin/.flowclip-$level.tmp" "$dir/bin/flowclip-$level"
done
install -m 755 "$dir/x86-64-v3/flowclip_launcher" "$dir/bin/.flowclip.tmp"
mv -f "$dir/bin/.flowclip.tmp" "$dir/bin/flowclip"
"$dir/bin/flowclip" --version >/dev/null
echo "portable: $dir/bin/flowclip (the launcher) and$(printf ' flowclip-%s' "${levels[@]}")" >&2
