#!/usr/bin/env bash
# Shows that the library a renderer links (`default-features = false`) builds, links and runs
# on a machine without shaderc and glslang (libshaderc-dev, glslang-dev): hides every file of
# those packages in a private mount namespace (nothing outside this script sees it; nothing is
# uninstalled), then builds the library, links the quickstart example and runs it on the
# SPIR-V embedded at build time. SPIRV-Tools (package spirv-tools) stays: the library
# validates every module with it.
#
# Needs root (unshare -m). Cleans vkshade's own release artifacts first, so its build script
# runs again while the libraries are hidden (nothing of vkshade built while they were visible
# is reused); the dependencies' artifacts are shared with the other release builds (none of
# them is shaderc: the check below says so).
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "${1:-}" != "--inside" ]; then
  if ! unshare -m true 2>/dev/null; then
    echo "check-no-shaderc: needs a private mount namespace (run as root: unshare -m)" >&2
    exit 1
  fi
  exec unshare -m --propagation private "$0" --inside
fi

# Inside the namespace. The files to hide: those the shaderc and glslang packages install
# (dpkg), else the usual library and header names.
packages=(libshaderc-dev libshaderc1 glslang-dev glslang-tools glslc)
files=()
if command -v dpkg-query >/dev/null; then
  for p in "${packages[@]}"; do
    dpkg-query -W "$p" >/dev/null 2>&1 || continue
    while IFS= read -r f; do
      [ -f "$f" ] && [ ! -L "$f" ] && files+=("$f")
    done < <(dpkg-query -L "$p")
  done
fi
for dir in /usr/lib/*-linux-gnu /usr/lib64 /usr/lib /usr/local/lib; do
  for f in "$dir"/lib{shaderc,glslang,SPIRV,MachineIndependent,GenericCodeGen,OSDependent,OGLCompiler}[._-]*; do
    case "$f" in */libSPIRV-Tools*) continue ;; esac
    [ -f "$f" ] && [ ! -L "$f" ] && files+=("$f")
  done
done
for f in "${files[@]}"; do
  mount --bind /dev/null "$f"
done
for d in /usr/include/shaderc /usr/include/glslang /usr/local/include/shaderc \
  /usr/local/include/glslang; do
  [ -d "$d" ] && mount -t tmpfs none "$d"
done
echo "check-no-shaderc: hid ${#files[@]} files of ${packages[*]}"
# The hiding worked: no glslang archive, shaderc library or header is readable any more.
for f in /usr/lib/*-linux-gnu/libglslang.a /usr/lib/*-linux-gnu/libSPIRV.a \
  /usr/lib/*-linux-gnu/libshaderc_combined.a /usr/lib/*-linux-gnu/libshaderc.so.1 \
  /usr/include/shaderc/shaderc.h /usr/include/glslang/Public/ShaderLang.h; do
  if [ -s "$f" ]; then
    echo "check-no-shaderc: $f is still visible" >&2
    exit 1
  fi
done

target=target
if cargo tree --no-default-features -e normal,build --prefix none | grep -E '^shaderc'; then
  echo "check-no-shaderc: the no-default-features library depends on shaderc" >&2
  exit 1
fi
cargo clean --release --target-dir "$target" -p vkshade
# vkshade itself at opt-level 0 without debug info (its dependencies as the release build
# left them): what is checked is that its build script, compile and link need no shaderc or
# glslang, which the optimisation level does not change (2 min at the release profile's
# settings on a loaded 2-core VM, 40 s this way).
cargo build --release --target-dir "$target" --no-default-features --lib --example quickstart \
  --config 'profile.release.package.vkshade.opt-level=0' \
  --config 'profile.release.package.vkshade.debug=false'
"$target/release/examples/quickstart"
echo "check-no-shaderc: the library builds, links and runs without shaderc and glslang"
