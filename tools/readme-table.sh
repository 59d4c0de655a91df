#!/usr/bin/env bash
# Regenerates the README's `bench all` results table (between its two marker comments) from
# the all.json of every recorded machine, bench/results/*/all.json: no hand-typed figures.
# VKSHADE names the binary (default target/release/vkshade).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${VKSHADE:-target/release/vkshade}
shopt -s nullglob
files=(bench/results/*/all.json)
((${#files[@]})) || { echo "readme-table: no bench/results/*/all.json" >&2; exit 1; }
grep -q '<!-- bench table begin' README.md || { echo "readme-table: no markers in README.md" >&2; exit 1; }
table=$("$bin" bench table "${files[@]}")
TABLE="$table" awk '
  /<!-- bench table begin/ { print; print ENVIRON["TABLE"]; skip = 1; next }
  /<!-- bench table end/ { skip = 0 }
  !skip { print }
' README.md >README.md.tmp
mv README.md.tmp README.md
echo "readme-table: README.md updated from ${files[*]}"
