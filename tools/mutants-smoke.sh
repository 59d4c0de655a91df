#!/usr/bin/env bash
# A small, fixed set of mutants that CI plants by hand (no cargo-mutants install): each entry of
# tools/mutants-smoke.txt names a file, an exact line fragment of it, its replacement and the
# tests that must fail with it. In a copy of the tree that keeps file times (cp -a, so only
# vkshade rebuilds, incrementally), the unmutated copy must pass every entry's tests; then
# each mutant is planted alone, must build, and must make its tests fail.
#
# Exits non-zero when a mutant survives, does not build, or its original text is not found
# exactly once (the list cannot rot silently when the code it names changes). The full runs
# are cargo-mutants' (see .cargo/mutants.toml); this is the part cheap enough for every CI run.
#
# Usage: tools/mutants-smoke.sh [LIST]   (default tools/mutants-smoke.txt)
# Keeps the copy when VKSHADE_MUTANTS_KEEP is set (its path is printed).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
list=${1:-tools/mutants-smoke.txt}
start=$(date +%s)

# The list: blocks of `file:`, `from:`, `to:`, `test:` lines (the value is everything after the
# first ": ", leading spaces included), blocks separated by blank lines, `#` lines ignored.
files=() froms=() tos=() tests=()
file='' from='' to='' test='' have_from=0 have_to=0
flush() {
  if [ -n "$file$test" ] || [ "$have_from$have_to" != 00 ]; then
    if [ -z "$file" ] || [ -z "$test" ] || [ "$have_from$have_to" != 11 ] || [ -z "$from" ]; then
      echo "mutants-smoke: $list: an entry lacks file:, from:, to: or test: (file '$file')" >&2
      exit 2
    fi
    files+=("$file") froms+=("$from") tos+=("$to") tests+=("$test")
  fi
  file='' from='' to='' test='' have_from=0 have_to=0
}
while IFS= read -r line || [ -n "$line" ]; do
  case "$line" in
    '#'*) ;;
    '') flush ;;
    'file: '*) file=${line#file: } ;;
    'from: '*) from=${line#from: } have_from=1 ;;
    'to: '*) to=${line#to: } have_to=1 ;;
    'test: '*) test=${line#test: } ;;
    *)
      echo "mutants-smoke: $list: cannot read the line '$line'" >&2
      exit 2
      ;;
  esac
done <"$list"
flush
if [ "${#files[@]}" -eq 0 ]; then
  echo "mutants-smoke: $list holds no mutants" >&2
  exit 2
fi

# Every original text must be found exactly once before anything is built.
for i in "${!files[@]}"; do
  f=${files[$i]}
  if [ ! -f "$f" ]; then
    echo "mutants-smoke: mutant $((i + 1)): no file $f" >&2
    exit 1
  fi
  n=$(grep -cF -- "${froms[$i]}" "$f" || true)
  if [ "$n" != 1 ]; then
    echo "mutants-smoke: mutant $((i + 1)): '${froms[$i]}' found on $n lines of $f (need 1)" >&2
    exit 1
  fi
done

# The copy: the sources, and target/release's dependencies (times kept, so they stay fresh).
work=$(mktemp -d "${TMPDIR:-/tmp}/vkshade-mutants-smoke.XXXXXX")
if [ -z "${VKSHADE_MUTANTS_KEEP:-}" ]; then
  trap 'rm -rf "$work"' EXIT
fi
for entry in "$root"/* "$root"/.cargo; do
  case "$(basename "$entry")" in target) continue ;; esac
  cp -a "$entry" "$work/"
done
# The dependencies are hard links (instant; a fresh dependency is never written, and a
# dependency that compiles here fails the run, below). vkshade's own entries are copied (its
# build script's output among them, which a rerun writes), bar its build outputs in deps/
# (gigabytes of test binaries), which every build here makes anew.
rel="$root/target/release"
if [ -d "$rel" ]; then
  for sub in deps build .fingerprint; do
    [ -d "$rel/$sub" ] || continue
    mkdir -p "$work/target/release/$sub"
    find "$rel/$sub" -mindepth 1 -maxdepth 1 ! -name '*vkshade*' \
      ! \( -type f -executable ! -name '*.*' \) -print0 |
      xargs -0 -r cp -al -t "$work/target/release/$sub"
    [ "$sub" = deps ] && continue
    find "$rel/$sub" -mindepth 1 -maxdepth 1 -name '*vkshade*' -print0 |
      xargs -0 -r cp -a -t "$work/target/release/$sub"
  done
fi
echo "mutants-smoke: copied the tree to $work in $(( $(date +%s) - start )) s"
cd "$work"
export CARGO_INCREMENTAL=1
# vkshade alone at opt-level 0 without debug info (its dependencies keep the release
# profile's, so none rebuilds): an incremental rebuild takes seconds, and Rust's float
# arithmetic does not depend on the optimisation level, so the tests' verdicts do not either.
cargo_cfg=(--config 'profile.release.package.vkshade.opt-level=0'
  --config 'profile.release.package.vkshade.debug=false')

# `test:` is a cargo test argument list (e.g. `--lib -- kernels::sss::sampler`); word-split.
run_tests() {
  local -a args
  read -r -a args <<<"$1"
  cargo test --release "${cargo_cfg[@]}" "${args[@]}"
}
# A dependency compiled here would have written through its hard links into the tree's own
# target/: stop (it means the copy was not fresh, which this script relies on).
no_dependency_built() {
  if grep -E '^ *Compiling ' "$1" | grep -vE '^ *Compiling vkshade '; then
    echo "mutants-smoke: a dependency was rebuilt in the copy (see above): target/release is stale; run cargo build --release first" >&2
    exit 1
  fi
}
build_tests() {
  local -a args=() before=()
  read -r -a args <<<"$1"
  for a in "${args[@]}"; do
    [ "$a" = -- ] && break
    before+=("$a")
  done
  cargo test --release "${cargo_cfg[@]}" --no-run "${before[@]}"
}

# The unmutated copy passes every distinct test command.
declare -A seen=()
for t in "${tests[@]}"; do
  [ -n "${seen[$t]:-}" ] && continue
  seen[$t]=1
  t0=$(date +%s)
  if ! run_tests "$t" >"$work/baseline.log" 2>&1; then
    no_dependency_built "$work/baseline.log"
    tail -40 "$work/baseline.log" >&2
    echo "mutants-smoke: the unmutated tree fails: cargo test --release $t" >&2
    exit 1
  fi
  no_dependency_built "$work/baseline.log"
  echo "mutants-smoke: unmutated: cargo test --release $t passed ($(( $(date +%s) - t0 )) s)"
done

survivors=0
for i in "${!files[@]}"; do
  f=${files[$i]} from=${froms[$i]} to=${tos[$i]} t=${tests[$i]}
  t0=$(date +%s)
  cp -p "$f" "$work/original"
  content=$(cat "$f"; echo x)
  content=${content%x}
  # Literal (quoted) pattern: the first and only occurrence.
  printf '%s' "${content/"$from"/"$to"}" >"$f"
  label=${to#"${to%%[![:space:]]*}"}
  label="mutant $((i + 1)) ($f: '${from#"${from%%[![:space:]]*}"}' -> '${label:0:60}')"
  build_ok=1
  build_tests "$t" >"$work/mutant.log" 2>&1 || build_ok=0
  no_dependency_built "$work/mutant.log"
  if [ "$build_ok" = 0 ]; then
    tail -30 "$work/mutant.log" >&2
    echo "mutants-smoke: $label does not build: fix the list" >&2
    exit 1
  fi
  if run_tests "$t" >"$work/mutant.log" 2>&1; then
    echo "mutants-smoke: $label SURVIVED: cargo test --release $t passed" >&2
    survivors=$((survivors + 1))
  else
    failed=$(grep -E '^test .* FAILED$|^    [a-z_:]+$' "$work/mutant.log" | head -3 | tr -s ' \n' ' ')
    echo "mutants-smoke: $label caught ($(( $(date +%s) - t0 )) s):$failed"
  fi
  # Restored with a new time, so the next build sees the change back.
  cat "$work/original" >"$f"
done

echo "mutants-smoke: ${#files[@]} mutants, $survivors survived, $(( $(date +%s) - start )) s"
[ "$survivors" -eq 0 ]
