#!/usr/bin/env bash
# Runs the cargo-fuzz targets (fuzz/) one after another, each for SECONDS (default 60), and
# prints a table: executions, coverage (libFuzzer's edge count `cov` and feature count `ft`)
# at the end, `cov` when half the executions had run (the second half's growth shows a
# plateau), the execution at which coverage last grew, corpus size and crashes. A target
# with a dictionary (dicts/TARGET.dict: keys, chunk names, magics) runs with it.
#   tools/fuzz.sh [SECONDS] [TARGET...]      (default: every target)
# Leak detection is off: a thread-local's destructor registered by glibc the first time an
# input reaches it (32 bytes in __cxa_thread_atexit_impl) reads as a leak of that input, and
# replaying the input alone reports nothing; and at exit the exr crate's decoding threads are
# still alive (their stacks read as leaked). A leak in safe Rust is not a crash anyway.
# Needs the nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`). The growing corpus
# lives in fuzz/corpus/TARGET (not committed); the committed seeds in fuzz/seeds/TARGET; a
# crash lands in fuzz/artifacts/TARGET and belongs, once fixed, in fuzz/regressions/TARGET
# (replayed by tests/fuzz_corpus.rs). Limits: 10 s per input (a hang; see
# VKSHADE_FUZZ_TIMEOUT below), 2 GiB RSS, and no single allocation above 512 MiB from an
# input of at most 64 KiB (unbounded allocation).
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
secs=${1:-60}
# libFuzzer's timeout is wall-clock: a run at low priority beside builds and tests is
# starved, and a 0.4 s input then reads as a 10 s hang. VKSHADE_FUZZ_TIMEOUT raises it for
# such runs (a timeout artifact is then replayed alone: `target/.../release/TARGET FILE`).
timeout=${VKSHADE_FUZZ_TIMEOUT:-10}
shift || true
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    targets=(gltf obj off ply sph envmap transfer btf_json btf_dir btf_image)
fi
# One build, then the binaries run directly: `cargo fuzz run` would rebuild (about 11
# CPU-minutes of ASan compilation) whenever the library's sources changed mid-campaign.
# VKSHADE_FUZZ_NO_BUILD=1 runs the binaries as they are (another run is building or has built).
if [ -z "${VKSHADE_FUZZ_NO_BUILD:-}" ]; then
    cargo +nightly fuzz build -O >/dev/null 2>&1 || cargo +nightly fuzz build -O
fi
bin_dir=target/x86_64-unknown-linux-gnu/release
mkdir -p logs
# Seeds from the installed data packages (assimp-testmodels, blender-data, every PNG/JPEG
# under /usr/share), added to the target's corpus once: real files of every variant the
# packages hold reach far more of a loader than the few committed seeds, so coverage
# starts high and its plateau comes sooner. Files above the 64 KiB input limit are skipped;
# a target whose input starts with a selector byte gets that byte in front.
package_seeds() {
    local t=$1 dir="corpus/$1" marker="corpus/$1/.package-seeds"
    [ -e "$marker" ] && return 0
    add() { # PREFIX FILE... (PREFIX: hex bytes, e.g. "02" or "010002"; a % in it is
        # replaced by 00 and 01 in turn, so that seeds alternate between two values)
        local prefix=$1 f n=0 p
        shift
        for f in "$@"; do
            [ -f "$f" ] && [ "$(stat -c %s "$f")" -lt 65535 ] || continue
            p=${prefix//%/0$((n % 2))}
            { [ -n "$p" ] && printf "$(printf '%s' "$p" | sed 's/../\\x&/g')"; cat "$f"; } \
                >"$dir/pkg-$(printf '%s' "$f" | md5sum | cut -c1-12)"
            n=$((n + 1))
        done
    }
    # Every 'step'-th of a sorted list, at most 'max' files (the PNGs number thousands).
    spread() { # MAX then paths on stdin
        awk -v max="$1" '{a[NR] = $0} END {s = NR > max ? NR / max : 1;
            for (i = 1; i <= NR; i += s) print a[int(i)]}'
    }
    local assimp=/usr/share/assimp/models
    case $t in
    gltf) mapfile -t f < <(find "$assimp" -iname '*.gltf' -o -iname '*.glb' | sort); add "" "${f[@]}" ;;
    obj) mapfile -t f < <(find "$assimp" -iname '*.obj' | sort); add "" "${f[@]}" ;;
    off) mapfile -t f < <(find "$assimp" -iname '*.off' | sort); add "" "${f[@]}" ;;
    ply) mapfile -t f < <(find "$assimp" -iname '*.ply' | sort); add "" "${f[@]}" ;;
    envmap)
        mapfile -t f < <(find /usr/share -iname '*.exr' 2>/dev/null | sort); add 01 "${f[@]}"
        mapfile -t f < <(find /usr/share -iname '*.hdr' 2>/dev/null | sort); add 00 "${f[@]}" ;;
    btf_image)
        # Small images only (a 64 KiB PNG decodes ~100x slower than a seed under ASan, and
        # the executions per second fell from ~2500 to 14); the EXR decoder is `envmap`'s.
        mapfile -t f < <(find /usr/share -iname '*.png' -size -16k 2>/dev/null | sort | spread 60)
        add 00 "${f[@]}"
        mapfile -t f < <(find /usr/share -iname '*.jp*g' -size -16k 2>/dev/null | sort)
        add 02 "${f[@]}" ;;
    btf_dir)
        # btf_image's seeds, each as the image of slot 0 (the first image decoded: it sets
        # the size every other image is checked against) or slot 1, in turn. Without them
        # the target starts from two tiny PNGs and, at about 4 executions a second (6,561
        # files per input), spends hours rediscovering the decoders that btf_image covers.
        mapfile -t f < <(find /usr/share -iname '*.png' -size -16k 2>/dev/null | sort | spread 60)
        add %0000 "${f[@]}"
        mapfile -t f < <(find /usr/share -iname '*.jp*g' -size -16k 2>/dev/null | sort)
        add %0002 "${f[@]}" ;;
    esac
    touch "$marker"
}
# btf_dir's inputs are btf_image's behind two slot bytes (slot 0, whose image sets the size
# every other image is checked against, or slot 1, by the input's hash): btf_image's corpus,
# explored at thousands of executions a second, is added to btf_dir's before each of its
# runs (each input once), so that btf_dir's few executions a second go to the directory
# logic rather than to rediscovering the decoders. Run btf_image first.
btf_image_into_btf_dir() {
    local f h n=0
    for f in corpus/btf_image/* seeds/btf_image/*; do
        [ -f "$f" ] && [ "$(stat -c %s "$f")" -le 65533 ] || continue
        h=$(md5sum <"$f" | cut -c1-12)
        [ -e "corpus/btf_dir/img-$h" ] && continue
        { printf "\\x0$(( 0x${h:0:1} % 2 ))\\x00"; cat "$f"; } >"corpus/btf_dir/img-$h"
        n=$((n + 1))
    done
    [ "$n" -eq 0 ] || echo "    btf_dir: $n input(s) added from btf_image's corpus" >&2
}
printf '%-9s %6s %10s %6s %8s %7s %14s %7s %s\n' target secs execs cov cov-half ft "last-new-cov" corpus crashes
status=0
for t in "${targets[@]}"; do
    mkdir -p "corpus/$t" "artifacts/$t"
    package_seeds "$t"
    [ "$t" != btf_dir ] || btf_image_into_btf_dir
    log="logs/$t.log"
    set +e
    dict=()
    if [ -f "dicts/$t.dict" ]; then
        dict=(-dict="dicts/$t.dict")
    fi
    ASAN_OPTIONS=detect_leaks=0 "$bin_dir/$t" "${dict[@]}" \
        -max_total_time="$secs" -timeout="$timeout" -rss_limit_mb=2048 -malloc_limit_mb=512 \
        -detect_leaks=0 \
        -max_len=65536 -print_final_stats=1 -artifact_prefix="artifacts/$t/" \
        "corpus/$t" "seeds/$t" >"$log" 2>&1
    rc=$?
    set -e
    execs=$(grep -o 'stat::number_of_executed_units: [0-9]*' "$log" | awk '{print $2}' | tail -1)
    last=$(grep -E '^#[0-9]+.*(NEW|REDUCE) +cov' "$log" | tail -1)
    cov=$(grep -oE 'cov: [0-9]+' "$log" | tail -1 | awk '{print $2}')
    ft=$(grep -oE 'ft: [0-9]+' "$log" | tail -1 | awk '{print $2}')
    lastn=$(echo "$last" | grep -oE '^#[0-9]+' | tr -d '#')
    # Coverage when half the executions had run: the growth over the second half says
    # whether the run reached a plateau.
    half=$(grep -E '^#[0-9]+.*cov: [0-9]+' "$log" | awk -v h="$(( ${execs:-0} / 2 ))" \
        '{n = substr($1, 2) + 0; if (n <= h) for (i = 1; i < NF; i++) if ($i == "cov:") c = $(i + 1)}
         END {print c}')
    # Crashes, out-of-memory, leaks and timeouts; libFuzzer's slow-unit files (inputs slower
    # than 10 s, which a starved run writes for quick inputs) are listed apart.
    crashes=$(find "artifacts/$t" -type f ! -name 'slow-unit-*' | wc -l)
    slow=$(find "artifacts/$t" -type f -name 'slow-unit-*' | wc -l)
    [ "$slow" -eq 0 ] || echo "    $t: $slow slow-unit file(s) in artifacts/$t (replay them alone)" >&2
    corpus=$(find "corpus/$t" -type f ! -name .package-seeds | wc -l)
    printf '%-9s %6s %10s %6s %8s %7s %14s %7s %s\n' "$t" "$secs" "${execs:-?}" "${cov:-?}" \
        "${half:-?}" "${ft:-?}" \
        "${lastn:-?}" "$corpus" "$crashes"
    if [ "$rc" -ne 0 ] || [ "$crashes" -ne 0 ]; then
        status=1
        grep -E 'ERROR|panicked|SUMMARY' "$log" | head -5 | sed 's/^/    /'
    fi
done
# Scratch directories are named vkshade-fuzz-PID-THREAD: remove those whose process is gone,
# so that two runs side by side (different targets) keep each other's.
for d in /dev/shm/vkshade-fuzz-*; do
    [ -e "$d" ] || continue
    pid=${d#/dev/shm/vkshade-fuzz-}
    kill -0 "${pid%%-*}" 2>/dev/null || rm -rf "$d"
done
exit $status
