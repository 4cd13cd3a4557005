#!/usr/bin/env bash
# Issue 30: one change's effect on training time, before against after, interleaved on one machine.
#
# Trains the teapot with `bcfpipe train` from two source trees (BEFORE: e.g. a `git worktree` of the
# commit before the change; AFTER: this tree), alternating, each run alone, and prints per run the
# PSNR from the exported files, the training seconds and the first encode's seconds.
#
#   benchmarks/bench_interleaved.sh BEFORE_TREE [PROFILES=1k,2k] [PRESET=draft] [REPS=2]
#   e.g.  git worktree add /tmp/before eab901f && benchmarks/bench_interleaved.sh /tmp/before
set -euo pipefail
before=$(cd "${1:?a source tree to compare against}" && pwd)
after=$(cd "$(dirname "$0")/.." && pwd)
profiles=${2:-1k,2k}
preset=${3:-draft}
reps=${4:-2}
py="$after/.venv/bin/python"
T="${BCFPIPE_SCENES:-$after/../shared/scenes}/usdwg_teapot/textures"
[ -d "$T" ] || { echo "bench_interleaved: no teapot textures at $T (set BCFPIPE_SCENES)" >&2; exit 2; }
set_args=("albedo=$T/tea_set_01_diff_2k.jpg:rgb" "occlusion=$T/tea_set_01_arm_2k.jpg:r"
          "roughness=$T/tea_set_01_arm_2k.jpg:g" "metallic=$T/tea_set_01_arm_2k.jpg:b")
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "| profile | round | code | all mips | train | encode |"
echo "|---|---:|---|---:|---:|---:|"
for prof in ${profiles//,/ }; do
  for rep in $(seq "$reps"); do
    for who in before after; do
      root=$before; [ "$who" = after ] && root=$after
      (cd "$root" && PYTHONPATH="$root" "$py" -m bcfpipe train "${set_args[@]}" --profile "$prof" \
         --quality "$preset" --json -o "$tmp/$who" > "$tmp/$who.json" 2> /dev/null)
      "$py" -c "import json, sys; j = json.load(open(sys.argv[1]))
print(f\"| {sys.argv[2]} | {sys.argv[3]} | {sys.argv[4]} | {j['psnr']:.2f} | {j['train_seconds']:.1f} s | {j['phase_seconds'].get('encode', 0):.2f} s |\")" \
        "$tmp/$who.json" "$prof" "$rep" "$who"
      rm -rf "${tmp:?}/$who"
    done
  done
done
