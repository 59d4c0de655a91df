#!/usr/bin/env bash
# Benchmarks on a machine with a GPU but no Rust, no Vulkan loader, no Debian data packages
# and no network (the GPU machines lent to this project's tasks), in two halves:
#
#   tools/bench-gpu.sh prepare DIR      here: a stripped release binary, the Vulkan loader's
#                                       Debian package, the data the benchmarks read and a
#                                       font, into DIR (checked to stay under 60 MiB: a device
#                                       call carries at most 64 MiB)
#   tools/bench-gpu.sh run DIR OUT [ARGS...]
#                                       there: unpacks the loader into a private folder (never
#                                       into /), finds the driver's ICD, runs `vkshade info`
#                                       and `vkshade bench all --json OUT/bench ARGS...`
#                                       (OUT/info.txt, log in OUT/log.txt; bench all writes
#                                       only into a directory of its own, so OUT/bench)
#
# On a lent GPU, from the repository root (DIR inside the repo, git-ignored, then carried):
#   tools/bench-gpu.sh prepare .gpu                (.gpu/ is git-ignored)
#   device run: tools/bench-gpu.sh run .gpu $OUT      (carry: [".gpu"])
# CI runs `prepare` and then `run ... --quick --validate` on lavapipe (.ci/run).
set -euo pipefail

usage() {
  sed -n '2,20p' "$0" >&2
  exit 2
}

die() {
  echo "bench-gpu: $*" >&2
  exit 1
}

# Inputs the benchmarks read, relative to / (absolute ones) or to the repository (data/).
SYSTEM_DATA=(
  usr/share/glmark2/models/bunny.obj
  usr/share/blender/datafiles/studiolights/world/forest.exr
)
REPO_DATA=(
  data/testwuson.glb
  data/bcn_epileptic.glb
)
FONT=/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf
LIMIT_MIB=60

prepare() {
  local dir=$1 repo
  repo=$(cd "$(dirname "$0")/.." && pwd)
  mkdir -p "$dir"
  dir=$(cd "$dir" && pwd)
  rm -rf "$dir/debs" "$dir/root" "$dir/vkshade"
  mkdir -p "$dir/debs" "$dir/root"

  (cd "$repo" && cargo build --release --bin vkshade) || die "release build failed"
  # Debug info is most of the release binary (~75 MB with it): strip it.
  strip -o "$dir/vkshade" "$repo/target/release/vkshade" || die "strip failed (binutils)"

  # The Vulkan loader (the GPU machine has the driver and its ICD, no loader), and libglvnd:
  # NVIDIA's Vulkan ICD is libGLX_nvidia.so.0, which needs libglvnd's libraries. Without them
  # the loader reports "Could not get 'vkCreateInstance' via 'vk_icdGetInstanceProcAddr'" and
  # finds no driver; with libglvnd0 and libglx0 alone it still found none on an H200 machine.
  # This set is the one that worked there (which of the last four it needs is not
  # established). x86-64 packages whatever this machine is: the GPU machines are x86-64.
  local pkgs=(libvulkan1 libglvnd0 libglx0 libegl1 libgl1 libopengl0 libgles2)
  local lists=/tmp/bench-gpu-apt-lists
  local o=(-o APT::Architecture=amd64 -o APT::Architectures=amd64 -o "Dir::State::Lists=$lists")
  if ! (cd "$dir/debs" && apt-get "${o[@]}" download "${pkgs[@]}" >/dev/null 2>&1); then
    mkdir -p "$lists/partial"
    apt-get "${o[@]}" update >/dev/null || die "apt-get update for amd64 lists failed"
    (cd "$dir/debs" && apt-get "${o[@]}" download "${pkgs[@]}") ||
      die "could not download ${pkgs[*]} (network, apt sources)"
  fi

  local f
  for f in "${SYSTEM_DATA[@]}"; do
    [[ -f /$f ]] || die "/$f is missing (tools/setup.sh installs it)"
    mkdir -p "$dir/root/$(dirname "$f")"
    cp "/$f" "$dir/root/$f"
  done
  for f in "${REPO_DATA[@]}"; do
    [[ -f $repo/$f ]] || die "$repo/$f is missing (tools/setup.sh converts it)"
    mkdir -p "$dir/root/$(dirname "$f")"
    cp "$repo/$f" "$dir/root/$f"
  done
  [[ -f $FONT ]] || die "$FONT is missing (fonts-dejavu-core)"
  cp "$FONT" "$dir/root/font.ttf"

  local kib
  kib=$(du -sk "$dir" | cut -f1)
  echo "bench-gpu: prepared $dir: $((kib / 1024)) MiB ($(du -sh "$dir/vkshade" | cut -f1) binary)"
  ((kib <= LIMIT_MIB * 1024)) || die "$dir is $((kib / 1024)) MiB, over the ${LIMIT_MIB} MiB a device call can carry"
}

run() {
  local dir=$1 out=$2
  shift 2
  [[ -x $dir/vkshade ]] || die "$dir/vkshade missing: run 'tools/bench-gpu.sh prepare $dir' first"
  dir=$(cd "$dir" && pwd)
  mkdir -p "$out"
  out=$(cd "$out" && pwd)

  # The carried loader, unpacked privately (dpkg -x into / can break a machine).
  SYS=$(mktemp -d /tmp/bench-gpu-sys.XXXXXX)
  trap 'rm -rf "$SYS"' EXIT
  local deb
  for deb in "$dir"/debs/*.deb; do
    [[ -e $deb ]] || die "no loader package in $dir/debs"
    dpkg -x "$deb" "$SYS"
  done
  export LD_LIBRARY_PATH="$SYS/usr/lib/x86_64-linux-gnu${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"

  # The NVIDIA driver's ICD where the loader does not look by itself.
  local nv=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  if [[ -z ${VK_DRIVER_FILES:-} && -f $nv ]] &&
    ! ls /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json >/dev/null 2>&1; then
    export VK_DRIVER_FILES=$nv
  fi
  export VKSHADE_FONT="$dir/root/font.ttf"

  "$dir/vkshade" info >"$out/info.txt" 2>&1 || {
    cat "$out/info.txt" >&2
    die "vkshade info failed: no Vulkan device (see $out/info.txt)"
  }
  local start=$SECONDS
  set -o pipefail
  "$dir/vkshade" bench all --json "$out/bench" --data-root "$dir/root" "$@" 2>&1 | tee "$out/log.txt"
  echo "bench-gpu: bench all took $((SECONDS - start)) s; results in $out/bench"
}

[[ $# -ge 2 ]] || usage
case $1 in
prepare) prepare "$2" ;;
run)
  [[ $# -ge 3 ]] || usage
  shift
  run "$@"
  ;;
*) usage ;;
esac
