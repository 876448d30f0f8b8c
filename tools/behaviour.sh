#!/usr/bin/env bash
# behaviour.sh BIN OUT: the outputs of the sim-host binary BIN that a refactor must leave
# byte-identical, written to OUT: every SIL case's summary.json and rows on the first
# acceptance seed, the call tapes (sha256) and
# per-frame replay digests of three path drives, two --sim-counter runs and the main command.
# Compare two builds with `diff -r OUT1 OUT2`; only the host-clock task timing of the main
# command's summaries (max_us, mean_us, overruns) and sil.log (progress lines, output paths) differ between
# two runs of the same binary.
set -uo pipefail
BIN=$(realpath "$1"); OUT=$(realpath -m "$2")
cd "$(dirname "$0")/.."
mkdir -p "$OUT"
"$BIN" sil --seeds 1 --out "$OUT/sil-results.md" --rows "$OUT/sil-seeds.jsonl" \
  --summaries "$OUT/sil" > "$OUT/sil.log" 2>&1 || true
for s in slope-10-cross:10 marsyard-25m:30 slope-10-faults:30; do
  n=${s%%:*}; t=${s##*:}
  "$BIN" record "scenarios/$n.toml" --seconds "$t" --out "$OUT/$n.tape" > /dev/null
  "$BIN" replay "$OUT/$n.tape" --digests "$OUT/$n.digests" > "$OUT/$n.replay" 2>&1
  sha256sum "$OUT/$n.tape" | cut -d' ' -f1 > "$OUT/$n.tape.sha"; rm "$OUT/$n.tape"
done
"$BIN" run scenarios/marsyard-25m.toml --sim-counter --out "$OUT/run-marsyard" > /dev/null 2>&1
"$BIN" run scenarios/marsyard-25m.toml --sim-counter --no-vo --localization \
  --out "$OUT/run-marsyard-novo-loc" > /dev/null 2>&1
"$BIN" compare --out "$OUT/compare" > /dev/null 2>&1
# The wall time of a run differs from run to run.
find "$OUT" -name summary.json -exec sed -i 's/"wall_time_s": [0-9.e+-]*/"wall_time_s": 0/' {} \;
sed -i 's/"wall_time_s": [0-9.e+-]*/"wall_time_s": 0/' "$OUT"/sil/*.json
sed -i 's/"wall_time_s":[0-9.e+-]*/"wall_time_s":0/' "$OUT/sil-seeds.jsonl"
# The page's summed wall time and its commit line.
sed -i -e 's/[0-9]* min of run wall time/N min of run wall time/' -e 's/from commit `[^`]*`/from commit X/' "$OUT/sil-results.md"
find "$OUT" -name report.html -delete
