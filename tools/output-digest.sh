#!/usr/bin/env bash
# Runs every kernel through the CLI on fixed inputs and prints a SHA-256 per data output
# (EXR, PLY, PNG, JSON fits), so two builds can be compared byte for byte.
# Usage: tools/output-digest.sh VKSHADE_BINARY WORKDIR > digest.txt   (from the repository root;
# reads data/, so run tools/setup.sh first). Every command runs under --validate.
set -euo pipefail
B=$1; D=$2
rm -rf "$D"; mkdir -p "$D"
run() { echo "+ $*" >&2; "$B" --validate "$@" > "$D/log.$RANDOM.txt" 2>&1 || { echo "FAILED: $*" >&2; exit 1; }; }
run ao --frames 2 --reference --out "$D/ao"
run sss --size 256 --samples 16 --reference --out "$D/sss"
run sss --size 256 --samples 8 --light dir:0.3,0.5,1 --profile burley --out "$D/sss-burley"
run btf synth --pattern weave --size 16 -o "$D/btfdata"
run btf render --btf "$D/btfdata" --width 128 --height 128 --reference --out "$D/btf"
run btf render --btf "$D/btfdata" --width 96 --height 96 --object cylinder --texture rgba8 --layout layers --out "$D/btf-layers"
run srbf fit --lobes 16 -o "$D/fit.json"
run srbf shade --frames 2 --reference --out "$D/srbf"
cd "$D"
find . -type f \( -name '*.exr' -o -name '*.ply' -o -name '*.png' \) | sort | xargs sha256sum
# JSON outputs without what varies from run to run: timings (keys naming ms, fps, seconds and
# timing statistics), the machine, the work directory in paths; floats to 10 significant
# digits (rayon's parallel sums may differ in the last bits from run to run). The errors
# against the CPU twins and the truths, sizes, fitted lobes and memory remain.
for r in fit.json $(find . -name report.json | sort); do
  python3 - "$r" "$D" <<'PY'
import json, re, sys, hashlib
volatile = re.compile(r"(^|_)(ms|fps|time|times|seconds|machine|timings|throughput|per_s|load)($|_)")
stats = {"max", "mean", "median", "min", "spread"}
def strip(v):
    if isinstance(v, dict):
        if stats <= set(v):
            return "(timing statistics)"
        return {k: strip(x) for k, x in v.items() if not volatile.search(k)}
    if isinstance(v, list):
        return [strip(x) for x in v]
    if isinstance(v, float):
        return float(f"{v:.10g}")
    if isinstance(v, str):
        return v.replace(sys.argv[2], "$D")
    return v
d = json.load(open(sys.argv[1]))
if sys.argv[1] == "fit.json":
    d["errors"] = [e[:-1] for e in d["errors"]]  # [lobes, error, per channel, fit ms]
text = json.dumps(strip(d), sort_keys=True)
print(hashlib.sha256(text.encode()).hexdigest(), sys.argv[1], "(stable fields)")
PY
done
