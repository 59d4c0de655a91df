#!/usr/bin/env bash
# Sets up vkshade on a fresh Debian 12 machine with Rust: installs the Debian packages it
# needs (Vulkan driver lavapipe, validation layers, shader tools, data sets), converts the
# test characters to glTF under data/, and builds the release binary. Safe to run again:
# it installs only what is missing and converts only what is out of date.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(
  # Vulkan: loader, software driver (lavapipe), validation layers, vulkaninfo
  libvulkan-dev mesa-vulkan-drivers vulkan-validationlayers vulkan-tools
  # Shaders: shaderc/glslang/SPIRV-Tools static libraries and command-line tools
  libshaderc-dev glslc glslang-tools spirv-tools
  # Plots need a TrueType font
  fonts-dejavu-core
  # Data: skinned characters (+ converter), the Stanford bunny, HDR environment maps
  assimp-utils assimp-testmodels glmark2-data blender-data
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  $sudo apt-get update -q
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
else
  echo "setup: all Debian packages present"
fi

# Test characters: assimp's DirectX files converted to binary glTF (skin, animations and UVs
# kept; vkshade renormalises the skin weights assimp writes unnormalised).
mkdir -p data
convert() {
  local src=$1 dst=$2
  if [ ! -s "$dst" ] || [ "$src" -nt "$dst" ]; then
    echo "setup: converting $src -> $dst"
    assimp export "$src" "$dst.tmp.glb" -f glb2 >/dev/null
    mv "$dst.tmp.glb" "$dst"
  fi
}
convert /usr/share/assimp/models/X/Testwuson.X data/testwuson.glb
convert /usr/share/assimp/models/X/BCN_Epileptic.X data/bcn_epileptic.glb
# The MakeHuman body (Collada, zipped): the SSS issue's second real test case.
convert /usr/share/assimp/models/Collada/human.zae data/human.glb

echo "setup: building vkshade (release)"
cargo build --release --quiet
echo "setup: done"
